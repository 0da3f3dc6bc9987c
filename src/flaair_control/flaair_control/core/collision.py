r"""Wing-collision metric (paper, section Applications) and a per-wingbeat collision monitor.

Pure numpy; explicit state; SI inside (rad), degrees only in the reported figures (``*_deg``).

The paper's metric itself (FFT RMSE against a drive-frequency sine) is
``flaair_control.core.spectral`` (import its names from there).

2. Per-wingbeat monitor (``MonitorParams``, ``initial_state``, ``step``)
-----------------------------------------------------------------------
Windows one wingbeat long, either locked to the drive phase (``window_source="drive"``,
window k = samples n with floor(f n / fs + phase / 2pi) = k) or to the measured stroke
(``"stroke"``: between successive upward crossings of a Schmitt trigger of +-
``crossing_hysteresis_rad`` around the previous wingbeat's mean; for asynchronous flapping where
no drive frequency exists). In each window, per channel (stroke, pitch), a least-squares fit of
[1, t, cos wt, sin wt] (w = drive frequency, or 2pi / window length) and the distortion ratio

    d = rms(residual) / (A / sqrt(2)),   A = fundamental amplitude

(total harmonic distortion + noise); the known sensor-noise contribution (``*_noise_rms_rad``)
is removed in quadrature. The wingbeat score is max(d_stroke / stroke_threshold,
d_pitch / pitch_threshold). Decision with hysteresis: onset after ``n_on`` consecutive wingbeats
with score >= 1 (``on_level``), clearance after ``n_off`` consecutive wingbeats with score <
``off_level``. Windows whose stroke fundamental is below ``min_amplitude_rad`` are IDLE (not
flapping; count as clear), windows holding a non-finite sample are INVALID (no decision,
counters unchanged). The first ``arm_wingbeats`` windows (start-up transient: the free 140 Hz
mode is not yet damped and is indistinguishable from distortion) are ARMING. ``rearm`` restarts
that period (e.g. after a drive change).

Simulated margins (nominal model, sensor noise on, 60-200 Hz, 100/200 Vpp, steady state): the
stroke distortion stays below 1.3 % and the pitch distortion below 9 % (60 Hz, mostly noise and
the third harmonic near the 190 Hz pitch resonance); an obstacle at 20 deg against a 28 deg free
stroke (100 Hz, 75 V) gives 30 % and 69 %. Defaults 5 % / 25 % put the threshold a factor ~3
above the nominal worst case and ~3-6 below the collision.

``step`` is exact under block splitting: ``run`` is ``step`` on the whole record.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import numba
import numpy as np

from flaair_control.core.spectral import CollisionParameterError

# A closed window (start, end, omega rad/sample, idle); its features (A_stroke, A_pitch, d_stroke,
# d_pitch, score, usable); a report row (wingbeat, start, end, end time s, frequency Hz, A_stroke,
# A_pitch, d_stroke, d_pitch, score, status).
Window = tuple[int, int, float, bool]
Features = tuple[float, float, float, float, float, bool]
ReportRow = tuple[int, int, int, float, float, float, float, float, float, float, int]

__all__ = [
    "ARMING",
    "CLEAR",
    "CLEARANCE",
    "COLLISION",
    "IDLE",
    "INVALID",
    "ONSET",
    "MonitorEvent",
    "MonitorInputs",
    "MonitorOutputs",
    "MonitorParams",
    "MonitorState",
    "WingbeatReport",
    "concat_reports",
    "initial_state",
    "rearm",
    "run",
    "step",
]

# Wingbeat status codes.
ARMING = -1
CLEAR = 0
COLLISION = 1
IDLE = 2
INVALID = 3

# Event kinds.
ONSET = 1
CLEARANCE = 2


# --------------------------------------------------------------------------- per-wingbeat monitor


@dataclass(frozen=True)
class MonitorParams:
    """Per-wingbeat collision monitor parameters (see module docstring)."""

    sample_rate_hz: float
    window_source: str  # "drive" or "stroke"
    drive_frequency_hz: float | None  # required for "drive"
    drive_phase_rad: float  # window starts where 2 pi f t + phase = 2 pi k
    stroke_threshold: float  # stroke distortion ratio counted as score 1
    pitch_threshold: float  # pitch distortion ratio counted as score 1
    use_pitch: bool
    off_level: float
    n_on: int
    n_off: int
    arm_wingbeats: int
    min_amplitude_rad: float
    stroke_noise_rms_rad: float
    pitch_noise_rms_rad: float
    crossing_hysteresis_rad: float
    min_period_s: float  # stroke mode: shortest accepted wingbeat
    max_period_s: float  # stroke mode: longer = IDLE window
    on_level: float = 1.0  # scores are normalised: 1 = threshold

    def __post_init__(self) -> None:
        fs = self.sample_rate_hz
        if not (math.isfinite(fs) and fs > 0):
            raise CollisionParameterError(f"sample_rate_hz must be finite and > 0, got {fs}")
        if self.window_source not in ("drive", "stroke"):
            raise CollisionParameterError(
                f"window_source must be 'drive' or 'stroke', got {self.window_source!r}"
            )
        if self.window_source == "drive":
            f = self.drive_frequency_hz
            if f is None or not (math.isfinite(f) and 0 < f < fs / 8):
                raise CollisionParameterError(
                    "drive_frequency_hz must be in (0, sample_rate_hz/8) for "
                    f"window_source='drive', got {f}"
                )
        for name in ("stroke_threshold", "pitch_threshold", "on_level", "off_level"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise CollisionParameterError(f"{name} must be finite and > 0, got {v}")
        if not self.off_level <= self.on_level:
            raise CollisionParameterError(
                f"off_level ({self.off_level}) must be <= on_level ({self.on_level})"
            )
        for name in ("n_on", "n_off"):
            if getattr(self, name) < 1:
                raise CollisionParameterError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.arm_wingbeats < 0:
            raise CollisionParameterError(f"arm_wingbeats must be >= 0, got {self.arm_wingbeats}")
        for name in (
            "min_amplitude_rad",
            "stroke_noise_rms_rad",
            "pitch_noise_rms_rad",
            "crossing_hysteresis_rad",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise CollisionParameterError(f"{name} must be finite and >= 0, got {v}")
        if not (0 < self.min_period_s < self.max_period_s and math.isfinite(self.max_period_s)):
            raise CollisionParameterError("need 0 < min_period_s < max_period_s < inf")
        if self.max_period_s * fs < 8:
            raise CollisionParameterError("max_period_s must span at least 8 samples")


class MonitorState(NamedTuple):
    """Monitor state: samples of the open window, window counter and decision memory."""

    tail_stroke_rad: np.ndarray  # samples of the current (open) window
    tail_pitch_rad: np.ndarray
    tail_start_index: int  # absolute index of tail[0]
    window_index: int  # drive mode: drive-cycle index k of the open window
    wingbeats_seen: int  # closed windows since (re)arming
    in_collision: bool
    above_count: int
    below_count: int
    schmitt_high: bool  # stroke mode: trigger state at the tail's end
    center_rad: float  # stroke mode: crossing centre (last window mean)
    scan_index: int  # stroke mode: samples of the tail already scanned
    # False until the first window boundary (partial window dropped)
    synced: bool


class WingbeatReport(NamedTuple):
    """One entry per wingbeat closed in this step (arrays of equal length)."""

    wingbeat: np.ndarray  # running index
    start_index: np.ndarray  # first sample (absolute)
    end_index: np.ndarray  # one past the last sample
    end_time_s: np.ndarray  # time of the last sample + 1/fs (decision time)
    frequency_hz: np.ndarray
    stroke_amplitude_rad: np.ndarray
    pitch_amplitude_rad: np.ndarray
    stroke_distortion: np.ndarray
    pitch_distortion: np.ndarray
    score: np.ndarray
    status: np.ndarray  # ARMING / CLEAR / COLLISION / IDLE / INVALID


class MonitorEvent(NamedTuple):
    """Onset or clearance of a collision."""

    kind: int  # ONSET or CLEARANCE
    wingbeat: int
    sample_index: int  # end of the deciding window
    time_s: float
    score: float


def initial_state(params: MonitorParams, *, start_index: int = 0) -> MonitorState:
    """Empty monitor whose first sample has absolute index ``start_index`` (time index / fs)."""
    if params.window_source == "drive":
        k = _cycle_of(start_index, params)
        synced = _cycle_start(k, params) == start_index
    else:
        k, synced = 0, False
    return MonitorState(
        np.zeros(0), np.zeros(0), int(start_index), k, 0, False, 0, 0, False, 0.0, 0, synced
    )


def rearm(state: MonitorState) -> MonitorState:
    """Restart the arming period and clear the decision memory (keeps the open window)."""
    return state._replace(wingbeats_seen=0, in_collision=False, above_count=0, below_count=0)


def _drive_hz(p: MonitorParams) -> float:
    """The drive frequency of drive-locked windows
    (MonitorParams requires it for window_source 'drive').
    """
    assert p.drive_frequency_hz is not None
    return p.drive_frequency_hz


def _cycle_of(index: int, p: MonitorParams) -> int:
    return math.floor(
        index * _drive_hz(p) / p.sample_rate_hz + p.drive_phase_rad / (2 * math.pi) + 1e-12
    )


def _cycle_start(k: int, p: MonitorParams) -> int:
    # first sample n with f n / fs + phase / 2pi >= k
    return math.ceil(
        (k - p.drive_phase_rad / (2 * math.pi)) * p.sample_rate_hz / _drive_hz(p) - 1e-9
    )


@lru_cache(maxsize=256)
def _projector(n: int, omega_per_sample: float) -> tuple[np.ndarray, np.ndarray]:
    """Basis [1, t, cos, sin] over n samples and its pseudo-inverse (cached)."""
    idx = np.arange(n, dtype=float)
    tn = (idx - 0.5 * (n - 1)) / max(0.5 * (n - 1), 1.0)
    ph = omega_per_sample * idx
    basis = np.ascontiguousarray(np.column_stack([np.ones(n), tn, np.cos(ph), np.sin(ph)]))
    return basis, np.ascontiguousarray(np.linalg.pinv(basis))


@numba.njit(cache=True)
def _fit_rows(  # pragma: no cover - numba
    segments: np.ndarray, basis: np.ndarray, pinv: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per row: fundamental amplitude and residual rms (fixed summation order, so the result of
    a window never depends on which other windows share the batch).
    """
    m, n = segments.shape
    amp = np.empty(m)
    rms = np.empty(m)
    nb = basis.shape[1]
    coef = np.empty(nb)
    for r in range(m):
        for j in range(nb):
            acc = 0.0
            for i in range(n):
                acc += pinv[j, i] * segments[r, i]
            coef[j] = acc
        ss = 0.0
        for i in range(n):
            fit = 0.0
            for j in range(nb):
                fit += basis[i, j] * coef[j]
            e = segments[r, i] - fit
            ss += e * e
        amp[r] = math.sqrt(coef[2] * coef[2] + coef[3] * coef[3])
        rms[r] = math.sqrt(ss / n)
    return amp, rms


