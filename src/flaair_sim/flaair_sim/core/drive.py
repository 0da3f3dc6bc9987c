"""Drive-voltage generators: whole-record functions and a sample-exact block form for a node.

Every generator is a function of the sample time t_k = k / fs_hz (k an integer sample
index), so the block form `drive_step` gives bit-identical samples to the whole record.

- sine: bias + A sin(2 pi f t + phase)
- chirp: linear sweep start_hz -> stop_hz over duration_s, phase-continuous; after
  duration_s it continues at stop_hz (phase-continuous).
- stepped_sine: each frequency held dwell_s (rounded to whole samples), phase-continuous
  across steps; after the last step it continues at the last frequency.
- multisine: bias + A sum_k cos(2 pi k n / N + phase_k) over integer lines k of f0 = fs / N
  (a whole number of samples per period; the phase from the integer k n mod N, exact over any
  run length): the odd random-phase multisine of `flaair multisine design`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "DRIVE_KINDS",
    "DriveError",
    "DriveParams",
    "DriveState",
    "chirp",
    "drive_record",
    "drive_step",
    "multisine",
    "multisine_period_samples",
    "sine",
    "stepped_sine",
    "stepped_sine_frequencies_hz",
]

DRIVE_KINDS = ("sine", "chirp", "stepped_sine", "multisine")


class DriveError(ValueError):
    """Invalid drive parameters (the message names the parameter)."""


def _finite(name: str, value: float) -> float:
    if isinstance(value, bool):
        raise DriveError(f"{name} must be a number, got {value!r}")
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise DriveError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(value):
        raise DriveError(f"{name} must be finite, got {value}")
    return value


def _positive(name: str, value: float) -> float:
    value = _finite(name, value)
    if not value > 0:
        raise DriveError(f"{name} must be > 0, got {value:g}")
    return value


def sine(
    t_s: np.ndarray,
    amplitude_v: float,
    frequency_hz: float,
    bias_v: float = 0.0,
    phase_rad: float = 0.0,
) -> np.ndarray:
    """bias_v + amplitude_v * sin(2 pi frequency_hz t + phase_rad)."""
    t = np.asarray(t_s, dtype=np.float64)
    return bias_v + amplitude_v * np.sin(2.0 * np.pi * frequency_hz * t + phase_rad)


def chirp(
    t_s: np.ndarray, amplitude_v: float, start_hz: float, stop_hz: float, duration_s: float
) -> np.ndarray:
    """Linear, phase-continuous chirp from start_hz (t = 0) to stop_hz (t = duration_s).

    Past duration_s the frequency stays at stop_hz (phase-continuous); before 0 at start_hz.
    """
    duration_s = _positive("duration_s", duration_s)
    t = np.asarray(t_s, dtype=np.float64)
    rate = (stop_hz - start_hz) / duration_s
    inside = np.clip(t, 0.0, duration_s)
    cycles = (
        start_hz * inside + 0.5 * rate * inside * inside + stop_hz * np.maximum(t - duration_s, 0.0)
    )
    cycles = cycles + start_hz * np.minimum(t, 0.0)
    return amplitude_v * np.sin(2.0 * np.pi * cycles)


def _stepped_sine_at(
    k: np.ndarray, fs_hz: float, amplitude_v: float, frequencies_hz: np.ndarray, dwell_samples: int
) -> tuple[np.ndarray, np.ndarray]:
    step_index = np.minimum(k // dwell_samples, len(frequencies_hz) - 1)
    # cycles completed at the start of each step (phase continuity across steps)
    start_cycles = np.concatenate([[0.0], np.cumsum(frequencies_hz[:-1] * dwell_samples / fs_hz)])
    local_t = (k - step_index * dwell_samples) / fs_hz
    freq = frequencies_hz[step_index]
    cycles = start_cycles[step_index] + freq * local_t
    # reduce to one cycle before multiplying by 2 pi: keeps the phase exact over long runs
    return amplitude_v * np.sin(2.0 * np.pi * (cycles - np.floor(cycles))), freq


def _dwell_samples(fs_hz: float, dwell_s: float) -> int:
    n = round(_positive("dwell_s", dwell_s) * _positive("fs_hz", fs_hz))
    if n < 1:
        raise DriveError(f"dwell_s {dwell_s:g} is shorter than one sample at fs_hz {fs_hz:g}")
    return n


def stepped_sine(
    fs_hz: float, amplitude_v: float, frequencies_hz: Sequence[float], dwell_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Sine stepped through `frequencies_hz`, each held `dwell_s` (phase-continuous).

    Returns
    -------
    (drive_v, frequency_hz)
        Drive per sample and the frequency in force at each sample, len(frequencies) x
        round(dwell_s * fs_hz) samples.
    """
    freqs = np.asarray(frequencies_hz, dtype=np.float64).ravel()
    if freqs.size == 0:
        raise DriveError("frequencies_hz must not be empty")
    if not np.all(np.isfinite(freqs)) or np.any(freqs <= 0):
        raise DriveError("frequencies_hz must be finite and > 0")
    dwell = _dwell_samples(fs_hz, dwell_s)
    k = np.arange(freqs.size * dwell)
    return _stepped_sine_at(k, float(fs_hz), amplitude_v, freqs, dwell)


