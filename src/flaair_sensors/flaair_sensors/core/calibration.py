"""Sensor calibration against ground truth: gain, polarity, offset and lag per sensor.

Pure core: numpy and scipy only. Input is a measured-run record (columns of
docs/LAB_CSV_FORMAT.md: voltages in V, truth in deg, NaN where the video lost the wing);
output is a plain dict ready for JSON, read back by ``frontend_params.params_from_calibration``::

    angle_deg(t) = polarity * gain_deg_per_v * (V(t + lag_s) - reference_voltage_v - offset_v)

Method, per sensor
    On the finite truth samples, least squares of
    ``truth_deg(t) ~ g * V(t + lag) + sum_k c_k ((t - t_mid)/T)^k`` (``trend_order`` terms absorb
    V_HREF error and slow sensor drift, so the fit is not biased by drift or by a drift-removing
    high-pass). The lag is found by a coarse search over integer lags within ``max_lag_s`` and
    refined to sub-sample precision (bounded scalar minimisation, cubic-spline interpolation of
    the fully-sampled sensor record). ``gain_deg_per_v = |g|``, ``polarity = sign(g)``,
    ``offset_v`` = zero-angle voltage at mid-record minus ``reference_voltage_v``.

Figures (as ``characterization``)
    With the fitted gain, polarity and offset but *without* lag correction (the paper's
    convention), the sensor angle and the truth are compared by phase-tracking sine fits
    in windows tiled over the run: ``amplitude_rmse_deg`` / ``phase_rmse_deg`` over all windows,
    ``amplitude_rmse_band_deg`` over the windows within ``amplitude_band_hz``. Phase error is the
    sensor's phase minus its own truth's phase (pitch: relative to ground-truth stroke).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from .bode import CharacterizationError, frequency_track_from_drive, sine_phasor, wrap_deg
from .characterization import fit_delay

__all__ = ["CHANNELS", "CalibrationError", "calibrate", "calibrate_channel"]

CHANNELS = {"stroke": ("stroke_sensor_v", "stroke_deg"), "pitch": ("pitch_sensor_v", "pitch_deg")}


class CalibrationError(ValueError):
    """Calibration impossible; the message names the column and the problem."""


def _column(run: Mapping[str, Any], name: str, n: int | None = None) -> np.ndarray:
    if name not in run:
        raise CalibrationError(f"run has no column '{name}'")
    try:
        a = np.asarray(run[name], dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"column '{name}' is not numeric: {exc}") from None
    if n is not None and a.size != n:
        raise CalibrationError(f"column '{name}' has {a.size} samples, expected {n}")
    return a


def _sample_rate(run: Mapping[str, Any], sample_rate_hz: float | None) -> tuple[float, int]:
    if sample_rate_hz is not None:
        if not (math.isfinite(sample_rate_hz) and sample_rate_hz > 0):
            raise CalibrationError(f"sample_rate_hz must be positive, got {sample_rate_hz!r}")
        n = _column(run, CHANNELS["stroke"][0]).size
        return float(sample_rate_hz), n
    t = _column(run, "time_s")
    if t.size < 2 or not np.all(np.isfinite(t)):
        raise CalibrationError("column 'time_s' must hold at least two finite samples")
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0)) + 1
        raise CalibrationError(f"column 'time_s' is not increasing (sample {i})")
    step = float(np.median(dt))
    if np.max(np.abs(dt - step)) > 1e-3 * step:
        raise CalibrationError("column 'time_s' is not uniformly sampled")
    return 1.0 / step, t.size


def _check_sensor(
    v: np.ndarray, name: str, rails_v: tuple[float, float] | None, flat_fraction: float
) -> None:
    bad = ~np.isfinite(v)
    if bad.any():
        raise CalibrationError(
            f"column '{name}' has {int(bad.sum())} non-finite samples (first at index "
            f"{int(np.argmax(bad))}); sensor columns must be complete"
        )
    if rails_v is not None:
        lo, hi = rails_v
        at_rail = (v <= lo) | (v >= hi)
        if at_rail.any():
            raise CalibrationError(
                f"column '{name}' is saturated: {int(at_rail.sum())} samples at or beyond the "
                f"rails [{lo:g}, {hi:g}] V (first at index {int(np.argmax(at_rail))})"
            )
    span = float(v.max() - v.min())
    if span <= 0:
        raise CalibrationError(f"column '{name}' is constant ({v[0]:g} V): no sensor signal")
    tol = 1e-6 * span
    limit = max(5, int(flat_fraction * v.size))
    for extreme, label in ((v.max(), "upper"), (v.min(), "lower")):
        count = int(np.count_nonzero(np.abs(v - extreme) <= tol))
        if count >= limit:
            raise CalibrationError(
                f"column '{name}' looks saturated: {count} samples sit flat at its {label} extreme "
                f"{extreme:g} V (clipped waveform)"
            )


def _window_errors(
    angle_deg: np.ndarray,
    truth_deg: np.ndarray,
    phase: np.ndarray,
    track: np.ndarray,
    fs: float,
    window_s: float,
    min_valid_fraction: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per tiled window: frequency, amplitude error (deg), wrapped phase error (deg)."""
    n = angle_deg.size
    w = max(8, round(window_s * fs))
    hann = np.hanning(w + 2)[1:-1]
    # Truth sampled at a video rate below fs (a finite value every k-th sample) counts as
    # complete at 1/k: min_valid_fraction is relative to the truth's own sampling.
    expected_fraction = 1.0 / truth_stride(truth_deg)
    freqs, damp, dph = [], [], []
    for a in range(0, n - w + 1, w):
        sl = slice(a, a + w)
        y = truth_deg[sl]
        if np.isfinite(y).mean() < min_valid_fraction * expected_fraction:
            continue
        # the sensor is compared on the samples where the truth exists
        ps = sine_phasor(np.where(np.isfinite(y), angle_deg[sl], np.nan), phase[sl], hann)
        pt = sine_phasor(y, phase[sl], hann)
        if not (np.isfinite(ps) and np.isfinite(pt)) or abs(pt) == 0:
            continue
        freqs.append(float(np.mean(track[sl])))
        damp.append(abs(ps) - abs(pt))
        dph.append(float(wrap_deg(np.degrees(np.angle(ps / pt)))))
    return np.asarray(freqs), np.asarray(damp), np.asarray(dph)


