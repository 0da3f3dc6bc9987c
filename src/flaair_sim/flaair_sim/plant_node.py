"""plant_node: the simulated flapping-wing robot (stroke, pitch, PVDF sensors) as a ROS 2 node.

Subscribes to drive-command blocks (/flaair/drive) and publishes raw sensor-voltage blocks
(/flaair/sensor_v), ground-truth wing-state blocks (/flaair/wing_state/truth) and /clock.

Modes:
  lockstep  advances exactly one block per command block, in order, so a closed loop is
            deterministic whatever the wall speed (sim time = samples / sample_rate_hz).
  realtime  advances with the wall clock; uses the queued command blocks, zero drive if none.

A command block with NaN/inf samples, the wrong length or rate, or out of order is rejected,
counted and logged; the plant holds zero drive for that block and keeps running. Drive is
clamped to +-drive_limit_v before it reaches the model.

Drive watchdog (lockstep): the plant stands in for the actuator and its driver, which must not
hold a voltage when the command source dies. Once commands have flowed for
ARM_S (50 ms) of signal time, if no command block arrives for command_timeout_s of wall-clock
time while the last applied block was not all zeros (a source
that stops cleanly sends a zero block first: drive_node and the dSA controller do), the
watchdog trips: the drive is zeroed, an error is logged, and the plant rings down with zero
drive at the real-time rate for ring_down_s of signal time (published and recorded like any
block), then waits. A command that continues the sample count re-arms it.

An obstacle (the paper's collision experiment) can be scheduled in sim time with
obstacle_windows_s (pairs of start/end seconds) at obstacle_stroke_limit_deg.

Usage: bin/flaair run flaair_sim plant_node [--ros-args -p mode:=realtime -p model_file:=my.yaml]
"""
from __future__ import annotations

import collections
import time

import numpy as np
from rclpy.node import Node
from rosgraph_msgs.msg import Clock

from flaair_common import cdr, topics
from flaair_common.blocks import check_block, stamp_from_time_s, stamp_ns_of_sample
from flaair_common.params import ParameterError, ParamSpec, declare_parameters
from flaair_common.qos import BLOCK_STREAM
from flaair_common.runtime import run_node, warn_counted
from flaair_msgs.msg import DriveCommandBlock, SensorVoltageBlock, WingStateBlock
from flaair_sim import plant
from flaair_model.model import ModelError, with_effects
from flaair_model.model_io import load_model

NODE_NAME = "plant_node"
CLOCK_DEPTH = 1000  # /clock publisher history (KEEP_LAST, reliable)
ARM_S = 0.05  # drive watchdog: armed after this much commanded signal time
CONFIG_FILE = "flaair.yaml"
PARAMS = [
    ParamSpec("sample_rate_hz", float, "Sample rate of every block stream [Hz]", 1000.0, 1.0e6, read_only=True),
    ParamSpec("block_size", int, "Samples per block", 1, 100000, read_only=True),
    ParamSpec("drive_limit_v", float, "Actuator safe range: drive clamped to +-this [V]", 0.0, 300.0),
    ParamSpec("model_file", str, "Model YAML (empty: config/model.yaml)", read_only=True),
    ParamSpec("mode", str, "lockstep: one block per command block; realtime: wall clock", choices=("lockstep", "realtime"), read_only=True),
    ParamSpec("noise", bool, "Add the model's sensor-voltage noise", read_only=True),
    ParamSpec("noise_seed", int, "Seed of the sensor-noise generator", 0, 2**31 - 1, read_only=True),
    ParamSpec("publish_clock", bool, "Publish /clock with the simulation time", read_only=True),
    ParamSpec("obstacle_windows_s", list, "Obstacle in place over these [start, end) sim-time pairs [s]", read_only=True),
    ParamSpec("command_timeout_s", float, "lockstep: no command for this long (wall clock) while driven: zero drive, ring down (0: off) [s]", 0.0, 60.0, read_only=True),
    ParamSpec("ring_down_s", float, "Signal time stepped with zero drive after a drive-watchdog trip [s]", 0.0, 60.0, read_only=True),
    ParamSpec("obstacle_stroke_limit_deg", float, "Stroke angle at which the wing strikes the obstacle [deg]", 0.0, 90.0, read_only=True),
]


def obstacle_windows(flat_s: list[float]) -> list[tuple[float, float]]:
    """[start, end) pairs from a flat list; empty pairs (end <= start) are dropped."""
    if len(flat_s) % 2:
        raise ParameterError(f"parameter 'obstacle_windows_s' needs start/end pairs, got {len(flat_s)} values")
    return [(a, b) for a, b in zip(flat_s[0::2], flat_s[1::2]) if b > a]