def _fit_many(segments: np.ndarray, omega_per_sample: float) -> tuple[np.ndarray, np.ndarray]:
    """(fundamental amplitude, residual rms) of each row of ``segments`` (m, n)."""
    basis, pinv = _projector(segments.shape[1], float(omega_per_sample))
    amp, rms = _fit_rows(np.ascontiguousarray(segments), basis, pinv)
    return amp, rms


def _distortion(amp: np.ndarray, resid_rms: np.ndarray, noise_rms: float) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        d2 = (resid_rms * resid_rms - noise_rms * noise_rms) / (0.5 * amp * amp)
    return np.where(amp > 0, np.sqrt(np.maximum(d2, 0.0)), np.inf)


def _drive_windows(
    st: MonitorState, n_avail: int, base: int, p: MonitorParams
) -> tuple[list[Window], int, MonitorState]:
    """Closed drive-locked windows [(start, end, omega, idle)] (relative to base) and new state."""
    wins: list[Window] = []
    k = st.window_index
    pos = 0
    synced = st.synced
    omega = 2 * math.pi * _drive_hz(p) / p.sample_rate_hz
    while True:
        end = _cycle_start(k + 1, p) - base
        if end > n_avail:
            break
        if synced:
            wins.append((pos, end, omega, False))
        synced = True
        pos = end
        k += 1
    return wins, pos, st._replace(window_index=k, synced=synced)


