"""collision_monitor_node: per-wingbeat wing-collision verdicts from the sensor-derived wing state.

Subscribes to the estimated wing state (/flaair/wing_state) and, for drive-locked windows with
an estimated frequency, to the drive (/flaair/drive). Publishes a CollisionStatus for every
wingbeat (/flaair/collision/status) and a CollisionEvent at each onset and clearance
(/flaair/collision/events, reliable + transient-local). A thin shell over flaair_control.collision.

Windows (the core's per-wingbeat monitor): one wingbeat long, either
  * window_source drive: locked to the drive phase, window k = samples with
    floor(f n / fs + drive_phase_rad / 2 pi) = k; f = drive_frequency_hz, or, when that is 0,
    estimated from /flaair/drive: the core's stroke-locked window finder run on the drive
    signal (Schmitt trigger, +-drive_hysteresis_v) gives its upward crossings; f = periods /
    samples over the last frequency_average_wingbeats of them, the phase puts the window start
    on the last crossing. The monitor (re)locks when the estimate moves by more than
    relock_tolerance, and re-arms (the paper metric's record must hold one frequency): while
    the frequency moves, e.g. through the sync -> async transition, it re-arms at every step
    and decides nothing; for asynchronous flapping use window_source stroke; or
  * window_source stroke: between upward crossings of the measured stroke (no drive frequency,
    e.g. asynchronous flapping).
The drive and wing-state streams share the sample index (first_sample_index), as the plant
produces one sensor block per command block.

Decision (decision parameter):
  * paper (default): the paper's metric through collision.spectral_metric: FFT of the
    sensor-derived pitch over the last metric_wingbeats wingbeats vs a pure sine at the
    wingbeat frequency, RMSE over 0-metric_band_hz; onset after n_on consecutive wingbeats with
    RMSE >= threshold_deg (1 deg), clearance after n_off consecutive wingbeats with
    RMSE < off_level x threshold_deg. The FFT record spans metric_wingbeats, so a new
    obstacle needs a few wingbeats to raise it (about 6 at 100 Hz on the simulated robot).
  * distortion: the core monitor's own per-wingbeat decision (residual of a one-wingbeat sine
    fit, stroke_threshold / pitch_threshold, n_on / n_off / off_level), about 1 wingbeat.
Both report the paper figures (spectrum_rmse_deg, time_rmse_deg; NaN until metric_wingbeats
valid wingbeats are available). Wingbeats during the first arm_wingbeats (start-up), with the
stroke below min_amplitude_deg (IDLE: count as clear) or holding an invalid sample (INVALID: no
decision) are reported with colliding unchanged.

Usage: bin/flaair run flaair_control collision_monitor_node [--ros-args -p drive_frequency_hz:=100.0]
"""
from __future__ import annotations

import math

import numpy as np
from rclpy.node import Node

from flaair_common import topics
from flaair_common.blocks import check_block, stamp_from_time_s, time_s_from_stamp
from flaair_common.params import ParameterError, ParamSpec, declare_parameters
from flaair_common.qos import BLOCK_STREAM, EVENTS, STATUS
from flaair_common.runtime import run_node, warn_counted
from flaair_control import collision as col
from flaair_msgs.msg import CollisionEvent, CollisionStatus, DriveCommandBlock, WingStateBlock

