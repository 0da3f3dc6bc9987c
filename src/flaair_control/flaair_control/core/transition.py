r"""Sync -> async transition analysis (paper, Applications, Fig. asynch): frequency and amplitude.

Pure numpy/scipy; no ROS, no file I/O.

Hilbert analysis (``hilbert_analysis``)
---------------------------------------
The paper reports the stroke frequency and amplitude of the transition from the Hilbert
transform of the sensor-determined stroke angle, "smoothened through a bandpass and
Savitzky-Golay filter". It does not give the filters, so (parameters in ``HilbertParams``; the
values the tools use, noted as "config" below, are config/flaair.yaml ``analyze: hilbert_*``):

1. invalid samples (NaN) are filled by linear interpolation (counted in the result);
2. band-pass: Butterworth (``band_order``, config 4) over ``band_hz`` (config 40-400 Hz, wide
   enough for the 80-100 Hz synchronous start and the ~145 Hz self-excited end, removing the
   offset/drift and the higher harmonics), applied forward and backward (zero phase: the
   analysis is offline);
3. analytic signal z = x + j H[x] (scipy.signal.hilbert); amplitude |z|; frequency
   d(unwrap(arg z))/dt / 2 pi;
4. Savitzky-Golay smoothing of both (``savgol_window_s`` long, config 20 ms, polynomial order
   ``savgol_order``, config 2): the instantaneous frequency and amplitude of a non-sinusoidal
   stroke ripple at twice the wingbeat frequency; a window of about 3 wingbeats removes it;
5. ``edge_s`` at both ends (filter transients) is set to NaN.

For a pure sine the result is its frequency and amplitude exactly (away from the edges).

Crossing frequency (``CrossingFrequency``)
------------------------------------------
A streaming estimate used live by the dSA controller node (ControllerState.stroke_frequency_hz)
and offline as an independent check of the Hilbert frequency: upward crossings of a Schmitt
trigger (+-``hysteresis`` about 0; the front end removes the offset), located to a fraction of
a sample by linear interpolation at the +hysteresis level; the frequency is the number of
periods over the time spanned by the last ``average`` + 1 crossings. 0 until two crossings are
seen or when none has occurred for ``max_period_s``. NaN samples are skipped (the trigger
holds its state; an interpolation never spans a NaN).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from scipy import signal

__all__ = [
    "CROSSING_START",
    "BlockRecord",
    "CrossingFrequency",
    "CrossingParams",
    "CrossingState",
    "HilbertParams",
    "HilbertResult",
    "TransitionError",
    "WindowStats",
    "crossing_frequency_hz",
    "crossing_params",
    "crossing_step",
    "crossing_times",
    "hilbert_analysis",
    "join_blocks",
    "stamp_s",
    "window_stats",
]


class TransitionError(ValueError):
    """A parameter or record is invalid; the message names it."""


# --------------------------------------------------------------------------- Hilbert analysis


@dataclass(frozen=True)
class HilbertParams:
    """Band-pass + Hilbert + Savitzky-Golay settings (see
    module docstring; values: config/flaair.yaml analyze).
    """

    band_hz: tuple[float, float]
    band_order: int
    savgol_window_s: float
    savgol_order: int
    edge_s: float

    def __post_init__(self) -> None:
        lo, hi = self.band_hz
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
            raise TransitionError(f"band_hz must be 0 < low < high, got {self.band_hz}")
        if self.band_order < 1:
            raise TransitionError(f"band_order must be >= 1, got {self.band_order}")
        if not (math.isfinite(self.savgol_window_s) and self.savgol_window_s > 0):
            raise TransitionError(f"savgol_window_s must be > 0, got {self.savgol_window_s}")
        if self.savgol_order < 0:
            raise TransitionError(f"savgol_order must be >= 0, got {self.savgol_order}")
        if not (math.isfinite(self.edge_s) and self.edge_s >= 0):
            raise TransitionError(f"edge_s must be >= 0, got {self.edge_s}")


class HilbertResult(NamedTuple):
    """Smoothed instantaneous frequency and amplitude (same length as the input)."""

    time_s: np.ndarray
    frequency_hz: np.ndarray  # NaN within edge_s of the ends
    amplitude: np.ndarray  # in the unit of the input angle; NaN at the edges
    band_passed: np.ndarray  # the band-passed angle (unit of the input)
    filled_samples: int  # NaN input samples filled by interpolation


def _fill_nan(x: np.ndarray) -> tuple[np.ndarray, int]:
    bad = ~np.isfinite(x)
    n_bad = int(bad.sum())
    if n_bad == 0:
        return x, 0
    if n_bad == x.size:
        raise TransitionError("angle holds no finite sample")
    idx = np.arange(x.size)
    out = x.copy()
    out[bad] = np.interp(idx[bad], idx[~bad], x[~bad])
    return out, n_bad


def hilbert_analysis(
    angle: np.ndarray, sample_rate_hz: float, params: HilbertParams, start_time_s: float = 0.0
) -> HilbertResult:
    """Frequency and amplitude of ``angle`` (one uniformly sampled record; NaN = invalid)."""
    fs = float(sample_rate_hz)
    if not (math.isfinite(fs) and fs > 0):
        raise TransitionError(f"sample_rate_hz must be finite and > 0, got {sample_rate_hz}")
    if params.band_hz[1] >= fs / 2:
        raise TransitionError(
            f"band_hz upper edge {params.band_hz[1]} must lie below fs/2 = {fs / 2}"
        )
    x = np.asarray(angle, dtype=float).ravel()
    window = round(params.savgol_window_s * fs) | 1
    if window <= params.savgol_order:
        raise TransitionError("savgol_window_s is shorter than savgol_order + 1 samples")
    sos = signal.butter(params.band_order, params.band_hz, btype="bandpass", fs=fs, output="sos")
    padlen = 3 * (2 * sos.shape[0] + 1)
    if x.size <= max(padlen, window):
        raise TransitionError(f"angle too short ({x.size} samples) for the filters")
    x, filled = _fill_nan(x)
    xb = signal.sosfiltfilt(sos, x)
    z = signal.hilbert(xb)
    amplitude = np.abs(z)
    phase = np.unwrap(np.angle(z))
    frequency = np.gradient(phase) * fs / (2 * np.pi)
    frequency = signal.savgol_filter(frequency, window, params.savgol_order)
    amplitude = signal.savgol_filter(amplitude, window, params.savgol_order)
    edge = min(round(params.edge_s * fs), x.size // 2)
    if edge > 0:
        for arr in (frequency, amplitude):
            arr[:edge] = np.nan
            arr[x.size - edge :] = np.nan
    t = start_time_s + np.arange(x.size) / fs
    return HilbertResult(t, frequency, amplitude, xb, filled)


class WindowStats(NamedTuple):
    """Mean, standard deviation and peak-to-peak of a quantity over a time window."""

    mean: float
    std: float
    ptp: float


def window_stats(time_s: np.ndarray, values: np.ndarray, t0_s: float, t1_s: float) -> WindowStats:
    """Statistics of the finite ``values`` with t0 <= t < t1."""
    t = np.asarray(time_s, dtype=float)
    v = np.asarray(values, dtype=float)
    sel = (t >= t0_s) & (t < t1_s) & np.isfinite(v)
    if not sel.any():
        raise TransitionError(f"no finite value in [{t0_s}, {t1_s}) s")
    w = v[sel]
    return WindowStats(float(w.mean()), float(w.std()), float(np.ptp(w)))


# --------------------------------------------------------------------------- crossing frequency


class CrossingParams(NamedTuple):
    """Upward Schmitt-trigger crossings about 0 (+-hysteresis, in the signal's unit)."""

    sample_rate_hz: float
    hysteresis: float
    average: int  # crossings averaged (periods)
    max_period_s: float  # no crossing for this long: frequency 0


class CrossingState(NamedTuple):
    """Crossing estimator state."""

    next_index: int  # absolute index of the next sample
    high: bool
    prev: float | None  # previous finite sample (None after a NaN)
    crossings: tuple[float, ...]  # fractional sample indices, the last average + 1


def crossing_params(
    sample_rate_hz: float, hysteresis: float, average: int = 4, max_period_s: float = 0.05
) -> CrossingParams:
    """Checked `CrossingParams`."""
    if not (math.isfinite(sample_rate_hz) and sample_rate_hz > 0):
        raise TransitionError(f"sample_rate_hz must be finite and > 0, got {sample_rate_hz}")
    if not (math.isfinite(hysteresis) and hysteresis >= 0):
        raise TransitionError(f"hysteresis must be finite and >= 0, got {hysteresis}")
    if average < 1:
        raise TransitionError(f"average must be >= 1, got {average}")
    return CrossingParams(
        float(sample_rate_hz), float(hysteresis), int(average), float(max_period_s)
    )


CROSSING_START = CrossingState(0, False, None, ())


def crossing_step(
    state: CrossingState, x: Iterable[float], params: CrossingParams
) -> tuple[CrossingState, float]:
    """Feed samples (one block); return the new state and the frequency estimate (Hz)."""
    h = params.hysteresis
    high, prev, i = state.high, state.prev, state.next_index
    values = x.tolist() if isinstance(x, np.ndarray) else list(x)
    # Most blocks (a few samples of a wingbeat) stay on one side of the trigger: every sample
    # finite (a finite sum) and none past the threshold that would flip it.
    if values and math.isfinite(sum(values)) and (min(values) >= -h if high else max(values) <= h):
        state = CrossingState(i + len(values), high, values[-1], state.crossings)
        return state, crossing_frequency_hz(state, params)
    crossings = list(state.crossings)
    keep = params.average + 1
    for v in values:
        if v != v or v in (math.inf, -math.inf):
            prev = None
        else:
            if high:
                if v < -h:
                    high = False
            elif v > h:
                high = True
                if prev is not None and prev <= h:
                    crossings.append(i - 1 + (h - prev) / (v - prev))
                    if len(crossings) > keep:
                        del crossings[0]
            prev = v
        i += 1
    state = CrossingState(i, high, prev, tuple(crossings))
    return state, crossing_frequency_hz(state, params)


def crossing_frequency_hz(state: CrossingState, params: CrossingParams) -> float:
    """The estimate: periods over the crossings kept (0 once the stroke stops crossing)."""
    c = state.crossings
    if len(c) < 2 or state.next_index - c[-1] > params.max_period_s * params.sample_rate_hz:
        return 0.0
    return (len(c) - 1) * params.sample_rate_hz / (c[-1] - c[0])


class CrossingFrequency:
    """Streaming stroke frequency from upward Schmitt-trigger
    crossings (`crossing_step` with its state).
    """

    def __init__(
        self, sample_rate_hz: float, hysteresis: float, average: int = 4, max_period_s: float = 0.05
    ) -> None:
        self.params = crossing_params(sample_rate_hz, hysteresis, average, max_period_s)
        self.fs = self.params.sample_rate_hz
        self.state = CROSSING_START

    def update(self, x: Iterable[float]) -> float:
        """Feed samples (one block); return the current frequency estimate (Hz)."""
        self.state, frequency = crossing_step(self.state, x, self.params)
        return frequency

    @property
    def crossings(self) -> list[float]:
        return list(self.state.crossings)

    @property
    def frequency_hz(self) -> float:
        return crossing_frequency_hz(self.state, self.params)


def crossing_times(angle: np.ndarray, sample_rate_hz: float, hysteresis: float) -> np.ndarray:
    """All upward-crossing times (s) of a whole record, as ``CrossingFrequency`` finds them."""
    x = np.asarray(angle, dtype=float).ravel()
    est = CrossingFrequency(sample_rate_hz, hysteresis, average=x.size + 1)  # keep every crossing
    est.update(x)
    return np.asarray(est.crossings) / est.fs


# --------------------------------------------------------------------------- records from messages


class BlockRecord(NamedTuple):
    """Samples of a block stream joined by first_sample_index (missing blocks: NaN)."""

    first_sample_index: int
    time_s: np.ndarray
    values: dict[str, np.ndarray]
    missing_blocks: int


def join_blocks(
    blocks: Sequence[Mapping[str, Any]],
    fields: Sequence[str],
    sample_rate_hz: float,
    valid_field: str | None = None,
) -> BlockRecord:
    """Join block messages (as dicts, e.g. from ``flaair topic echo``) into continuous arrays.

    Samples whose ``valid_field`` flag is false become NaN; duplicate blocks keep the first.
    """
    if not blocks:
        raise TransitionError("no blocks to join")
    blocks = sorted(blocks, key=lambda b: b["first_sample_index"])
    start = int(blocks[0]["first_sample_index"])
    end = max(int(b["first_sample_index"]) + len(b[fields[0]]) for b in blocks)
    out = {f: np.full(end - start, np.nan) for f in fields}
    filled = np.zeros(end - start, dtype=bool)
    n_blocks = 0
    for b in blocks:
        i = int(b["first_sample_index"]) - start
        n = len(b[fields[0]])
        if filled[i : i + n].any():
            continue
        n_blocks += 1
        filled[i : i + n] = True
        ok = np.asarray(b[valid_field], dtype=bool) if valid_field else np.ones(n, dtype=bool)
        for f in fields:
            out[f][i : i + n] = np.where(ok, np.asarray(b[f], dtype=float), np.nan)
    length = max(len(b[fields[0]]) for b in blocks)
    missing = round((~filled).sum() / max(length, 1))
    t = (start + np.arange(end - start)) / sample_rate_hz
    return BlockRecord(start, t, out, missing)


def stamp_s(message: Mapping[str, Any]) -> float:
    """Header stamp (s) of a message dict."""
    stamp = message["header"]["stamp"]
    return float(stamp["sec"] + 1e-9 * stamp["nanosec"])