def truth_stride(truth_deg: np.ndarray) -> int:
    """Samples between ground-truth values: 1 at the DAQ rate, 20 for 1 kHz video at 20 kHz."""
    index = np.flatnonzero(np.isfinite(truth_deg))
    return max(1, int(np.median(np.diff(index)))) if index.size > 1 else 1


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2))) if x.size else math.nan


def calibrate_channel(
    sensor_v: np.ndarray,
    truth_deg: np.ndarray,
    fs_hz: float,
    reference_voltage_v: float,
    *,
    sensor_name: str = "sensor_v",
    truth_name: str = "truth_deg",
    max_lag_s: float = 2e-3,
    trend_order: int = 1,
    min_valid_truth: int = 500,
) -> dict[str, Any]:
    """Gain, polarity, offset and lag of one sensor (no frequency figures).

    Parameters
    ----------
    sensor_v
        Complete sensor record (V).
    truth_deg
        Ground-truth angle (deg), NaN where unknown.
    fs_hz
        Sample rate.
    reference_voltage_v
        Nominal V_HREF; ``offset_v`` is reported relative to it.
    max_lag_s
        Lag search range (keep below half the shortest drive period for pure tones).
    trend_order
        Polynomial order of the slow drift absorbed by the fit (0: constant offset only).
    min_valid_truth
        Fewest finite truth samples accepted.
    """
    v = np.asarray(sensor_v, float)
    y = np.asarray(truth_deg, float)
    n_ok = int(np.isfinite(y).sum())
    if n_ok < min_valid_truth:
        raise CalibrationError(
            f"column '{truth_name}' has too few valid ground-truth samples ({n_ok} < "
            f"{min_valid_truth})"
        )
    finite = y[np.isfinite(y)]
    if float(np.ptp(finite)) <= 0:
        raise CalibrationError(f"column '{truth_name}' does not move: cannot fit a gain")
    try:
        fit = fit_delay(y, v, fs_hz, max_lag_s=max_lag_s, fit_gain=True, trend_order=trend_order)
    except CharacterizationError as exc:
        raise CalibrationError(f"columns '{sensor_name}'/'{truth_name}': {exc}") from None
    if not (math.isfinite(fit.gain) and fit.gain != 0):
        raise CalibrationError(
            f"column '{sensor_name}' does not follow '{truth_name}': gain fit failed"
        )
    g = fit.gain
    zero_v = -float(fit.trend[0]) / g if fit.trend.size else 0.0
    drift = -float(fit.trend[1]) / g * 2.0 / (v.size / fs_hz) if fit.trend.size > 1 else 0.0
    return {
        "gain_deg_per_v": abs(g),
        "polarity": 1 if g > 0 else -1,
        "offset_v": zero_v - reference_voltage_v,
        "lag_s": fit.lag_s,
        "drift_v_per_s": drift,
        "fit_rmse_deg": fit.rmse,
        "n_valid_truth": n_ok,
    }


