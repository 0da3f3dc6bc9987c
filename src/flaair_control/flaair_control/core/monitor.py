"""Collision monitor core: what the collision monitor node decides, as a pure step function.

One ``step(state, inputs, params) -> (state, outputs)`` takes either a drive block
(`DriveBlock`, for the drive-frequency lock) or a wing-state block (`WingBlock`) and returns
the per-wingbeat verdicts it closes. The node and offline replay (a recorded bag) call the
same function in the same order, so a bag replays to the live run's events exactly.

Parts (each also usable alone):
  * drive lock (`lock_step`): the core's stroke-locked window finder run on the drive signal
    (Schmitt trigger, +-drive_hysteresis_v) gives its upward crossings; the frequency is
    periods / samples over the last frequency_average_wingbeats of them and the window phase
    puts a window start on the last crossing. The monitor (re)locks when the estimate moves by
    more than relock_tolerance (and re-arms: the metric record must hold one frequency);
  * wingbeat windows and the distortion score: `flaair_control.core.collision` (per wingbeat);
  * the paper's metric: the FFT of the sensor-derived pitch over the last metric_wingbeats
    wingbeats against a pure sine (`collision.spectral_metric`), from a pitch history kept
    in the state;
  * the decision: ``distortion`` (the per-wingbeat score, about one wingbeat to detect) or
    ``paper`` (spectral RMSE >= threshold_deg for n_on wingbeats; clearance after n_off below
    off_level x threshold_deg).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from flaair_control.core import collision as col
from flaair_control.core import spectral
from flaair_model.notes import INFO, Note

__all__ = [
    "CLEARANCE",
    "ONSET",
    "CollisionMonitorParams",
    "CollisionMonitorState",
    "DriveBlock",
    "DriveLockState",
    "Lock",
    "MonitorOutputs",
    "Verdict",
    "WingBlock",
    "drive_lock_params",
    "initial_state",
    "lock_step",
    "metric_params",
    "step",
    "window_params",
    "wing_block",
]


ONSET = "onset"
CLEARANCE = "clearance"


@dataclass(frozen=True)
class CollisionMonitorParams:
    """Every setting of the monitor (config/flaair.yaml
    `collision_monitor_node`; units in names).
    """

    sample_rate_hz: float
    block_size: int
    window_source: str  # "drive" or "stroke"
    drive_frequency_hz: float  # drive windows: 0 = estimate from the drive stream
    drive_phase_rad: float
    drive_hysteresis_v: float
    frequency_average_wingbeats: int
    relock_tolerance: float
    decision: str  # "distortion" or "paper"
    threshold_deg: float
    metric_wingbeats: int
    metric_band_hz: float
    stroke_threshold: float
    pitch_threshold: float
    off_level: float
    n_on: int
    n_off: int
    arm_wingbeats: int
    min_amplitude_deg: float
    crossing_hysteresis_deg: float
    min_wingbeat_hz: float
    max_wingbeat_hz: float
    stroke_noise_rms_deg: float
    pitch_noise_rms_deg: float

    def __post_init__(self) -> None:
        if self.decision not in ("distortion", "paper"):
            raise spectral.CollisionParameterError(
                f"decision must be 'distortion' or 'paper', got {self.decision!r}"
            )
        if self.min_wingbeat_hz >= self.max_wingbeat_hz:
            raise spectral.CollisionParameterError("min_wingbeat_hz must be below max_wingbeat_hz")
        metric_params(self)
        if not self.estimates_frequency:
            window_params(self, self.drive_frequency_hz or None, self.drive_phase_rad)
        else:
            drive_lock_params(self)

    @property
    def estimates_frequency(self) -> bool:
        """Drive windows whose frequency comes from the drive stream."""
        return self.window_source == "drive" and self.drive_frequency_hz == 0.0

    @property
    def history_samples(self) -> int:
        """Pitch samples kept for the paper metric
        (metric_wingbeats + 2 of the slowest wingbeat).
        """
        return (
            math.ceil((self.metric_wingbeats + 2) * self.sample_rate_hz / self.min_wingbeat_hz)
            + self.block_size
        )


@lru_cache(maxsize=64)
def metric_params(p: CollisionMonitorParams) -> spectral.SpectralMetricParams:
    """The paper metric's settings."""
    return spectral.SpectralMetricParams(
        band_hz=p.metric_band_hz, threshold_deg=p.threshold_deg, n_wingbeats=p.metric_wingbeats
    )