@numba.njit(cache=True)
def _schmitt_scan(  # pragma: no cover - numba
    xs: np.ndarray,
    i0: int,
    high: bool,
    center: float,
    synced: bool,
    min_len: int,
    max_len: int,
    h: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, bool, float, bool]:
    """Sample-by-sample Schmitt-trigger window finder (see ``_stroke_windows``)."""
    n = xs.shape[0]
    cap = n // 4 + 2
    starts = np.empty(cap, np.int64)
    ends = np.empty(cap, np.int64)
    idles = np.empty(cap, np.bool_)
    m = 0
    pos = 0
    for i in range(i0, n):
        v = xs[i] - center
        boundary = False
        if high:
            if v < -h:
                high = False
        elif v > h:
            high = True
            boundary = (i - pos) >= min_len
        if boundary or (i - pos) >= max_len:
            idle = not boundary
            if synced or idle:
                starts[m] = pos
                ends[m] = i
                idles[m] = idle
                m += 1
            total = 0.0
            count = 0
            for j in range(pos, i):
                if np.isfinite(xs[j]):
                    total += xs[j]
                    count += 1
            if count > 0:
                center = total / count
            synced = boundary
            pos = i
    return starts[:m], ends[:m], idles[:m], pos, high, center, synced


def _stroke_windows(
    st: MonitorState, xs: np.ndarray, p: MonitorParams
) -> tuple[list[Window], int, MonitorState]:
    """Closed stroke-locked windows [(start, end, omega, idle)] (relative to xs) and new state.

    Sample by sample: the trigger goes low below centre - h and high above centre + h; an upward
    switch at least min_period after the window start closes the window there (the next one
    starts at that sample); a window reaching max_period is closed as IDLE (not flapping). The
    centre is the mean of the previous window. The partial window before the first switch is
    dropped.
    """
    fs = p.sample_rate_hz
    min_len = max(round(p.min_period_s * fs), 4)
    max_len = round(p.max_period_s * fs)
    starts, ends, idles, pos, high, center, synced = _schmitt_scan(
        np.ascontiguousarray(xs, dtype=np.float64),
        int(st.scan_index),
        bool(st.schmitt_high),
        float(st.center_rad),
        bool(st.synced),
        min_len,
        max_len,
        float(p.crossing_hysteresis_rad),
    )
    wins = [
        (int(a), int(b), 2 * math.pi / (b - a), bool(c))
        for a, b, c in zip(starts, ends, idles, strict=True)
    ]
    new = st._replace(
        schmitt_high=bool(high),
        center_rad=float(center),
        synced=bool(synced),
        scan_index=int(xs.size - pos),
    )
    return wins, int(pos), new