def _drive_phase(
    run: Mapping[str, Any], fs: float, n: int, frequency_hz_per_sample: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """The drive's phase and frequency per sample: integrated from the known frequency track,
    or estimated from ``drive_v`` (which must be finite either way).

    Returns
    -------
    tuple
        (phase in rad, frequency in Hz), one value per sample.

    Raises
    ------
    CalibrationError
        ``drive_v`` missing, non-numeric, of another length or non-finite; a frequency track of
        another length.
    """
    drive = _column(run, "drive_v", n)
    if not np.all(np.isfinite(drive)):
        raise CalibrationError("column 'drive_v' has non-finite samples")
    if frequency_hz_per_sample is not None:
        track = np.asarray(frequency_hz_per_sample, float).reshape(-1)
        if track.size != n:
            raise CalibrationError(
                f"frequency_hz_per_sample has {track.size} samples, expected {n}"
            )
        phase = 2 * np.pi * np.cumsum(track) / fs
    else:
        phase, track = frequency_track_from_drive(drive, fs)
    return phase, track


def calibrate(
    run: Mapping[str, Any],
    reference_voltage_v: float,
    *,
    sample_rate_hz: float | None = None,
    frequency_hz_per_sample: np.ndarray | None = None,
    max_lag_s: float = 2e-3,
    trend_order: int = 1,
    min_valid_truth: int = 500,
    rails_v: tuple[float, float] | None = None,
    flat_fraction: float = 0.002,
    window_s: float = 0.03,
    min_valid_fraction: float = 0.5,
    amplitude_band_hz: tuple[float, float],
) -> dict[str, Any]:
    """Calibrate both sensors of a measured run against its ground truth.

    Parameters
    ----------
    run
        Columns ``time_s`` (or give ``sample_rate_hz``), ``drive_v``, ``stroke_sensor_v``,
        ``pitch_sensor_v``, ``stroke_deg``, ``pitch_deg``.
    reference_voltage_v
        Nominal V_HREF (``model.sensors.reference_voltage_v``).
    frequency_hz_per_sample
        Known drive frequency per sample (else estimated from ``drive_v``'s analytic signal).
    max_lag_s, trend_order, min_valid_truth
        See ``calibrate_channel``.
    rails_v
        Known charge-amplifier rails; a sample at or beyond them is a saturation error. Without
        rails, a waveform sitting flat at its extreme for ``flat_fraction`` of the record is.
    window_s, min_valid_fraction
        Tiled fit windows for the amplitude/phase figures, and the finite-truth fraction a window
        needs.
    amplitude_band_hz
        Band of ``amplitude_rmse_band_deg`` (config: ``flaair_sensors.analysis_io``).

    Returns
    -------
    dict
        ``{"reference_voltage_v", "sample_rate_hz", "stroke": {...}, "pitch": {...}}`` with, per
        sensor: gain_deg_per_v, polarity, offset_v, lag_s, amplitude_rmse_deg, phase_rmse_deg,
        amplitude_rmse_band_deg, amplitude_band_hz, drift_v_per_s, fit_rmse_deg, n_valid_truth,
        n_windows.

    Raises
    ------
    CalibrationError
        Missing/non-numeric column, non-finite or saturated sensor samples, too few valid truth
        samples, a truth that does not move, bad time base.
    """
    if not math.isfinite(reference_voltage_v):
        raise CalibrationError(f"reference_voltage_v must be finite, got {reference_voltage_v!r}")
    fs, n = _sample_rate(run, sample_rate_hz)
    phase, track = _drive_phase(run, fs, n, frequency_hz_per_sample)

    result: dict[str, Any] = {
        "reference_voltage_v": float(reference_voltage_v),
        "sample_rate_hz": fs,
    }
    for ch, (vcol, tcol) in CHANNELS.items():
        v = _column(run, vcol, n)
        _check_sensor(v, vcol, rails_v, flat_fraction)
        y = _column(run, tcol, n)
        y = np.where(np.isfinite(y), y, np.nan)
        cal = calibrate_channel(
            v,
            y,
            fs,
            reference_voltage_v,
            sensor_name=vcol,
            truth_name=tcol,
            max_lag_s=max_lag_s,
            trend_order=trend_order,
            min_valid_truth=min_valid_truth,
        )
        angle = (
            cal["polarity"] * cal["gain_deg_per_v"] * (v - reference_voltage_v - cal["offset_v"])
        )
        freqs, damp, dph = _window_errors(angle, y, phase, track, fs, window_s, min_valid_fraction)
        band = (freqs >= amplitude_band_hz[0]) & (freqs <= amplitude_band_hz[1])
        cal.update(
            amplitude_rmse_deg=_rms(damp),
            phase_rmse_deg=_rms(dph),
            amplitude_rmse_band_deg=_rms(damp[band]),
            amplitude_band_hz=[float(amplitude_band_hz[0]), float(amplitude_band_hz[1])],
            n_windows=int(freqs.size),
        )
        result[ch] = _plain(cal)
    return result


def _plain(d: Mapping[str, Any]) -> dict[str, Any]:
    """Python scalars only (JSON-ready)."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, (np.floating, float)):
            out[k] = float(v)
        elif isinstance(v, (np.integer, int)) and not isinstance(v, bool):
            out[k] = int(v)
        else:
            out[k] = v
    return out