@lru_cache(maxsize=256)
def window_params(
    p: CollisionMonitorParams, frequency_hz: float | None, phase_rad: float
) -> col.MonitorParams:
    """Per-wingbeat window monitor at a drive frequency (None: stroke windows)."""
    return col.MonitorParams(
        p.sample_rate_hz,
        window_source=p.window_source,
        drive_frequency_hz=frequency_hz,
        drive_phase_rad=phase_rad,
        stroke_threshold=p.stroke_threshold,
        pitch_threshold=p.pitch_threshold,
        use_pitch=True,
        off_level=p.off_level,
        n_on=p.n_on,
        n_off=p.n_off,
        arm_wingbeats=p.arm_wingbeats,
        min_amplitude_rad=math.radians(p.min_amplitude_deg),
        stroke_noise_rms_rad=math.radians(p.stroke_noise_rms_deg),
        pitch_noise_rms_rad=math.radians(p.pitch_noise_rms_deg),
        crossing_hysteresis_rad=math.radians(p.crossing_hysteresis_deg),
        min_period_s=1.0 / p.max_wingbeat_hz,
        max_period_s=1.0 / p.min_wingbeat_hz,
    )


@lru_cache(maxsize=64)
def drive_lock_params(p: CollisionMonitorParams) -> col.MonitorParams:
    """The stroke-window finder run on the drive signal (volts), for the drive-frequency lock."""
    return col.MonitorParams(
        p.sample_rate_hz,
        window_source="stroke",
        drive_frequency_hz=None,
        drive_phase_rad=0.0,
        stroke_threshold=p.stroke_threshold,
        pitch_threshold=p.pitch_threshold,
        use_pitch=False,
        off_level=p.off_level,
        n_on=p.n_on,
        n_off=p.n_off,
        arm_wingbeats=0,
        min_amplitude_rad=p.drive_hysteresis_v,
        stroke_noise_rms_rad=0.0,
        pitch_noise_rms_rad=0.0,
        crossing_hysteresis_rad=p.drive_hysteresis_v,
        min_period_s=1.0 / p.max_wingbeat_hz,
        max_period_s=1.0 / p.min_wingbeat_hz,
    )


# --------------------------------------------------------------------------- drive lock


class DriveLockState(NamedTuple):
    """Drive-frequency estimator state."""

    finder: col.MonitorState | None  # window finder on the drive (None before the first block)
    expected_index: int | None  # first sample index of the next drive block
    crossings: tuple[int, ...]  # last upward crossings (absolute sample index)
    locked_hz: float  # 0 until locked


class Lock(NamedTuple):
    """A new drive lock: windows start where 2 pi f n / fs + phase = 2 pi k."""

    frequency_hz: float
    phase_rad: float
    crossing_index: int
    previous_hz: float