def multisine(
    n: np.ndarray,
    period_samples: int,
    lines: Sequence[int],
    phases_rad: Sequence[float],
    amplitude_v: float,
) -> np.ndarray:
    """amplitude_v * sum_k cos(2 pi k n / period_samples + phase_k) at integer sample indices n.

    The phase of each line is taken from the integer (k n) mod N, so a sample is the same
    whatever block it is computed in.
    """
    idx = np.asarray(n, dtype=np.int64)
    ks = np.asarray(lines, dtype=np.int64)
    phases = np.asarray(phases_rad, dtype=np.float64)
    if ks.shape != phases.shape or ks.ndim != 1 or ks.size == 0:
        raise DriveError("multisine lines and phases_rad must be two lists of one length (>= 1)")
    if period_samples < 1 or np.any(ks < 0) or np.any(ks >= period_samples):
        raise DriveError(f"multisine lines must lie in [0, {period_samples}) (the period)")
    out = np.zeros(idx.shape, dtype=np.float64)
    step = 2.0 * np.pi / period_samples
    for k, phase in zip(ks.tolist(), phases.tolist(), strict=True):
        out += np.cos(step * ((k * idx) % period_samples) + phase)
    return amplitude_v * out


def multisine_period_samples(fs_hz: float, base_hz: float) -> int:
    """N = fs / f0, which must be a whole number of samples."""
    ratio = _positive("fs_hz", fs_hz) / _positive("frequency_hz", base_hz)
    n = round(ratio)
    if n < 1 or abs(ratio - n) > 1e-9 * ratio:
        raise DriveError(
            f"multisine: fs_hz / frequency_hz = {ratio:.6g} is not a whole number of samples"
        )
    return int(n)


def stepped_sine_frequencies_hz(start_hz: float, stop_hz: float, step_hz: float) -> np.ndarray:
    """start_hz, start_hz + step_hz, ... up to stop_hz inclusive (within half a step)."""
    count = math.floor((stop_hz - start_hz) / step_hz + 0.5) + 1
    return start_hz + step_hz * np.arange(max(count, 1))


