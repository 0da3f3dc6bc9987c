"""Frequency responses from drive and sensor records: the stepped-sine and chirp Bode
estimates, and their shared helpers (phasors, frequency track, signal checks).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy import signal

__all__ = [
    "SIGNALS",
    "Bode",
    "ChannelBode",
    "CharacterizationError",
    "amplitude_phase_rmse",
    "as_1d",
    "bode_from_chirp",
    "bode_from_stepped",
    "frequency_track_from_drive",
    "rms",
    "run_signals",
    "sine_phasor",
    "stepped_segments",
    "wrap_deg",
]


SIGNALS = ("drive", "stroke_sensor", "stroke_truth", "pitch_sensor", "pitch_truth")


class CharacterizationError(ValueError):
    """Bad characterization input; the message names the argument or column."""


@dataclass(frozen=True, eq=False)
class ChannelBode:
    """Bode data of one channel: sensor-derived vs ground truth (degrees)."""

    frequency_hz: np.ndarray
    sensor_amplitude_deg: np.ndarray
    truth_amplitude_deg: np.ndarray
    sensor_phase_deg: np.ndarray
    truth_phase_deg: np.ndarray
    phase_reference: str

    def as_dict(self) -> dict[str, Any]:
        """Plain lists, ready for JSON."""
        return {
            k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in asdict(self).items()
        }


@dataclass(frozen=True, eq=False)
class Bode:
    """Bode data of both channels from one experiment (``method``: "chirp" or "stepped")."""

    method: str
    stroke: ChannelBode
    pitch: ChannelBode

    def as_dict(self) -> dict[str, Any]:
        """Plain dict, ready for JSON."""
        return {
            "method": self.method,
            "stroke": self.stroke.as_dict(),
            "pitch": self.pitch.as_dict(),
        }


def wrap_deg(x: np.ndarray | float) -> np.ndarray:
    """Wrap angles in degrees to [-180, 180)."""
    return (np.asarray(x, float) + 180.0) % 360.0 - 180.0


def as_1d(x: Any, name: str, n: int | None = None) -> np.ndarray:
    a = np.asarray(x, dtype=float).reshape(-1)
    if n is not None and a.size != n:
        raise CharacterizationError(f"{name} has {a.size} samples, expected {n}")
    return a


def rms(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if x.size else math.nan


def frequency_track_from_drive(
    drive_v: np.ndarray, fs_hz: float, smooth_s: float = 0.005
) -> tuple[np.ndarray, np.ndarray]:
    """Instantaneous phase (rad) and frequency (Hz) of the drive from its analytic signal.

    The frequency is smoothed with a moving average of ``smooth_s``; the phase is the unwrapped
    analytic-signal phase (edges are less accurate over about a cycle).
    """
    d = as_1d(drive_v, "drive_v")
    if not np.all(np.isfinite(d)):
        raise CharacterizationError("drive_v contains non-finite samples")
    phase = np.unwrap(np.angle(signal.hilbert(d - d.mean())))
    f = np.gradient(phase) * fs_hz / (2 * np.pi)
    k = max(1, round(smooth_s * fs_hz))
    if k > 1:
        f = np.convolve(
            np.pad(f, (k // 2, k - 1 - k // 2), mode="edge"), np.ones(k) / k, mode="valid"
        )
    return phase, f


def _phase_from_track(frequency_hz_per_sample: np.ndarray, fs_hz: float) -> np.ndarray:
    return 2 * np.pi * np.cumsum(frequency_hz_per_sample) / fs_hz


def stepped_segments(frequency_hz_per_sample: np.ndarray) -> list[tuple[int, int, float]]:
    """Dwell segments ``(start, stop, frequency_hz)`` of a piecewise-constant frequency track."""
    f = as_1d(frequency_hz_per_sample, "frequency_hz_per_sample")
    if f.size == 0:
        return []
    edges = np.flatnonzero(np.diff(f) != 0) + 1
    starts = np.r_[0, edges]
    stops = np.r_[edges, f.size]
    return [
        (int(a), int(b), float(f[a]))
        for a, b in zip(starts, stops, strict=True)
        if f[a] > 0 and np.isfinite(f[a])
    ]


def sine_phasor(
    x: np.ndarray, phase_rad: np.ndarray, weights: np.ndarray | None = None, min_samples: int = 8
) -> complex:
    """Least-squares phasor P of ``x ~ Re(P exp(j phase)) + c`` over the finite samples.

    Returns NaN when fewer than ``min_samples`` finite samples (or a degenerate fit).
    """
    ok = np.isfinite(x)
    if weights is not None:
        ok &= weights > 0
    if ok.sum() < min_samples:
        return complex(math.nan, math.nan)
    ph = phase_rad[ok]
    w = np.sqrt(weights[ok]) if weights is not None else np.ones(ph.size)
    a = np.column_stack([np.cos(ph), np.sin(ph), np.ones(ph.size)]) * w[:, None]
    coef, _, rank, _ = np.linalg.lstsq(a, x[ok] * w, rcond=None)
    if rank < 3:
        return complex(math.nan, math.nan)
    return complex(coef[0], -coef[1])


def _bode_from_phasors(
    method: str, freqs: np.ndarray, ph: Mapping[str, np.ndarray], pitch_phase_reference: str
) -> Bode:
    if pitch_phase_reference not in ("truth", "sensor"):
        raise CharacterizationError(
            f"pitch_phase_reference must be 'truth' or 'sensor', got {pitch_phase_reference!r}"
        )
    order = np.argsort(freqs)
    freqs = freqs[order]
    ph = {k: v[order] for k, v in ph.items()}

    def phase_curve(num: np.ndarray, den: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            r = np.angle(num / den)
        ok = np.isfinite(r)
        out = np.full(r.shape, np.nan)
        if ok.any():
            u = np.unwrap(r[ok])
            # Put the first point on the principal branch (-180, 180].
            u -= 2 * np.pi * np.round(u[0] / (2 * np.pi))
            out[ok] = u
        return np.degrees(out)

    def align(sensor_deg: np.ndarray, truth_deg: np.ndarray) -> np.ndarray:
        d = sensor_deg - truth_deg
        ok = np.isfinite(d)
        if ok.any():
            sensor_deg = sensor_deg - 360.0 * np.round(np.median(d[ok]) / 360.0)
        return sensor_deg

    def amp(x: np.ndarray) -> np.ndarray:
        return np.asarray(np.degrees(np.abs(x)))

    st_s = phase_curve(ph["stroke_sensor"], ph["drive"])
    st_t = phase_curve(ph["stroke_truth"], ph["drive"])
    stroke = ChannelBode(
        freqs, amp(ph["stroke_sensor"]), amp(ph["stroke_truth"]), align(st_s, st_t), st_t, "drive"
    )
    ref_s = ph["stroke_truth"] if pitch_phase_reference == "truth" else ph["stroke_sensor"]
    pi_s = phase_curve(ph["pitch_sensor"], ref_s)
    pi_t = phase_curve(ph["pitch_truth"], ph["stroke_truth"])
    ref_name = "stroke_truth" if pitch_phase_reference == "truth" else "stroke (same source)"
    pitch = ChannelBode(
        freqs, amp(ph["pitch_sensor"]), amp(ph["pitch_truth"]), align(pi_s, pi_t), pi_t, ref_name
    )
    return Bode(method, stroke, pitch)


def run_signals(
    drive_v: np.ndarray,
    stroke_sensor_rad: np.ndarray,
    pitch_sensor_rad: np.ndarray,
    stroke_truth_rad: np.ndarray,
    pitch_truth_rad: np.ndarray,
) -> dict[str, np.ndarray]:
    d = as_1d(drive_v, "drive_v")
    n = d.size
    return {
        "drive": d,
        "stroke_sensor": as_1d(stroke_sensor_rad, "stroke_sensor_rad", n),
        "stroke_truth": as_1d(stroke_truth_rad, "stroke_truth_rad", n),
        "pitch_sensor": as_1d(pitch_sensor_rad, "pitch_sensor_rad", n),
        "pitch_truth": as_1d(pitch_truth_rad, "pitch_truth_rad", n),
    }


def bode_from_chirp(
    drive_v: np.ndarray,
    stroke_sensor_rad: np.ndarray,
    pitch_sensor_rad: np.ndarray,
    stroke_truth_rad: np.ndarray,
    pitch_truth_rad: np.ndarray,
    fs_hz: float,
    *,
    frequency_hz_per_sample: np.ndarray | None = None,
    frequencies_hz: Sequence[float] | None = None,
    window_s: float = 0.03,
    pitch_phase_reference: str = "truth",
) -> Bode:
    """Bode data from a frequency sweep by sliding, phase-tracking sine fits.

    Parameters
    ----------
    drive_v, stroke_sensor_rad, pitch_sensor_rad, stroke_truth_rad, pitch_truth_rad
        Equal-length records (truth may hold NaN).
    fs_hz
        Sample rate.
    frequency_hz_per_sample
        Known instantaneous drive frequency (else estimated from the drive's analytic signal).
    frequencies_hz
        Points to evaluate (default every 5 Hz from 60 Hz to the top of the sweep).
    window_s
        Length of the Hann-weighted fit window.
    pitch_phase_reference
        "truth" or "sensor" (see module docstring).
    """
    sig = run_signals(
        drive_v, stroke_sensor_rad, pitch_sensor_rad, stroke_truth_rad, pitch_truth_rad
    )
    n = sig["drive"].size
    if frequency_hz_per_sample is not None:
        track = as_1d(frequency_hz_per_sample, "frequency_hz_per_sample", n)
        phase = _phase_from_track(track, fs_hz)
    else:
        phase, track = frequency_track_from_drive(sig["drive"], fs_hz)
    rising = np.maximum.accumulate(track)
    if frequencies_hz is None:
        lo, hi = max(60.0, float(np.nanmin(track))), float(rising[-1])
        freqs = np.arange(math.ceil(lo / 5.0) * 5.0, hi + 1e-9, 5.0)
    else:
        freqs = np.asarray(frequencies_hz, float)
    half = max(4, round(window_s * fs_hz / 2))
    out_f: list[float] = []
    out: dict[str, list[complex]] = {k: [] for k in SIGNALS}
    for f in freqs:
        c = int(np.searchsorted(rising, f))
        if c >= n:
            continue
        a, b = max(0, c - half), min(n, c + half)
        w = np.hanning(2 * half + 2)[1:-1][a - (c - half) : b - (c - half)]
        out_f.append(f)
        for k in SIGNALS:
            out[k].append(sine_phasor(sig[k][a:b], phase[a:b], w))
    return _bode_from_phasors(
        "chirp",
        np.asarray(out_f),
        {k: np.asarray(v, complex) for k, v in out.items()},
        pitch_phase_reference,
    )


def bode_from_stepped(
    drive_v: np.ndarray,
    stroke_sensor_rad: np.ndarray,
    pitch_sensor_rad: np.ndarray,
    stroke_truth_rad: np.ndarray,
    pitch_truth_rad: np.ndarray,
    fs_hz: float,
    frequency_hz_per_sample: np.ndarray,
    *,
    settle_fraction: float = 0.5,
    pitch_phase_reference: str = "truth",
) -> Bode:
    """Bode data from stepped sines: sine fit at the known frequency over each dwell's steady part.

    Parameters
    ----------
    frequency_hz_per_sample
        Drive frequency of every sample (piecewise constant; 0 = no drive).
    settle_fraction
        Fraction of each dwell, at its end, used for the fit.
    """
    sig = run_signals(
        drive_v, stroke_sensor_rad, pitch_sensor_rad, stroke_truth_rad, pitch_truth_rad
    )
    n = sig["drive"].size
    track = as_1d(frequency_hz_per_sample, "frequency_hz_per_sample", n)
    if not 0 < settle_fraction <= 1:
        raise CharacterizationError(f"settle_fraction must be in (0, 1], got {settle_fraction!r}")
    segs = stepped_segments(track)
    if not segs:
        raise CharacterizationError(
            "frequency_hz_per_sample has no dwell with a positive frequency"
        )
    t = np.arange(n) / fs_hz
    out_f: list[float] = []
    out: dict[str, list[complex]] = {k: [] for k in SIGNALS}
    for a, b, f in segs:
        a2 = b - max(8, round(settle_fraction * (b - a)))
        a2 = max(a, a2)
        ph = 2 * np.pi * f * t[a2:b]
        out_f.append(f)
        for k in SIGNALS:
            out[k].append(sine_phasor(sig[k][a2:b], ph))
    return _bode_from_phasors(
        "stepped",
        np.asarray(out_f),
        {k: np.asarray(v, complex) for k, v in out.items()},
        pitch_phase_reference,
    )


def amplitude_phase_rmse(
    bode: ChannelBode, band_hz: tuple[float, float] | None = None
) -> tuple[float, float]:
    """RMSE of sensor vs truth amplitude (deg) and of the wrapped phase difference (deg).

    Over all frequency points, or over those within ``band_hz`` (inclusive).
    """
    sel = np.ones(bode.frequency_hz.shape, bool)
    if band_hz is not None:
        sel = (bode.frequency_hz >= band_hz[0]) & (bode.frequency_hz <= band_hz[1])
    da = (bode.sensor_amplitude_deg - bode.truth_amplitude_deg)[sel]
    dp = wrap_deg(bode.sensor_phase_deg - bode.truth_phase_deg)[sel]
    return rms(da), rms(dp)