def lock_step(
    state: DriveLockState, block: DriveBlock, p: CollisionMonitorParams
) -> tuple[DriveLockState, Lock | None]:
    """Feed one drive block to the frequency estimator; returns a `Lock` when it (re)locks."""
    finder = state.finder
    crossings = state.crossings
    if state.expected_index is None or block.first_sample_index != state.expected_index:
        finder = col.initial_state(drive_lock_params(p), start_index=block.first_sample_index)
        crossings = ()
    assert finder is not None  # started above when the stream (re)starts
    drive_v = np.asarray(block.drive_v, dtype=float)
    finder, out = col.step(
        finder, col.MonitorInputs(drive_v, np.zeros_like(drive_v)), drive_lock_params(p)
    )
    kept = list(crossings)
    for start, status in zip(
        out.report.start_index.tolist(), out.report.status.tolist(), strict=True
    ):
        if status == col.IDLE:
            kept.clear()  # not driven: no frequency
        else:
            kept.append(start)
    need = p.frequency_average_wingbeats + 1
    kept = kept[-need:]
    state = DriveLockState(
        finder, block.first_sample_index + drive_v.size, tuple(kept), state.locked_hz
    )
    if len(kept) < need or out.report.start_index.size == 0:
        return state, None
    f = (need - 1) * p.sample_rate_hz / (kept[-1] - kept[0])
    if state.locked_hz != 0.0 and abs(f - state.locked_hz) <= p.relock_tolerance * state.locked_hz:
        return state, None
    phase = (-2 * math.pi * f * kept[-1] / p.sample_rate_hz) % (2 * math.pi)
    return state._replace(locked_hz=f), Lock(f, phase, kept[-1], state.locked_hz)


# --------------------------------------------------------------------------- monitor


class DriveBlock(NamedTuple):
    """One /flaair/drive block (the drive-frequency lock's input)."""

    first_sample_index: int
    drive_v: np.ndarray


class WingBlock(NamedTuple):
    """One /flaair/wing_state block as angles (rad; NaN where the sample is not valid)."""

    first_sample_index: int
    stroke_rad: np.ndarray
    pitch_rad: np.ndarray


def wing_block(
    first_sample_index: int,
    stroke_deg: ArrayLike,
    pitch_deg: ArrayLike,
    stroke_valid: ArrayLike,
    pitch_valid: ArrayLike,
) -> WingBlock:
    """A wing-state block's fields as the core's input: rad, NaN where a sample is not valid
    (validity flags of the wrong length mark the whole channel invalid).
    """
    stroke, pitch = (
        np.asarray(stroke_deg, dtype=np.float64),
        np.asarray(pitch_deg, dtype=np.float64),
    )
    s_valid, p_valid = np.asarray(stroke_valid, dtype=bool), np.asarray(pitch_valid, dtype=bool)
    s_ok = s_valid if len(s_valid) == len(stroke) else np.zeros(len(stroke), bool)
    p_ok = p_valid if len(p_valid) == len(pitch) else np.zeros(len(pitch), bool)
    return WingBlock(
        int(first_sample_index),
        np.where(s_ok, np.radians(stroke), np.nan),
        np.where(p_ok, np.radians(pitch), np.nan),
    )


class Verdict(NamedTuple):
    """One closed wingbeat: what the monitor publishes as CollisionStatus (+ CollisionEvent)."""

    wingbeat_index: int
    end_index: int  # one past the wingbeat's last sample
    frequency_hz: float
    colliding: bool
    spectrum_rmse_deg: float  # paper metric (NaN until metric_wingbeats valid wingbeats)
    time_rmse_deg: float
    score: float  # per-wingbeat distortion score (1 = threshold)
    event: str | None  # ONSET, CLEARANCE or None


class MonitorOutputs(NamedTuple):
    """Verdicts of the wingbeats a block closed, and notes worth a log line."""

    verdicts: tuple[Verdict, ...]
    notes: tuple[Note, ...]


class CollisionMonitorState(NamedTuple):
    """Monitor state between blocks (arrays are read-only;
    a NamedTuple, so ``_replace`` is cheap).
    """

    windows: col.MonitorParams | None  # None: drive frequency not known yet
    monitor: col.MonitorState | None
    lock: DriveLockState
    expected_index: int | None  # first sample index of the next wing-state block
    stroke_history_rad: np.ndarray  # last history_samples stroke samples (NaN = none)
    pitch_history_rad: np.ndarray  # last history_samples pitch samples (NaN = none)
    history_end: int  # absolute index one past the last stored sample
    colliding: bool
    above: int
    below: int
    wingbeats: int


