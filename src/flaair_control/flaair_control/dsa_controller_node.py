"""dsa_controller_node: the delayed-stretch-activation (dSA) controller that closes the wingbeat loop.

Subscribes to the estimated wing state (/flaair/wing_state: stroke velocity and validity, from
the front end) and publishes one drive-command block (/flaair/drive) per wing-state block, plus
a ControllerState (/flaair/controller/state) per command block. With the plant in lockstep the
loop is closed block by block: plant -> front end -> controller -> plant. A thin shell over
three cores: flaair_control.dsa (filter, K_r blend, clamp), flaair_control.safety (watchdog
envelope, slew limit, clamp to +-drive_limit_v) and, for the ControllerState stroke frequency,
flaair_control.transition.CrossingFrequency.

Drive (paper eqs. dsa/dsaconst): the dSA filter tau'' + a tau' + b tau = -c phi' runs all the
time on the measured stroke velocity; drive = K_r sync + (1 - K_r) tau / G_a, with sync a sine
(sync_amplitude_v, sync_frequency_hz) and K_r (1 synchronous, 0 asynchronous) ramped on a
schedule: kr_initial until kr_ramp_start_s (signal time), then linearly to kr_target over
kr_ramp_duration_s. Setting kr_target or kr_ramp_duration_s while running (parameter service
of the node) starts a new ramp from the current K_r at the next block (std_srvs is not
available in this environment, so the parameter callback is the "service"). G_a comes from the
model file.

Starting the loop: the lockstep plant waits for commands, so once the plant subscribes to
/flaair/drive (and publishes /flaair/sensor_v) and a publisher of /flaair/wing_state exists
(and start_delay_s has passed, for
the front end to match the plant's sensor stream), the node publishes blocks_in_flight blocks
itself (drive from a filter at rest: the synchronous sine). If no wing-state block answers
within start_retry_s it sends one more block (a lost first block would otherwise deadlock).
A wing-state block that arrives before that (blocks already flowing) is simply answered, once
/flaair/drive has a subscriber.

Transport delay and its compensation: velocity block k (samples [kN, (k+1)N)) is complete only
at the end of block k, so its drive is applied in block k + blocks_in_flight. The loop delay is
T = (blocks_in_flight N + 0.5) / fs (block transport plus the drive's zero-order hold) plus the
front end's velocity-filter group delay (0.22 ms for the default 1 kHz differentiator):
0.5 + 0.025 + 0.22 = 0.75 ms at 20 kHz with 10-sample blocks. At 140 Hz the block alone is
360 f T_block = 25 deg of phase lag, 38 deg in all. Uncompensated, that lag turns part of the
dSA negative damping into negative stiffness and the loop self-excites *below* the resonance
(135 Hz and 25 deg with the defaults, simulated and predicted alike) instead of slightly above
it. With compensate_delay the dsa core's phase advance (tau + sin(w_c T)/w_c tau', tau predicted
one loop delay ahead) is configured with T from block_size, blocks_in_flight and the front
end's velocity delay (velocity_delay_s < 0: computed from the front end's config section), at
w_c = 2 pi compensation_frequency_hz: the delay is cancelled exactly at w_c and to first order
near it, and the loop settles where the delay-free theory puts it (flaair_control.hopf:
144.2 Hz, 20.5 deg with the defaults; 144.1 Hz, 20.6 deg measured over DDS). Pipelining
(blocks_in_flight 2) adds a block of delay, compensated the same way (theory 144.2 Hz).

Safety: every block goes through the safety core (non-finite -> 0, slew limit, clamp to
+-drive_limit_v). The watchdog trips (latched; reset_watchdog:=true re-arms) when
  * no wing-state block arrives for watchdog_timeout_s of *wall-clock* time (checked on a
    wall-clock timer: in lockstep, sim time stops with the loop), or
  * no fully valid block (all stroke_valid, finite velocity) arrives for invalid_timeout_s of
    signal time (blocks keep coming but turned invalid), or
  * a collision onset arrives and collision_response is stop.
Once tripped, the wall-clock timer takes over the pacing: it publishes the ramp-down
(ramp_down_s to zero) and then zero_hold_s of zero drive at the real-time rate, then one zero
block per keepalive_period_s, whether or not the loop still answers. Invalid or malformed
wing-state blocks (NaN velocity, stroke_valid false, wrong length or rate) are counted and
logged; their samples drive the filter as 0 and the loop keeps going; duplicates are ignored.
collision_response reduce_amplitude scales the drive by collision_reduction_factor from an
onset until the clearance (collision_restore_on_clearance). close() (Ctrl-C, SIGTERM) publishes
a zero-drive block before the node exits.

Usage: bin/flaair run flaair_control dsa_controller_node [--ros-args -p kr_ramp_start_s:=0.3 ...]
"""
from __future__ import annotations