class PlantNode(Node):
    """Thin shell over flaair_sim.plant.step: messages to arrays and back."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.p = declare_parameters(self, PARAMS, CONFIG_FILE)
        try:
            self.model = load_model(self.p["model_file"] or None)
        except (ModelError, OSError) as exc:
            raise ParameterError(f"parameter 'model_file': {exc}") from exc
        self.windows_s = obstacle_windows(self.p["obstacle_windows_s"])
        try:
            self.obstacle_model = with_effects(self.model, {"collision": {"stroke_limit_deg": self.p["obstacle_stroke_limit_deg"]}})
        except ModelError as exc:
            raise ParameterError(f"parameter 'obstacle_stroke_limit_deg': {exc}") from exc
        self.fs_hz = self.p["sample_rate_hz"]
        self.block_size = self.p["block_size"]
        self.state = plant.initial_state(self.model, self.fs_hz)
        self.noise_rng = np.random.default_rng(self.p["noise_seed"]) if self.p["noise"] else None
        self.next_index = 0
        self.expected_command_index: int | None = None
        self.rejected_blocks = 0
        self.sensor_pub = self.create_publisher(SensorVoltageBlock, topics.SENSOR_VOLTAGE, BLOCK_STREAM)
        self.truth_pub = self.create_publisher(WingStateBlock, topics.WING_STATE_TRUTH, BLOCK_STREAM)
        # One /clock per block (2000/s): a 10-deep reliable history lost ticks to a recorder a
        # moment behind (bench_recorder: 33 of 20,843); 1000 deep is 0.5 s of slack.
        self.clock_pub = self.create_publisher(Clock, topics.CLOCK, CLOCK_DEPTH) if self.p["publish_clock"] else None
        # Block streams travel as CDR bytes through flaair_common.cdr: rclpy's message conversion
        # would cost about as much CPU as the transport at 2000 blocks/s.
        self.drive_codec = cdr.FixedCodec(cdr.DRIVE_COMMAND_BLOCK, self.block_size)
        self.sensor_codec = cdr.FixedCodec(cdr.SENSOR_VOLTAGE_BLOCK, self.block_size, topics.FRAME_ID)
        self.truth_codec = cdr.FixedCodec(cdr.WING_STATE_BLOCK, self.block_size, topics.FRAME_ID)
        self.all_valid = np.ones(self.block_size, dtype=bool)
        self.no_velocity = np.full(self.block_size, np.nan)
        self.create_subscription(DriveCommandBlock, topics.DRIVE, self.on_command, BLOCK_STREAM, raw=True)
        self.pending: collections.deque[np.ndarray] = collections.deque(maxlen=1000)
        self.last_command_wall = time.monotonic()
        self.driven = False          # last applied block not all zeros
        self.ring_down: tuple[float, int, int] | None = None   # (wall start, first index, end index)
        self.commanded_samples = 0
        if self.p["mode"] == "realtime":
            self.wall_start_s = time.monotonic()
            self.create_timer(0.005, self.on_realtime_tick)
        elif self.p["command_timeout_s"] > 0:
            self.create_timer(min(0.01, self.p["command_timeout_s"] / 4), self.on_watchdog_tick)
        self.get_logger().info(
            f"plant ready: {self.p['mode']}, {self.fs_hz:g} Hz, {self.block_size}-sample blocks, "
            f"effects: {', '.join(name for name, _ in self.model.effects) or 'none'}"
            + (f", obstacle at {self.p['obstacle_stroke_limit_deg']:g} deg over {self.windows_s} s" if self.windows_s else "")
        )

    def on_command(self, data: bytes) -> None:
        try:
            message = self.drive_codec.decode(data)
        except cdr.CdrError as exc:
            self.rejected_blocks += 1
            warn_counted(self.get_logger(), self.rejected_blocks,
                         f"rejected command block ({exc}); ignored [{self.rejected_blocks} rejected so far]")
            return
        first = int(message["first_sample_index"])
        drive_v = np.array(message["drive_v"], dtype=np.float64)
        rate_hz = float(message["sample_rate_hz"])
        # Fast path (every block of a healthy stream); check_block names what is wrong otherwise.
        if not (first == self.expected_command_index and len(drive_v) == self.block_size and rate_hz == self.fs_hz
                and np.isfinite(drive_v).all()):
            check = check_block({"drive_v": drive_v}, rate_hz, self.fs_hz, first, self.expected_command_index,
                                self.block_size)
            if not check.ok:
                self.rejected_blocks += 1
                action = {"stale": "ignored", "gap": "accepted after the gap", "content": "holding zero drive"}[check.kind]
                warn_counted(self.get_logger(), self.rejected_blocks,
                             f"rejected command block {first} ({check.reason}); {action} "
                             f"[{self.rejected_blocks} rejected so far]")
                if check.kind == "stale":
                    return  # a duplicate or stale block must not advance the plant again
                if check.kind == "content":
                    drive_v = np.zeros(self.block_size)
        self.expected_command_index = first + self.block_size
        self.last_command_wall = time.monotonic()
        if self.p["mode"] == "lockstep":
            if self.ring_down is not None:
                self.get_logger().info(f"drive commands resumed at block {first}; drive watchdog re-armed")
                self.ring_down = None
            self.driven = bool(np.any(drive_v != 0.0))
            self.commanded_samples += len(drive_v)
            self.advance(drive_v)
        else:
            self.pending.append(drive_v)

    def on_watchdog_tick(self) -> None:
        """Lockstep drive watchdog: trip on a silent, non-zero command source; pace the ring-down."""
        now = time.monotonic()
        if self.ring_down is None:
            silent_s = now - self.last_command_wall
            # Armed once commands have flowed for ARM_S of signal time: a controller's start-up
            # (first blocks unanswered until its retry) is not a dead source.
            armed = self.commanded_samples >= ARM_S * self.fs_hz
            if not (armed and self.driven and silent_s > self.p["command_timeout_s"]):
                return
            n_ring = int(round(self.p["ring_down_s"] * self.fs_hz / self.block_size)) * self.block_size
            self.ring_down = (now, self.next_index, self.next_index + n_ring)
            self.driven = False
            self.get_logger().error(
                f"DRIVE WATCHDOG: no command block for {1e3 * silent_s:.1f} ms (> command_timeout_s "
                f"{self.p['command_timeout_s']:g} s) after block {self.next_index - self.block_size}, last drive not zero: "
                f"drive zeroed, ringing down for {self.p['ring_down_s']:g} s")
        wall_start, first, end = self.ring_down
        due = min(end, first + int((now - wall_start) * self.fs_hz))
        zero = np.zeros(self.block_size)
        while self.next_index + self.block_size <= due:
            self.advance(zero)
        # the stream continues from here: a command for the next block is in order
        self.expected_command_index = self.next_index

    def on_realtime_tick(self) -> None:
        due = int((time.monotonic() - self.wall_start_s) * self.fs_hz) - self.next_index
        for _ in range(max(0, due // self.block_size)):
            drive_v = self.pending.popleft() if self.pending else np.zeros(self.block_size)
            self.advance(drive_v)

    def advance(self, drive_v: np.ndarray) -> None:
        """Step the model one block and publish its outputs."""
        limit = self.get_parameter("drive_limit_v").value
        drive_v = np.clip(drive_v, -limit, limit)
        start_s = self.next_index / self.fs_hz
        obstacle = any(a <= start_s < b for a, b in self.windows_s)
        self.state, out = plant.step(self.state, plant.PlantInputs(drive_v, self.noise_rng),
                                       plant.PlantStepParams(self.obstacle_model if obstacle else self.model, self.fs_hz))
        stroke_v, pitch_v = out.stroke_sensor_v, out.pitch_sensor_v
        stamp_ns = stamp_ns_of_sample(self.next_index, self.fs_hz)
        sensor = {"sample_rate_hz": self.fs_hz, "first_sample_index": self.next_index,
                  "stroke_sensor_v": stroke_v, "pitch_sensor_v": pitch_v}
        truth = {"sample_rate_hz": self.fs_hz, "first_sample_index": self.next_index,
                 "source": WingStateBlock.SOURCE_GROUND_TRUTH, "stroke_deg": np.degrees(out.stroke_rad),
                 "pitch_deg": np.degrees(out.pitch_rad), "stroke_velocity_deg_s": self.no_velocity,
                 "stroke_valid": self.all_valid, "pitch_valid": self.all_valid}
        self.next_index += len(drive_v)
        self.sensor_pub.publish(self.sensor_codec.encode(stamp_ns, sensor))
        self.truth_pub.publish(self.truth_codec.encode(stamp_ns, truth))
        if self.clock_pub is not None:
            self.clock_pub.publish(Clock(clock=stamp_from_time_s(self.next_index / self.fs_hz)))


def main(args: list[str] | None = None) -> int:
    return run_node(PlantNode, PARAMS, CONFIG_FILE, NODE_NAME, args)


if __name__ == "__main__":
    raise SystemExit(main())