def initial_state(p: CollisionMonitorParams) -> CollisionMonitorState:
    """Monitor before the first block."""
    windows = (
        None
        if p.estimates_frequency
        else window_params(p, p.drive_frequency_hz or None, p.drive_phase_rad)
    )
    history = np.full(p.history_samples, np.nan)
    history.flags.writeable = False
    return CollisionMonitorState(
        windows,
        None,
        DriveLockState(None, None, (), 0.0),
        None,
        history,
        history,
        0,
        False,
        0,
        0,
        0,
    )


def step(
    state: CollisionMonitorState, inputs: DriveBlock | WingBlock, p: CollisionMonitorParams
) -> tuple[CollisionMonitorState, MonitorOutputs]:
    """Advance the monitor by one drive block or one wing-state block."""
    if isinstance(inputs, DriveBlock):
        return _on_drive(state, inputs, p)
    return _on_wing(state, inputs, p)


def _on_drive(
    state: CollisionMonitorState, block: DriveBlock, p: CollisionMonitorParams
) -> tuple[CollisionMonitorState, MonitorOutputs]:
    if not p.estimates_frequency:
        return state, MonitorOutputs((), ())
    lock_state, lock = lock_step(state.lock, block, p)
    state = state._replace(lock=lock_state)
    if lock is None:
        return state, MonitorOutputs((), ())
    try:
        windows = window_params(p, lock.frequency_hz, lock.phase_rad)
    except spectral.CollisionParameterError as exc:
        return state, MonitorOutputs(
            (), (Note(INFO, f"drive frequency estimate {lock.frequency_hz:.2f} Hz refused: {exc}"),)
        )
    note = Note(
        INFO,
        f"drive windows locked at {lock.frequency_hz:.3f} Hz"
        + (f" (was {lock.previous_hz:.3f} Hz; monitor re-armed)" if lock.previous_hz else ""),
    )
    # The windows start at the lock's crossing, whichever stream is ahead: the verdicts do not
    # depend on how the drive and wing-state blocks interleaved (live and replay agree).
    start = lock.crossing_index
    monitor = col.initial_state(windows, start_index=start)
    state = state._replace(windows=windows, monitor=monitor)
    behind = state.history_end - start  # wing samples already received past the crossing
    if state.expected_index is None or behind <= 0:
        return state, MonitorOutputs((), (note,))
    if behind > state.pitch_history_rad.size:  # history too short: start at the wing stream
        return (
            state._replace(monitor=col.initial_state(windows, start_index=state.history_end)),
            MonitorOutputs((), (note,)),
        )
    state, verdicts = _feed(
        state, monitor, state.stroke_history_rad[-behind:], state.pitch_history_rad[-behind:], p
    )
    return state, MonitorOutputs(verdicts, (note,))


def _store(history: np.ndarray, end: int, first_index: int, x: np.ndarray) -> np.ndarray:
    """A history with this block appended (cleared on a discontinuity)."""
    n = x.size
    if first_index != end:
        history = np.full(history.size, np.nan)
    out = (
        np.concatenate([history, x])[-history.size :]
        if n < history.size
        else x[-history.size :].copy()
    )
    out.flags.writeable = False
    return out


def _paper_metric(
    history: np.ndarray,
    history_end: int,
    end_index: int,
    frequency_hz: float,
    p: CollisionMonitorParams,
) -> spectral.SpectralMetric | None:
    """The paper metric over the metric_wingbeats wingbeats ending at ``end_index``."""
    if not (math.isfinite(frequency_hz) and frequency_hz > 0):
        return None
    n = math.ceil(p.metric_wingbeats * p.sample_rate_hz / frequency_hz)
    stop = history.size - (history_end - end_index)
    if stop > history.size or stop - n < 0:
        return None
    x = history[stop - n : stop]
    if not np.isfinite(x).all():
        return None
    try:
        return spectral.spectral_metric(x, p.sample_rate_hz, frequency_hz, metric_params(p))
    except spectral.CollisionParameterError:
        return None