class MonitorInputs(NamedTuple):
    """One block of sensor-derived angles (rad, same length; NaN = invalid sample)."""

    stroke_rad: np.ndarray
    pitch_rad: np.ndarray


class MonitorOutputs(NamedTuple):
    """Every wingbeat closed by one block, and the onsets/clearances they caused."""

    report: WingbeatReport
    events: list[MonitorEvent]


def step(
    state: MonitorState, inputs: MonitorInputs, params: MonitorParams
) -> tuple[MonitorState, MonitorOutputs]:
    """Feed one block of sensor-derived angles.

    Returns the new state and the report of every wingbeat closed by this block with the
    events (onset/clearance) they caused.
    """
    s_in = np.asarray(inputs.stroke_rad, dtype=float).ravel()
    p_in = np.asarray(inputs.pitch_rad, dtype=float).ravel()
    if s_in.shape != p_in.shape:
        raise CollisionParameterError(
            f"stroke_rad and pitch_rad must have the same length, got {s_in.size} and {p_in.size}"
        )
    if not params.use_pitch:
        p_in = np.zeros_like(p_in)
    xs = np.concatenate([state.tail_stroke_rad, s_in])
    xp = np.concatenate([state.tail_pitch_rad, p_in])
    base = state.tail_start_index
    if params.window_source == "drive":
        wins, pos, st = _drive_windows(state, xs.size, base, params)
    else:
        wins, pos, st = _stroke_windows(state, xs, params)
    feats = _features(xs, xp, wins, params)
    rows: list[ReportRow] = []
    events: list[MonitorEvent] = []
    for (start, end, omega, idle), (a_s, a_p, d_s, d_p, score, ok) in zip(wins, feats, strict=True):
        st, row, ev = _decide(
            st, base + start, base + end, omega, idle, ok, a_s, a_p, d_s, d_p, score, params
        )
        rows.append(row)
        events.extend(ev)
    st = st._replace(
        tail_stroke_rad=xs[pos:].copy(), tail_pitch_rad=xp[pos:].copy(), tail_start_index=base + pos
    )
    return st, MonitorOutputs(_report(rows), events)