@dataclass(frozen=True)
class DriveParams:
    """Drive signal for a node; which fields matter depends on `kind`.

    sine: amplitude_v, bias_v, frequency_hz. chirp: amplitude_v, bias_v, start_hz, stop_hz,
    duration_s. stepped_sine: amplitude_v, bias_v, start_hz, stop_hz, step_hz, dwell_s.
    multisine: amplitude_v (each line's), bias_v, frequency_hz (f0 = fs / N), lines (integer
    line numbers k, each at k f0), phases_rad (one per line).
    lead_in_s (any kind): zero drive first, then the waveform from its own t = 0 (a rest that
    lets the wing settle between back-to-back runs).
    """

    kind: str
    amplitude_v: float
    bias_v: float = 0.0
    frequency_hz: float = 0.0
    start_hz: float = 0.0
    stop_hz: float = 0.0
    duration_s: float = 0.0
    step_hz: float = 0.0
    dwell_s: float = 0.0
    lead_in_s: float = 0.0
    lines: tuple[float, ...] = ()
    phases_rad: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in DRIVE_KINDS:
            raise DriveError(f"kind must be one of {', '.join(DRIVE_KINDS)}, got {self.kind!r}")
        for name in (
            "amplitude_v",
            "bias_v",
            "frequency_hz",
            "start_hz",
            "stop_hz",
            "duration_s",
            "step_hz",
            "dwell_s",
            "lead_in_s",
        ):
            object.__setattr__(self, name, _finite(name, getattr(self, name)))
        if self.lead_in_s < 0:
            raise DriveError(f"lead_in_s must be >= 0, got {self.lead_in_s:g}")
        required = {
            "sine": ("frequency_hz",),
            "chirp": ("start_hz", "stop_hz", "duration_s"),
            "stepped_sine": ("start_hz", "stop_hz", "step_hz", "dwell_s"),
            "multisine": ("frequency_hz",),
        }[self.kind]
        for name in required:
            _positive(name, getattr(self, name))
        if self.kind == "stepped_sine" and self.stop_hz < self.start_hz:
            raise DriveError(
                f"stop_hz {self.stop_hz:g} must be >= start_hz {self.start_hz:g} for stepped_sine"
            )
        lines = tuple(_finite("lines", v) for v in self.lines)
        phases = tuple(_finite("phases_rad", v) for v in self.phases_rad)
        object.__setattr__(self, "lines", lines)
        object.__setattr__(self, "phases_rad", phases)
        if self.kind == "multisine":
            if not lines or len(lines) != len(phases):
                raise DriveError(
                    f"multisine needs lines and phases_rad of one length >= 1, got "
                    f"{len(lines)} and {len(phases)}"
                )
            if any(v != round(v) or v < 0 for v in lines):
                raise DriveError("multisine lines must be whole numbers >= 0")


@dataclass(frozen=True)
class DriveState:
    """Index of the next sample to generate."""

    sample_index: int = 0


def _samples(k: np.ndarray, fs_hz: float, params: DriveParams) -> np.ndarray:
    lead = round(params.lead_in_s * fs_hz)
    if lead:
        out = np.zeros(k.shape)
        running = k >= lead
        out[running] = _waveform(k[running] - lead, fs_hz, params)
        return out
    return _waveform(k, fs_hz, params)


def _waveform(k: np.ndarray, fs_hz: float, params: DriveParams) -> np.ndarray:
    t = k / fs_hz
    if params.kind == "sine":
        return sine(t, params.amplitude_v, params.frequency_hz, params.bias_v)
    if params.kind == "chirp":
        return params.bias_v + chirp(
            t, params.amplitude_v, params.start_hz, params.stop_hz, params.duration_s
        )
    if params.kind == "multisine":
        n = multisine_period_samples(fs_hz, params.frequency_hz)
        lines = [round(v) for v in params.lines]
        return params.bias_v + multisine(k, n, lines, params.phases_rad, params.amplitude_v)
    freqs = stepped_sine_frequencies_hz(params.start_hz, params.stop_hz, params.step_hz)
    dwell = _dwell_samples(fs_hz, params.dwell_s)
    return params.bias_v + _stepped_sine_at(k, fs_hz, params.amplitude_v, freqs, dwell)[0]


def drive_record(params: DriveParams, fs_hz: float, n_samples: int) -> np.ndarray:
    """Whole record of `n_samples` from sample 0 (what drive_step produces block by block)."""
    return _samples(np.arange(int(n_samples)), _positive("fs_hz", fs_hz), params)


def drive_step(
    state: DriveState, n_samples: int, fs_hz: float, params: DriveParams
) -> tuple[DriveState, np.ndarray]:
    """Next `n_samples` of the drive.

    Parameters
    ----------
    state
        Drive state (sample index).
    n_samples
        Block length.
    fs_hz
        Sample rate.
    params
        Drive parameters.

    Returns
    -------
    (DriveState, drive_v_block)
    """
    if n_samples < 0:
        raise DriveError(f"n_samples must be >= 0, got {n_samples}")
    k = state.sample_index + np.arange(int(n_samples))
    block = _samples(k, _positive("fs_hz", fs_hz), params)
    return DriveState(state.sample_index + int(n_samples)), block