import math
import time

import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node

from flaair_common import cdr, topics
from flaair_common.blocks import check_block, stamp_ns_of_sample
from flaair_model.config import ConfigError, node_parameters
from flaair_common.params import ParameterError, ParamSpec, declare_parameters
from flaair_common.qos import BLOCK_STREAM, STATUS
from flaair_common.runtime import run_node, warn_counted
from flaair_control import dsa, safety
from flaair_control.transition import CrossingFrequency
from flaair_msgs.msg import CollisionEvent, ControllerState, DriveCommandBlock, WingStateBlock

NODE_NAME = "dsa_controller_node"
CONFIG_FILE = "flaair.yaml"
PARAMS = [
    ParamSpec("sample_rate_hz", float, "Sample rate of every block stream [Hz]", 1000.0, 1.0e6, read_only=True),
    ParamSpec("block_size", int, "Samples per block", 1, 100000, read_only=True),
    ParamSpec("drive_limit_v", float, "Actuator safe range: drive clamped to +-this [V]", 0.0, 300.0, read_only=True),
    ParamSpec("model_file", str, "Model YAML for the actuator gain G_a (empty: config/model.yaml)", read_only=True),
    ParamSpec("r3_rad_s", float, "dSA coefficient r3 (force delay) [rad/s]", 1e-3, 1e6, read_only=True),
    ParamSpec("kappa", float, "dSA coefficient kappa (force decay) [-]", 1e-6, 1e3, read_only=True),
    ParamSpec("mu_nm_s_per_rad", float, "dSA gain mu (DC: tau = -mu phi') [N m s/rad]", 0.0, 1.0, read_only=True),
    ParamSpec("sync_amplitude_v", float, "Synchronous sine amplitude [V]", 0.0, 300.0, read_only=True),
    ParamSpec("sync_frequency_hz", float, "Synchronous sine frequency [Hz]", 0.0, 5000.0, read_only=True),
    ParamSpec("sync_phase_rad", float, "Synchronous sine phase at t = 0 [rad]", -10.0, 10.0, read_only=True),
    ParamSpec("kr_initial", float, "K_r before the ramp (1 synchronous, 0 asynchronous) [-]", 0.0, 1.0, read_only=True),
    ParamSpec("kr_target", float, "K_r after the ramp; set while running: new ramp from the current K_r [-]", 0.0, 1.0),
    ParamSpec("kr_ramp_start_s", float, "Signal time at which the first K_r ramp starts [s]", 0.0, 1e6, read_only=True),
    ParamSpec("kr_ramp_duration_s", float, "K_r ramp duration; set while running: new ramp [s]", 0.0, 1e6),
    ParamSpec("compensate_delay", bool, "Phase-advance compensation of the loop delay (dsa core)", read_only=True),
    ParamSpec("compensation_frequency_hz", float, "Frequency w_c/2pi at which the delay is cancelled exactly [Hz]", 1.0, 5000.0, read_only=True),
    ParamSpec("velocity_delay_s", float, "Front-end velocity delay to compensate (< 0: from the front end's config) [s]", -1.0, 0.1, read_only=True),
    ParamSpec("blocks_in_flight", int, "Command blocks kept in the lockstep loop (loop delay = this many blocks)", 1, 64, read_only=True),
    ParamSpec("slew_limit_v_per_s", float, "Drive slew-rate limit (0: off) [V/s]", 0.0, 1e9, read_only=True),
    ParamSpec("watchdog_timeout_s", float, "Trip when no wing-state block arrives for this long (wall clock) [s]", 1e-3, 60.0, read_only=True),
    ParamSpec("invalid_timeout_s", float, "Trip when no valid wing-state block arrives for this long (signal time) [s]", 1e-4, 60.0, read_only=True),
    ParamSpec("ramp_down_s", float, "Drive ramp to zero after a trip (signal time) [s]", 0.0, 10.0, read_only=True),
    ParamSpec("zero_hold_s", float, "Zero drive published at the real-time rate after the ramp [s]", 0.0, 10.0, read_only=True),
    ParamSpec("keepalive_period_s", float, "Tripped and ramped down: one zero block per this period (wall clock) [s]", 1e-3, 60.0, read_only=True),
    ParamSpec("reset_watchdog", bool, "Set true while running to re-arm a tripped watchdog (restarts the loop)"),
    ParamSpec("collision_response", str, "Reaction to a collision onset", choices=("none", "stop", "reduce_amplitude"), read_only=True),
    ParamSpec("collision_reduction_factor", float, "reduce_amplitude: drive scale while colliding [-]", 0.0, 1.0, read_only=True),
    ParamSpec("collision_restore_on_clearance", bool, "reduce_amplitude: back to full drive at the clearance", read_only=True),
    ParamSpec("min_drive_subscribers", int, "Start once /flaair/drive has this many subscribers (plant, + recorder, + monitor)", 1, 100, read_only=True),
    ParamSpec("wait_for_peers", bool, "Start only once /flaair/drive has a subscriber and /flaair/sensor_v and /flaair/wing_state publishers", read_only=True),
    ParamSpec("start_delay_s", float, "Wall time between seeing the peers and sending the first blocks [s]", 0.0, 60.0, read_only=True),
    ParamSpec("start_retry_s", float, "No answer to the first blocks for this long: send one more (wall clock) [s]", 0.01, 60.0, read_only=True),
    ParamSpec("run_time_s", float, "Stop after this much signal time: zero block, then idle (0: never) [s]", 0.0, 1e6, read_only=True),
    ParamSpec("frequency_hysteresis_deg", float, "Stroke-frequency estimate: Schmitt hysteresis about 0 [deg]", 0.0, 90.0, read_only=True),
    ParamSpec("timing_file", str, "Write per-block receive/publish monotonic times here at exit (.npz; empty: off)", read_only=True),
]