def _on_wing(
    state: CollisionMonitorState, block: WingBlock, p: CollisionMonitorParams
) -> tuple[CollisionMonitorState, MonitorOutputs]:
    first = block.first_sample_index
    stroke = np.asarray(block.stroke_rad, dtype=float)
    pitch = np.asarray(block.pitch_rad, dtype=float)
    notes: list[Note] = []
    monitor = state.monitor
    if (
        state.expected_index is not None
        and first != state.expected_index
        and state.windows is not None
    ):
        notes.append(
            Note(
                INFO,
                f"wing-state block {first} after {state.expected_index - 1}: monitor restarted",
            )
        )
        monitor = None
    state = state._replace(
        expected_index=first + stroke.size,
        stroke_history_rad=_store(state.stroke_history_rad, state.history_end, first, stroke),
        pitch_history_rad=_store(state.pitch_history_rad, state.history_end, first, pitch),
        history_end=first + stroke.size,
    )
    if state.windows is None:
        return state, MonitorOutputs((), tuple(notes))  # drive frequency not known yet
    if monitor is None:
        monitor = col.initial_state(state.windows, start_index=first)
    # > 0: windows start inside/after
    skip = monitor.tail_start_index + monitor.tail_stroke_rad.size - first
    if skip < 0:
        # off this stream position: restart here
        monitor = col.initial_state(state.windows, start_index=first)
        skip = 0
    if skip >= stroke.size:
        return state._replace(monitor=monitor), MonitorOutputs((), tuple(notes))
    state, verdicts = _feed(state, monitor, stroke[skip:], pitch[skip:], p)
    return state, MonitorOutputs(verdicts, tuple(notes))


def _feed(
    state: CollisionMonitorState,
    monitor: col.MonitorState,
    stroke: np.ndarray,
    pitch: np.ndarray,
    p: CollisionMonitorParams,
) -> tuple[CollisionMonitorState, tuple[Verdict, ...]]:
    """Run the window monitor on samples that continue it, and decide every wingbeat it closes."""
    assert state.windows is not None  # the caller feeds only once windows are known
    monitor, out = col.step(monitor, col.MonitorInputs(stroke, pitch), state.windows)
    verdicts = []
    colliding, above, below, wingbeats = state.colliding, state.above, state.below, state.wingbeats
    core_events = {ev.wingbeat: ev.kind for ev in out.events}
    report = out.report
    for k in range(report.wingbeat.size):
        status = int(report.status[k])
        end = int(report.end_index[k])
        frequency = float(report.frequency_hz[k])
        metric = (
            _paper_metric(state.pitch_history_rad, state.history_end, end, frequency, p)
            if status not in (col.INVALID, col.ARMING)
            else None
        )
        rmse = metric.spectral_rmse_deg if metric is not None else math.nan
        event = None
        if p.decision == "distortion":
            kind = core_events.get(int(report.wingbeat[k]))
            event = None if kind is None else ONSET if kind == col.ONSET else CLEARANCE
        elif status in (col.CLEAR, col.COLLISION, col.IDLE):
            if status == col.IDLE or (metric is not None and rmse < p.off_level * p.threshold_deg):
                above, below = 0, below + 1
            elif metric is not None and rmse >= p.threshold_deg:
                above, below = above + 1, 0
            else:  # hysteresis band, or not enough history yet: hold
                above, below = 0, 0
            if not colliding and above >= p.n_on:
                event = ONSET
            elif colliding and below >= p.n_off:
                event = CLEARANCE
        if event is not None:
            colliding = event == ONSET
        verdicts.append(
            Verdict(
                wingbeats,
                end,
                frequency,
                colliding,
                rmse,
                metric.time_rmse_deg if metric is not None else math.nan,
                float(report.score[k]),
                event,
            )
        )
        wingbeats += 1
    state = state._replace(
        monitor=monitor, colliding=colliding, above=above, below=below, wingbeats=wingbeats
    )
    return state, tuple(verdicts)