NODE_NAME = "collision_monitor_node"
CONFIG_FILE = "flaair.yaml"
PARAMS = [
    ParamSpec("sample_rate_hz", float, "Sample rate of the wing-state blocks [Hz]", 1000.0, 1.0e6, read_only=True),
    ParamSpec("block_size", int, "Samples per block", 1, 100000, read_only=True),
    ParamSpec("window_source", str, "Wingbeat windows locked to the drive or to the measured stroke", choices=("drive", "stroke"), read_only=True),
    ParamSpec("drive_frequency_hz", float, "drive windows: drive frequency (0: estimate from /flaair/drive) [Hz]", 0.0, 2500.0, read_only=True),
    ParamSpec("drive_phase_rad", float, "drive windows with a known frequency: window starts where 2 pi f t + phase = 2 pi k [rad]", -10.0, 10.0, read_only=True),
    ParamSpec("drive_hysteresis_v", float, "Drive-frequency estimate: Schmitt hysteresis on the drive [V]", 0.0, 100.0, read_only=True),
    ParamSpec("frequency_average_wingbeats", int, "Drive-frequency estimate: wingbeats averaged", 1, 1000, read_only=True),
    ParamSpec("relock_tolerance", float, "Re-lock the drive windows when the estimate moves by this fraction [-]", 1e-6, 1.0, read_only=True),
    ParamSpec("decision", str, "Which metric decides onset/clearance", choices=("paper", "distortion"), read_only=True),
    ParamSpec("threshold_deg", float, "paper: spectral RMSE threshold [deg]", 1e-6, 90.0, read_only=True),
    ParamSpec("metric_wingbeats", int, "paper: wingbeats in the FFT record", 1, 1000, read_only=True),
    ParamSpec("metric_band_hz", float, "paper: RMSE over 0..this [Hz]", 1.0, 1e5, read_only=True),
    ParamSpec("stroke_threshold", float, "distortion: stroke distortion ratio scored 1 [-]", 1e-6, 10.0, read_only=True),
    ParamSpec("pitch_threshold", float, "distortion: pitch distortion ratio scored 1 [-]", 1e-6, 10.0, read_only=True),
    ParamSpec("off_level", float, "Clearance level as a fraction of the onset threshold [-]", 1e-6, 1.0, read_only=True),
    ParamSpec("n_on", int, "Consecutive wingbeats above the threshold for an onset", 1, 1000, read_only=True),
    ParamSpec("n_off", int, "Consecutive wingbeats below off_level for a clearance", 1, 1000, read_only=True),
    ParamSpec("arm_wingbeats", int, "Wingbeats ignored after start or re-lock (start-up transient)", 0, 100000, read_only=True),
    ParamSpec("min_amplitude_deg", float, "Stroke amplitude below which a wingbeat is IDLE (not flapping) [deg]", 0.0, 90.0, read_only=True),
    ParamSpec("crossing_hysteresis_deg", float, "stroke windows: Schmitt hysteresis [deg]", 0.0, 90.0, read_only=True),
    ParamSpec("min_wingbeat_hz", float, "Slowest wingbeat (longer windows are IDLE) [Hz]", 1.0, 1000.0, read_only=True),
    ParamSpec("max_wingbeat_hz", float, "Fastest accepted wingbeat (stroke windows) [Hz]", 1.0, 5000.0, read_only=True),
    ParamSpec("stroke_noise_rms_deg", float, "distortion: stroke sensor noise removed in quadrature [deg]", 0.0, 10.0, read_only=True),
    ParamSpec("pitch_noise_rms_deg", float, "distortion: pitch sensor noise removed in quadrature [deg]", 0.0, 10.0, read_only=True),
]