def _features(
    xs: np.ndarray, xp: np.ndarray, wins: list[Window], p: MonitorParams
) -> list[Features]:
    """Per window: (A_stroke, A_pitch, d_stroke, d_pitch, score, usable); fits batched by length."""
    out: list[Features] = [(math.nan,) * 5 + (False,)] * len(wins)
    groups: dict[tuple[int, float], list[int]] = {}
    for w, (start, end, omega, _) in enumerate(wins):
        n = end - start
        if n < 8 or not (np.all(np.isfinite(xs[start:end])) and np.all(np.isfinite(xp[start:end]))):
            out[w] = (math.nan,) * 5 + (False,)
            continue
        groups.setdefault((n, omega), []).append(w)
    for (_, omega), members in groups.items():
        seg_s = np.stack([xs[wins[w][0] : wins[w][1]] for w in members])
        seg_p = np.stack([xp[wins[w][0] : wins[w][1]] for w in members])
        a_s, r_s = _fit_many(seg_s, omega)
        d_s = _distortion(a_s, r_s, p.stroke_noise_rms_rad)
        if p.use_pitch:
            a_p, r_p = _fit_many(seg_p, omega)
            d_p = _distortion(a_p, r_p, p.pitch_noise_rms_rad)
            score = np.maximum(d_s / p.stroke_threshold, d_p / p.pitch_threshold)
        else:
            a_p = np.zeros(len(members))
            d_p = np.zeros(len(members))
            score = d_s / p.stroke_threshold
        for j, w in enumerate(members):
            out[w] = (
                float(a_s[j]),
                float(a_p[j]),
                float(d_s[j]),
                float(d_p[j]),
                float(score[j]),
                True,
            )
    return out


def _decide(
    st: MonitorState,
    start: int,
    end: int,
    omega: float,
    idle: bool,
    ok: bool,
    a_s: float,
    a_p: float,
    d_s: float,
    d_p: float,
    score: float,
    p: MonitorParams,
) -> tuple[MonitorState, ReportRow, list[MonitorEvent]]:
    """Hysteresis decision for one closed wingbeat."""
    fs = p.sample_rate_hz
    freq = omega * fs / (2 * math.pi)
    wingbeat = st.wingbeats_seen
    events: list[MonitorEvent] = []
    in_coll, above, below = st.in_collision, st.above_count, st.below_count
    if not ok:
        status = INVALID
    elif wingbeat < p.arm_wingbeats:
        status = ARMING
    elif idle or a_s < p.min_amplitude_rad:
        status = IDLE
        above, below = 0, below + 1
    else:
        if score >= p.on_level:
            above, below = above + 1, 0
        elif score < p.off_level:
            above, below = 0, below + 1
        else:  # inside the hysteresis band: hold
            above, below = 0, 0
        status = CLEAR
    if status in (CLEAR, IDLE):
        if not in_coll and above >= p.n_on:
            in_coll = True
            events.append(MonitorEvent(ONSET, wingbeat, end, end / fs, score))
        elif in_coll and below >= p.n_off:
            in_coll = False
            events.append(MonitorEvent(CLEARANCE, wingbeat, end, end / fs, score))
        if status == CLEAR and in_coll:
            status = COLLISION
    row = (wingbeat, start, end, end / fs, freq, a_s, a_p, d_s, d_p, score, status)
    return (
        st._replace(
            wingbeats_seen=wingbeat + 1, in_collision=in_coll, above_count=above, below_count=below
        ),
        row,
        events,
    )


def _report(rows: list[ReportRow]) -> WingbeatReport:
    if not rows:
        empty_i = np.zeros(0, dtype=np.int64)
        empty_f = np.zeros(0)
        return WingbeatReport(
            empty_i,
            empty_i,
            empty_i,
            empty_f,
            empty_f,
            empty_f,
            empty_f,
            empty_f,
            empty_f,
            empty_f,
            empty_i,
        )
    cols = list(zip(*rows, strict=True))
    ints = {0, 1, 2, 10}
    return WingbeatReport(
        *[np.asarray(c, dtype=np.int64 if i in ints else float) for i, c in enumerate(cols)]
    )


def concat_reports(reports: list[WingbeatReport]) -> WingbeatReport:
    """Join the reports of consecutive steps."""
    if not reports:
        return _report([])
    return WingbeatReport(*[np.concatenate(parts) for parts in zip(*reports, strict=True)])


def run(
    stroke_rad: np.ndarray,
    pitch_rad: np.ndarray,
    params: MonitorParams,
    state: MonitorState | None = None,
) -> tuple[MonitorState, WingbeatReport, list[MonitorEvent]]:
    """Whole record: ``step`` applied once from ``state`` (default ``initial_state``)."""
    if state is None:
        state = initial_state(params)
    state, out = step(state, MonitorInputs(stroke_rad, pitch_rad), params)
    return state, out.report, out.events