# Pacing modes.
WAITING = "waiting"        # not started: waiting for peers / start delay
LOOP = "loop"              # one command block per wing-state block
TRIPPED = "tripped"        # wall-clock timer publishes the ramp-down and zeros
DONE = "done"              # run_time_s reached: idle


def velocity_delay_from_frontend(fs_hz: float, frequency_hz: float) -> float:
    """Group delay (s) of the front end's stroke velocity at ``frequency_hz``, from its config section."""
    from flaair_sensors import frontend
    from flaair_sensors.frontend_node import frontend_params

    try:
        values = node_parameters(CONFIG_FILE, "frontend_node")
    except ConfigError as exc:
        raise ParameterError(f"parameter 'velocity_delay_s' < 0 needs the frontend_node config: {exc}") from exc
    return float(frontend.estimate_delay_s(frontend_params(values, fs_hz), frequency_hz)["stroke_velocity_s"])


class DsaControllerNode(Node):
    """Thin shell over flaair_control.dsa.step and flaair_control.safety.step."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        p = self.p = declare_parameters(self, PARAMS, CONFIG_FILE)
        self.fs_hz = p["sample_rate_hz"]
        self.block_size = p["block_size"]
        self.in_flight = p["blocks_in_flight"]
        try:
            from flaair_model.model import ModelError
            from flaair_model.model_io import load_model

            try:
                model = load_model(p["model_file"] or None)
            except (ModelError, OSError) as exc:
                raise ParameterError(f"parameter 'model_file': {exc}") from exc
            self.actuator_gain = model.plant.actuator_gain_nm_per_v
            self.velocity_delay_s = (p["velocity_delay_s"] if p["velocity_delay_s"] >= 0
                                     else velocity_delay_from_frontend(self.fs_hz, p["compensation_frequency_hz"]))
            # block transport (blocks_in_flight blocks) + ZOH half sample + the front end's velocity delay
            self.loop_delay_s = dsa.loop_delay_s(self.block_size * self.in_flight, self.fs_hz,
                                                 self.velocity_delay_s * self.fs_hz)
            self.schedule = dsa.KrSchedule(p["kr_initial"], p["kr_target"], p["kr_ramp_start_s"], p["kr_ramp_duration_s"])
            self.dsa_params = self._dsa_params(self.schedule)
            self.safety_params = safety.SafetyParams(
                drive_limit_v=p["drive_limit_v"],
                slew_limit_v_per_s=p["slew_limit_v_per_s"] if p["slew_limit_v_per_s"] > 0 else math.inf,
                watchdog_timeout_s=p["invalid_timeout_s"], ramp_down_s=p["ramp_down_s"],
            )
        except (dsa.DsaParameterError, safety.SafetyParameterError) as exc:
            raise ParameterError(str(exc)) from exc
        self.ctrl = dsa.initial_state(self.dsa_params)
        self.safety = safety.initial_state(0.0)
        self.frequency = CrossingFrequency(self.fs_hz, p["frequency_hysteresis_deg"])  # fed stroke_deg
        self.mode = WAITING
        self.fault = ""
        self.amplitude_scale = 1.0
        self.next_index = 0
        self.expected_index: int | None = None
        self.end_index = int(round(p["run_time_s"] * self.fs_hz)) or None
        self.counts = {"blocks": 0, "invalid": 0, "rejected": 0, "stale": 0, "gaps": 0, "kicks": 0}
        self.peers_seen_wall: float | None = None
        self.last_arrival_wall = 0.0
        self.first_arrival_wall: float | None = None
        self.first_arrival_index = 0
        self.last_sent_wall = 0.0
        self.trip_pace_wall = 0.0
        self.trip_pace_index = 0
        self.nan_block = np.full(self.block_size, np.nan)
        # (drive index, wing-state receive, drive publish) per block, for benchmarks
        self.timing: list[tuple[int, float, float]] | None = [] if p["timing_file"] else None
        # Block streams travel as CDR bytes through flaair_common.cdr: rclpy's message conversion
        # costs about as much CPU as the transport at 2000 blocks/s.
        self.wing_state_codec = cdr.FixedCodec(cdr.WING_STATE_BLOCK, self.block_size, topics.FRAME_ID)
        self.drive_codec = cdr.FixedCodec(cdr.DRIVE_COMMAND_BLOCK, self.block_size)
        self.drive_pub = self.create_publisher(DriveCommandBlock, topics.DRIVE, BLOCK_STREAM)
        # One state per block: a block stream (deep queue), not a keep-the-last-few status topic.
        self.state_pub = self.create_publisher(ControllerState, topics.CONTROLLER_STATE, BLOCK_STREAM)
        self.create_subscription(WingStateBlock, topics.WING_STATE, self.on_wing_state, BLOCK_STREAM, raw=True)
        # Volatile: matches the monitor's transient-local publisher and a plain one (flaair topic pub),
        # and a stale onset from before this node started is not acted upon.
        self.create_subscription(CollisionEvent, topics.COLLISION_EVENTS, self.on_collision_event, STATUS)
        self.add_on_set_parameters_callback(self.on_set_parameters)
        # Every timer wake-up costs a spin of the executor (~0.3-0.5 ms CPU with run_node's
        # SingleThreadedExecutor), so no faster than needed: 10 ms, or a quarter of the timeout.
        self.timer_period_s = min(0.01, p["watchdog_timeout_s"] / 4)
        self.create_timer(self.timer_period_s, self.on_timer)
        block_ms = 1e3 * self.block_size / self.fs_hz
        f_c = p["compensation_frequency_hz"]
        self.get_logger().info(
            f"dSA controller ready: r3 {p['r3_rad_s']:g} rad/s, kappa {p['kappa']:g}, mu {p['mu_nm_s_per_rad']:g} N m s/rad, "
            f"G_a {self.actuator_gain:g} N m/V; sync {p['sync_amplitude_v']:g} V at {p['sync_frequency_hz']:g} Hz; "
            f"K_r {p['kr_initial']:g} -> {p['kr_target']:g} from {p['kr_ramp_start_s']:g} s over {p['kr_ramp_duration_s']:g} s; "
            f"loop delay {1e3 * self.loop_delay_s:.3f} ms ({self.in_flight} x {block_ms:g} ms blocks + ZOH + "
            f"velocity {1e3 * self.velocity_delay_s:.3f} ms) = {360 * f_c * self.loop_delay_s:.1f} deg at {f_c:g} Hz, "
            f"{'compensated' if p['compensate_delay'] else 'NOT compensated'}; limit +-{p['drive_limit_v']:g} V; "
            f"collision response {p['collision_response']}"
        )

    # ------------------------------------------------------------------ parameters
    def _dsa_params(self, schedule: dsa.KrSchedule) -> dsa.DsaParams:
        p = self.p
        return dsa.DsaParams(
            r3_rad_s=p["r3_rad_s"], kappa=p["kappa"], mu_nm_s_per_rad=p["mu_nm_s_per_rad"],
            actuator_gain_nm_per_v=self.actuator_gain, sample_rate_hz=self.fs_hz, drive_limit_v=p["drive_limit_v"],
            sync_amplitude_v=p["sync_amplitude_v"], sync_frequency_hz=p["sync_frequency_hz"],
            sync_phase_rad=p["sync_phase_rad"], kr_schedule=schedule,
            loop_delay_s=self.loop_delay_s if p["compensate_delay"] else 0.0,
            compensation_frequency_hz=p["compensation_frequency_hz"],
        )

    def on_set_parameters(self, parameters) -> SetParametersResult:
        """kr_target / kr_ramp_duration_s: new ramp from the current K_r; reset_watchdog: re-arm."""
        changes = {param.name: param.value for param in parameters}
        t_now = self.next_index / self.fs_hz
        if "kr_target" in changes or "kr_ramp_duration_s" in changes:
            target = changes.get("kr_target", self.get_parameter("kr_target").value)
            duration = changes.get("kr_ramp_duration_s", self.get_parameter("kr_ramp_duration_s").value)
            current = float(self.schedule.value(np.array([t_now]))[0])
            try:
                schedule = dsa.KrSchedule(current, float(target), t_now, float(duration))
                self.dsa_params = self._dsa_params(schedule)
            except dsa.DsaParameterError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
            self.schedule = schedule
            self.get_logger().info(f"K_r ramp {current:.3f} -> {target:g} over {duration:g} s from t = {t_now:.4f} s")
        if changes.get("reset_watchdog"):
            if self.mode == TRIPPED:
                self.safety = safety.reset(self.safety, t_now)
                self.fault = ""
                self.mode = LOOP
                self.last_arrival_wall = time.monotonic()
                self.get_logger().warning("watchdog reset by request; restarting the loop")
                for _ in range(self.in_flight):
                    self.send_block(self.nan_block, None)
            else:
                self.get_logger().info("reset_watchdog: watchdog not tripped, nothing to do")
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ inputs
    def on_wing_state(self, data: bytes) -> None:
        t_receive = time.monotonic()
        if self.mode == DONE:
            return
        try:
            message = self.wing_state_codec.decode(data)
        except cdr.CdrError as exc:
            self.counts["rejected"] += 1
            self._warn(f"wing-state block dropped: {exc}", "rejected")
            return
        first = int(message["first_sample_index"])
        if self.mode == WAITING:
            # Blocks already flow (a realtime plant, or a publisher faster than our start check):
            # join the loop by answering them, no extra start blocks - once someone listens.
            if self.drive_pub.get_subscription_count() == 0:
                return
            self.mode = LOOP
            self.get_logger().info(f"wing-state block {first} before the start: joining the loop")
        self.last_arrival_wall = t_receive
        if self.first_arrival_wall is None:
            self.first_arrival_wall = t_receive
            self.first_arrival_index = first
            self.safety = safety.initial_state(first / self.fs_hz)
            self.get_logger().info(f"loop closed: first wing-state block {first}")
        n = self.block_size
        field = message["stroke_velocity_deg_s"]
        rate_hz = float(message["sample_rate_hz"])
        kind = "ok"
        # Fast path (every block in a healthy loop): in order, right length and rate; check_block
        # (allocations, np.isclose) only runs to name what is wrong.
        if not (first == self.expected_index and len(field) == n and rate_hz == self.fs_hz):
            check = check_block({"stroke_velocity_deg_s": np.zeros(len(field))}, rate_hz, self.fs_hz,
                                first, self.expected_index, n)
            kind = check.kind
            if kind == "stale":
                self.counts["stale"] += 1
                self._warn(f"wing-state block {first} ignored: {check.reason}", "stale")
                return
            if kind == "gap":
                self.counts["gaps"] += 1
                self._warn(f"wing-state block {first}: {check.reason}", "gaps")
            elif kind == "content":
                self.counts["rejected"] += 1
                self._warn(f"wing-state block {first} rejected: {check.reason}; its samples drive the filter as 0",
                           "rejected")
        self.expected_index = first + n
        self.counts["blocks"] += 1
        if kind == "content":
            velocity_rad_s, valid = self.nan_block, False
        else:
            velocity_rad_s = np.radians(field)
            flags = message["stroke_valid"]
            valid = len(flags) == n and bool(flags.all()) and bool(np.isfinite(velocity_rad_s).all())
            if not valid:
                self.counts["invalid"] += 1
                self._warn(f"wing-state block {first} invalid (stroke_valid false or non-finite velocity); "
                           "its invalid samples drive the filter as 0", "invalid")
                if len(flags) == n:
                    velocity_rad_s = np.where(flags, velocity_rad_s, np.nan)
            stroke_deg = message["stroke_deg"]
            self.frequency.update(stroke_deg if len(stroke_deg) == n else self.nan_block)
        if valid:
            self.safety = safety.note_sensor_block(self.safety, (first + n) / self.fs_hz, True, self.safety_params)
            self._check_core_trip()
        if self.mode != LOOP:
            return
        self.send_block(velocity_rad_s, t_receive)

    def on_collision_event(self, message: CollisionEvent) -> None:
        response = self.p["collision_response"]
        if message.kind == CollisionEvent.ONSET:
            text = (f"collision onset at wingbeat {message.wingbeat_index} "
                    f"(spectrum RMSE {message.spectrum_rmse_deg:.2f} deg)")
            if response == "stop":
                self.trip(f"{text}: stop")
            elif response == "reduce_amplitude":
                self.amplitude_scale = self.p["collision_reduction_factor"]
                self.get_logger().warning(f"{text}: drive scaled by {self.amplitude_scale:g}")
            else:
                self.get_logger().warning(f"{text}: no response configured")
        elif message.kind == CollisionEvent.CLEARANCE:
            if response == "reduce_amplitude" and self.p["collision_restore_on_clearance"] and self.amplitude_scale != 1.0:
                self.amplitude_scale = 1.0
                self.get_logger().info(f"collision cleared at wingbeat {message.wingbeat_index}: full drive again")
            else:
                self.get_logger().info(f"collision cleared at wingbeat {message.wingbeat_index}")

    # ------------------------------------------------------------------ output
    def send_block(self, velocity_rad_s: np.ndarray, t_receive: float | None) -> None:
        """Run the cores on one velocity block and publish the drive block and the controller state."""
        t_start = self.next_index / self.fs_hz
        self.ctrl, drive_v, sig = dsa.step(self.ctrl, velocity_rad_s, t_start, self.dsa_params)
        if self.amplitude_scale != 1.0:
            drive_v = drive_v * self.amplitude_scale
        self.safety, out = safety.step(self.safety, drive_v, t_start, self.fs_hz, self.safety_params)
        self._check_core_trip()
        stamp_ns = stamp_ns_of_sample(self.next_index, self.fs_hz)
        self.drive_pub.publish(self.drive_codec.encode(stamp_ns, {
            "sample_rate_hz": self.fs_hz, "first_sample_index": self.next_index, "drive_v": out.drive_v}))
        t_publish = time.monotonic()
        self.last_sent_wall = t_publish
        if t_receive is not None and self.timing is not None:
            self.timing.append((self.next_index, t_receive, t_publish))
        self.state_pub.publish(cdr.encode(cdr.CONTROLLER_STATE, stamp_ns, "", {
            "k_r": sig.kr[-1], "async_drive_v": sig.async_v[-1], "sync_drive_v": sig.sync_v[-1],
            "drive_v": out.drive_v[-1],
            "drive_clamped": np.abs(sig.drive_unclipped_v).max() * self.amplitude_scale > self.p["drive_limit_v"],
            "watchdog": ControllerState.WATCHDOG_TRIPPED if out.tripped else ControllerState.WATCHDOG_OK,
            "fault": self.fault, "amplitude_scale": self.amplitude_scale,
            "stroke_frequency_hz": self.frequency.frequency_hz}))
        self.next_index += self.block_size
        if self.end_index is not None and self.next_index >= self.end_index and self.mode != DONE:
            self.finish()

    def _check_core_trip(self) -> None:
        """The safety core tripped by itself (signal-time timeout without a valid block)."""
        if self.safety.status == safety.TRIPPED and self.mode == LOOP:
            self.fault = (f"no valid wing-state block after t = {self.safety.last_valid_time_s:.4f} s for more than "
                          f"invalid_timeout_s = {self.p['invalid_timeout_s']:g} s of signal time")
            self._enter_tripped()

    def trip(self, fault: str) -> None:
        """Trip the watchdog now (at the next unpublished sample) with a fault text."""
        if self.mode == TRIPPED or self.mode == DONE:
            return
        t_now = self.next_index / self.fs_hz
        # The safety core trips an invalid block at its time: the ramp starts at the next sample.
        self.safety = safety.note_sensor_block(self.safety, t_now, False, self.safety_params)
        self.fault = fault
        self._enter_tripped()

    def _enter_tripped(self) -> None:
        self.mode = TRIPPED
        self.trip_pace_wall = time.monotonic()
        self.trip_pace_index = self.next_index
        self.get_logger().error(f"WATCHDOG TRIPPED at t = {self.safety.trip_time_s:.4f} s: {self.fault}; "
                                f"ramping the drive to zero over {self.p['ramp_down_s']:g} s")

    def finish(self) -> None:
        """run_time_s reached: zero block, then idle."""
        self.mode = DONE
        self.publish_zero_block()
        self.get_logger().info(self.summary("run complete"))

    def publish_zero_block(self) -> None:
        self.drive_pub.publish(self.drive_codec.encode(stamp_ns_of_sample(self.next_index, self.fs_hz), {
            "sample_rate_hz": self.fs_hz, "first_sample_index": self.next_index, "drive_v": np.zeros(self.block_size)}))
        self.next_index += self.block_size

    # ------------------------------------------------------------------ wall-clock timer
    def on_timer(self) -> None:
        now = time.monotonic()
        if self.mode == WAITING:
            self.try_start(now)
        elif self.mode == LOOP:
            if self.first_arrival_wall is None:
                if now - self.last_sent_wall > self.p["start_retry_s"]:
                    self.counts["kicks"] += 1
                    self.get_logger().warning(
                        f"no wing-state block {self.p['start_retry_s']:g} s after starting; sending one more block "
                        f"({self.counts['kicks']}) - is the front end running?")
                    self.send_block(self.nan_block, None)
            elif now - self.last_arrival_wall > self.p["watchdog_timeout_s"]:
                self.trip(f"no wing-state block for {1e3 * (now - self.last_arrival_wall):.0f} ms of wall-clock time "
                          f"(> watchdog_timeout_s {self.p['watchdog_timeout_s']:g} s) after block "
                          f"{(self.expected_index or self.block_size) - self.block_size}")
        elif self.mode == TRIPPED:
            t_quiet = self.safety.trip_time_s + self.p["ramp_down_s"] + self.p["zero_hold_s"]
            if self.next_index / self.fs_hz < t_quiet:
                due = self.trip_pace_index + int((now - self.trip_pace_wall) * self.fs_hz)
                budget = max(1, int(4 * self.timer_period_s * self.fs_hz / self.block_size))
                while self.next_index + self.block_size <= due and budget > 0:
                    self.send_block(self.nan_block, None)
                    budget -= 1
            elif now - self.last_sent_wall >= self.p["keepalive_period_s"]:
                self.send_block(self.nan_block, None)

    def try_start(self, now: float) -> None:
        # A /flaair/drive subscriber alone may be a monitor or a recorder: also wait for the
        # sensor stream's source (the plant, or the DAQ) and the wing-state source (front end).
        if self.p["wait_for_peers"] and (self.drive_pub.get_subscription_count() < self.p["min_drive_subscribers"]
                                         or self.count_publishers(topics.SENSOR_VOLTAGE) == 0
                                         or self.count_publishers(topics.WING_STATE) == 0):
            return
        if self.peers_seen_wall is None:
            self.peers_seen_wall = now
        if now - self.peers_seen_wall < self.p["start_delay_s"]:
            return
        self.mode = LOOP
        self.get_logger().info(f"starting the loop: {self.in_flight} block(s) in flight")
        for _ in range(self.in_flight):
            self.send_block(self.nan_block, None)

    # ------------------------------------------------------------------ helpers
    def _warn(self, text: str, counter: str) -> None:
        count = self.counts[counter]
        warn_counted(self.get_logger(), count, f"{text} [{count} {counter} so far]")

    def summary(self, what: str) -> str:
        wall = (self.last_arrival_wall - self.first_arrival_wall) if self.first_arrival_wall else 0.0
        sim = (self.expected_index - self.first_arrival_index) / self.fs_hz if self.expected_index else 0.0
        rtf = f"{sim / wall:.3f}" if wall > 0 else "n/a"
        c = self.counts
        return (f"{what}: {c['blocks']} wing-state blocks ({c['invalid']} invalid, {c['rejected']} rejected, "
                f"{c['stale']} stale, {c['gaps']} gaps), {sim:.4f} s signal in {wall:.3f} s wall (RTF {rtf}), "
                f"watchdog {'TRIPPED: ' + self.fault if self.safety.status == safety.TRIPPED else 'ok'}")

    def close(self) -> None:
        """Shutdown: a zero-drive block so the actuator does not hold the last command."""
        self.publish_zero_block()
        self.get_logger().info(self.summary("shutting down, zero drive sent"))
        if self.timing:
            np.savez(self.p["timing_file"], timing=np.array(self.timing))
        time.sleep(0.1)  # let reliable delivery of the zero block finish


def main(args: list[str] | None = None) -> int:
    return run_node(DsaControllerNode, PARAMS, CONFIG_FILE, NODE_NAME, args)


if __name__ == "__main__":
    raise SystemExit(main())