class CollisionMonitorNode(Node):
    """Thin shell over flaair_control.collision (monitor windows, paper metric)."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        p = self.p = declare_parameters(self, PARAMS, CONFIG_FILE)
        self.fs_hz = p["sample_rate_hz"]
        self.block_size = p["block_size"]
        if p["min_wingbeat_hz"] >= p["max_wingbeat_hz"]:
            raise ParameterError("parameter 'min_wingbeat_hz' must be below 'max_wingbeat_hz'")
        try:
            self.metric_params = col.SpectralMetricParams(band_hz=p["metric_band_hz"], threshold_deg=p["threshold_deg"],
                                                          n_wingbeats=p["metric_wingbeats"])
            estimate = p["window_source"] == "drive" and p["drive_frequency_hz"] == 0.0
            self.params: col.MonitorParams | None = None
            if not estimate:
                self.params = self._monitor_params(p["drive_frequency_hz"] or None, p["drive_phase_rad"])
            # Drive-frequency estimator: the core's stroke-locked window finder on the drive signal.
            self.drive_params = col.MonitorParams(
                self.fs_hz, window_source="stroke", use_pitch=False, arm_wingbeats=0,
                crossing_hysteresis_rad=p["drive_hysteresis_v"], min_amplitude_rad=p["drive_hysteresis_v"],
                min_period_s=1.0 / p["max_wingbeat_hz"], max_period_s=1.0 / p["min_wingbeat_hz"],
            ) if estimate else None
        except col.CollisionParameterError as exc:
            raise ParameterError(str(exc)) from exc
        self.state = col.initial_state(self.params) if self.params is not None else None
        self.drive_state = col.initial_state(self.drive_params) if self.drive_params is not None else None
        self.drive_expected: int | None = None
        self.drive_starts: list[int] = []
        self.locked_hz = 0.0
        self.expected_index: int | None = None
        self.time_offset_s: float | None = None   # header time - index / fs
        history = int(math.ceil((p["metric_wingbeats"] + 2) * self.fs_hz / p["min_wingbeat_hz"])) + self.block_size
        self.pitch_history = np.full(history, np.nan)
        self.history_end = 0                      # absolute index one past the last stored sample
        self.colliding = False
        self.above = 0
        self.below = 0
        self.wingbeats = 0
        self.rejected = 0
        self.status_pub = self.create_publisher(CollisionStatus, topics.COLLISION_STATUS, STATUS)
        self.event_pub = self.create_publisher(CollisionEvent, topics.COLLISION_EVENTS, EVENTS)
        self.create_subscription(WingStateBlock, topics.WING_STATE, self.on_wing_state, BLOCK_STREAM)
        if self.drive_params is not None:
            self.create_subscription(DriveCommandBlock, topics.DRIVE, self.on_drive, BLOCK_STREAM)
        where = (f"drive windows at {p['drive_frequency_hz']:g} Hz" if self.params is not None and p["window_source"] == "drive"
                 else "drive windows, frequency estimated from /flaair/drive" if estimate else "stroke windows")
        self.get_logger().info(
            f"collision monitor ready: {where}; decision {p['decision']} "
            + (f"(pitch FFT RMSE over {p['metric_wingbeats']} wingbeats, 0-{p['metric_band_hz']:g} Hz, "
               f"threshold {p['threshold_deg']:g} deg)" if p["decision"] == "paper" else
               f"(distortion: stroke {p['stroke_threshold']:g}, pitch {p['pitch_threshold']:g})")
            + f"; onset after {p['n_on']}, clearance after {p['n_off']} wingbeats"
        )

    def _monitor_params(self, frequency_hz: float | None, phase_rad: float) -> col.MonitorParams:
        p = self.p
        return col.MonitorParams(
            self.fs_hz, window_source=p["window_source"], drive_frequency_hz=frequency_hz, drive_phase_rad=phase_rad,
            stroke_threshold=p["stroke_threshold"], pitch_threshold=p["pitch_threshold"], off_level=p["off_level"],
            n_on=p["n_on"], n_off=p["n_off"], arm_wingbeats=p["arm_wingbeats"],
            min_amplitude_rad=math.radians(p["min_amplitude_deg"]),
            stroke_noise_rms_rad=math.radians(p["stroke_noise_rms_deg"]),
            pitch_noise_rms_rad=math.radians(p["pitch_noise_rms_deg"]),
            crossing_hysteresis_rad=math.radians(p["crossing_hysteresis_deg"]),
            min_period_s=1.0 / p["max_wingbeat_hz"], max_period_s=1.0 / p["min_wingbeat_hz"],
        )

    # ------------------------------------------------------------------ drive-frequency estimate
    def on_drive(self, message: DriveCommandBlock) -> None:
        drive_v = np.frombuffer(message.drive_v, dtype=np.float64) if len(message.drive_v) else np.zeros(0)
        check = check_block({"drive_v": drive_v}, message.sample_rate_hz, self.fs_hz, message.first_sample_index,
                            self.drive_expected)
        if not check.ok and check.kind != "gap":
            return
        if self.drive_expected is None or check.kind == "gap":
            self.drive_state = col.initial_state(self.drive_params, message.first_sample_index)
            self.drive_starts.clear()
        self.drive_expected = message.first_sample_index + len(drive_v)
        self.drive_state, report, _ = col.step(self.drive_state, drive_v, np.zeros_like(drive_v), self.drive_params)
        for start, status in zip(report.start_index.tolist(), report.status.tolist()):
            if status == col.IDLE:
                self.drive_starts.clear()   # not driven: no frequency
                continue
            self.drive_starts.append(start)
        need = self.p["frequency_average_wingbeats"] + 1
        if len(self.drive_starts) > need:
            del self.drive_starts[:-need]
        if len(self.drive_starts) == need and report.start_index.size:
            first, last = self.drive_starts[0], self.drive_starts[-1]
            f = (need - 1) * self.fs_hz / (last - first)
            if self.locked_hz == 0.0 or abs(f - self.locked_hz) > self.p["relock_tolerance"] * self.locked_hz:
                self.lock(f, last)

    def lock(self, frequency_hz: float, crossing_index: int) -> None:
        """(Re)start the drive-locked monitor at ``frequency_hz`` with a window starting at ``crossing_index``."""
        phase = (-2 * math.pi * frequency_hz * crossing_index / self.fs_hz) % (2 * math.pi)
        try:
            self.params = self._monitor_params(frequency_hz, phase)
        except col.CollisionParameterError as exc:
            self.get_logger().warning(f"drive frequency estimate {frequency_hz:.2f} Hz refused: {exc}",
                                      throttle_duration_sec=1.0)
            return
        self.get_logger().info(f"drive windows locked at {frequency_hz:.3f} Hz"
                               + (f" (was {self.locked_hz:.3f} Hz; monitor re-armed)" if self.locked_hz else ""))
        self.locked_hz = frequency_hz
        start = self.expected_index if self.expected_index is not None else crossing_index
        self.state = col.initial_state(self.params, start)

    # ------------------------------------------------------------------ wing state
    def on_wing_state(self, message: WingStateBlock) -> None:
        n = len(message.stroke_deg)
        stroke = np.frombuffer(message.stroke_deg, dtype=np.float64) if n else np.zeros(0)
        pitch = np.frombuffer(message.pitch_deg, dtype=np.float64) if len(message.pitch_deg) else np.zeros(0)
        check = check_block({"stroke_deg": np.zeros(n), "pitch_deg": np.zeros(len(pitch))}, message.sample_rate_hz,
                            self.fs_hz, message.first_sample_index, self.expected_index)
        if not check.ok and check.kind != "gap":
            self.rejected += 1
            text = f"wing-state block {message.first_sample_index}: {check.reason} [{self.rejected} rejected so far]"
            warn_counted(self.get_logger(), self.rejected, text)
            return
        if self.time_offset_s is None:
            self.time_offset_s = time_s_from_stamp(message.header.stamp) - message.first_sample_index / self.fs_hz
        if check.kind == "gap" and self.params is not None:
            self.get_logger().warning(f"wing-state {check.reason}; monitor restarted")
            self.state = col.initial_state(self.params, message.first_sample_index)
        self.expected_index = message.first_sample_index + n
        s_ok = np.asarray(message.stroke_valid, dtype=bool) if len(message.stroke_valid) == n else np.zeros(n, bool)
        p_ok = np.asarray(message.pitch_valid, dtype=bool) if len(message.pitch_valid) == n else np.zeros(n, bool)
        stroke_rad = np.where(s_ok, np.radians(stroke), np.nan)
        pitch_rad = np.where(p_ok, np.radians(pitch), np.nan)
        self.store_pitch(message.first_sample_index, pitch_rad)
        if self.state is None:
            return  # drive frequency not known yet
        if self.state.tail_start_index + self.state.tail_stroke_rad.size != message.first_sample_index:
            self.state = col.initial_state(self.params, message.first_sample_index)  # locked off this stream position
        self.state, report, events = col.step(self.state, stroke_rad, pitch_rad, self.params)
        for k in range(report.wingbeat.size):
            self.judge(report, k, events)

    def store_pitch(self, first_index: int, pitch_rad: np.ndarray) -> None:
        """Keep the last samples of pitch for the paper metric (ring shifted by whole blocks)."""
        h = self.pitch_history
        n = pitch_rad.size
        if first_index != self.history_end:
            h[:] = np.nan
        if n >= h.size:
            h[:] = pitch_rad[-h.size:]
        else:
            h[:-n] = h[n:]
            h[-n:] = pitch_rad
        self.history_end = first_index + n

    def paper_metric(self, end_index: int, frequency_hz: float) -> col.SpectralMetric | None:
        """Paper metric of the pitch over the metric_wingbeats wingbeats ending at ``end_index``."""
        if not (math.isfinite(frequency_hz) and frequency_hz > 0):
            return None
        n = int(math.ceil(self.p["metric_wingbeats"] * self.fs_hz / frequency_hz))
        stop = self.pitch_history.size - (self.history_end - end_index)
        if stop > self.pitch_history.size or stop - n < 0:
            return None
        x = self.pitch_history[stop - n:stop]
        if not np.isfinite(x).all():
            return None
        try:
            return col.spectral_metric(x, self.fs_hz, frequency_hz, self.metric_params)
        except col.CollisionParameterError:
            return None

    def judge(self, report: col.WingbeatReport, k: int, core_events: list[col.MonitorEvent]) -> None:
        status = int(report.status[k])
        end = int(report.end_index[k])
        frequency = float(report.frequency_hz[k])
        metric = self.paper_metric(end, frequency) if status not in (col.INVALID, col.ARMING) else None
        rmse = metric.spectral_rmse_deg if metric is not None else math.nan
        event_kind = None
        if self.p["decision"] == "distortion":
            for ev in core_events:
                if ev.wingbeat == int(report.wingbeat[k]):
                    event_kind = CollisionEvent.ONSET if ev.kind == col.ONSET else CollisionEvent.CLEARANCE
        elif status in (col.CLEAR, col.COLLISION, col.IDLE):
            threshold = self.p["threshold_deg"]
            if status == col.IDLE or (metric is not None and rmse < self.p["off_level"] * threshold):
                self.above, self.below = 0, self.below + 1
            elif metric is not None and rmse >= threshold:
                self.above, self.below = self.above + 1, 0
            else:  # hysteresis band, or not enough history yet: hold
                self.above, self.below = 0, 0
            if not self.colliding and self.above >= self.p["n_on"]:
                event_kind = CollisionEvent.ONSET
            elif self.colliding and self.below >= self.p["n_off"]:
                event_kind = CollisionEvent.CLEARANCE
        stamp = stamp_from_time_s((self.time_offset_s or 0.0) + end / self.fs_hz)
        if event_kind is not None:
            self.colliding = event_kind == CollisionEvent.ONSET
            event = CollisionEvent(kind=event_kind, wingbeat_index=self.wingbeats, spectrum_rmse_deg=rmse)
            event.header.stamp = stamp
            self.event_pub.publish(event)
            text = (f"at wingbeat {self.wingbeats} (t = {end / self.fs_hz:.4f} s, {frequency:.1f} Hz): "
                    f"pitch spectrum RMSE {rmse:.3f} deg (threshold {self.p['threshold_deg']:g} deg), "
                    f"distortion score {float(report.score[k]):.2f}")
            # rclpy fixes a call site's severity at its first call: one call site per severity.
            if self.colliding:
                self.get_logger().warning(f"collision ONSET {text}")
            else:
                self.get_logger().info(f"collision CLEARANCE {text}")
        out = CollisionStatus(wingbeat_index=self.wingbeats, wingbeat_frequency_hz=frequency, colliding=self.colliding,
                              spectrum_rmse_deg=rmse,
                              time_rmse_deg=metric.time_rmse_deg if metric is not None else math.nan,
                              threshold_deg=self.p["threshold_deg"])
        out.header.stamp = stamp
        self.status_pub.publish(out)
        self.wingbeats += 1


def main(args: list[str] | None = None) -> int:
    return run_node(CollisionMonitorNode, PARAMS, CONFIG_FILE, NODE_NAME, args)


if __name__ == "__main__":
    raise SystemExit(main())
