"""Sensor performance characterization (paper, section "Sensor Performance Characterization").

Pure core: numpy and scipy only. Angles are radians inside; every reported figure is in
degrees (``*_deg``), Hz or seconds.

Bode data
    Amplitude (zero-to-peak of the fundamental) and phase of the sensor-derived angle and of
    the ground-truth angle versus frequency.

    * chirp (paper: 20-200 Hz, 1 s): sliding sine fits that track the drive's instantaneous
      phase. In a Hann-weighted window of ``window_s`` centred where the sweep passes each
      requested frequency, every signal is least-squares fitted as
      ``a cos(Phi) + b sin(Phi) + c`` with ``Phi`` the drive phase (from the known frequency
      track, or from the drive's analytic signal), so phases come out relative to the drive.
    * stepped sines (paper: 0.2 s dwell each): per dwell, a sine fit at the known frequency over
      the last ``settle_fraction`` of the dwell (steady state).

    Stroke phase = phase of stroke relative to the drive input. Pitch phase = phase of pitch
    relative to stroke; the stroke reference is the *ground-truth* stroke for both pitch curves
    (``pitch_phase_reference="truth"``, isolates the pitch sensor's own lag) or each curve's own
    stroke (``"sensor"``: sensor pitch vs sensor stroke, truth pitch vs truth stroke).

Figures (``ChannelMetrics``)
    amplitude RMSE between sensor and truth amplitudes over all frequency points and over a band
    (stroke-to-pitch resonance band, default 110-190 Hz); phase RMSE (wrapped sensor-minus-truth
    phase over all points); all-sample time RMSE of sensor angle vs truth; the consistent lag
    (least-squares sub-sample delay); time RMSE after correcting that lag, over all samples and
    over the samples whose drive frequency lies in a band (default 100-190 Hz).

Ground truth may hold NaN (video lost the wing): every fit uses the finite samples only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any, NamedTuple

import numpy as np
from scipy import interpolate, optimize

from flaair_sensors.core.bode import (
    Bode,
    CharacterizationError,
    amplitude_phase_rmse,
    as_1d,
    bode_from_chirp,
    bode_from_stepped,
    frequency_track_from_drive,
    rms,
    run_signals,
    sine_phasor,
)

__all__ = [
    "ChannelMetrics",
    "Characterization",
    "DelayFit",
    "characterize",
    "characterize_run",
    "fit_delay",
    "time_metrics",
]


# ----------------------------------------------------------------------------- result types


@dataclass(frozen=True)
class ChannelMetrics:
    """Paper figures of one sensor (all angles in degrees)."""

    amplitude_rmse_deg: float
    amplitude_rmse_band_deg: float
    amplitude_band_hz: tuple[float, float]
    phase_rmse_deg: float
    time_rmse_deg: float
    lag_s: float
    time_rmse_lag_corrected_deg: float
    time_rmse_lag_corrected_band_deg: float
    time_band_hz: tuple[float, float]
    n_frequency_points: int
    n_truth_samples: int


@dataclass(frozen=True, eq=False)
class Characterization:
    """Bode data and figures of both sensors."""

    bode: Bode
    stroke: ChannelMetrics
    pitch: ChannelMetrics

    def as_dict(self) -> dict[str, Any]:
        """Plain dict, ready for JSON."""
        return {
            "bode": self.bode.as_dict(),
            "stroke": asdict(self.stroke),
            "pitch": asdict(self.pitch),
        }


class DelayFit(NamedTuple):
    """Result of ``fit_delay``: truth ~ gain * sensor(t + lag_s) + trend."""

    lag_s: float
    gain: float
    trend: np.ndarray
    rmse: float
    n_samples: int


# ----------------------------------------------------------------------------- helpers


# ----------------------------------------------------------------------------- Bode


# ----------------------------------------------------------------------------- time domain


def fit_delay(
    truth: np.ndarray,
    sensor: np.ndarray,
    fs_hz: float,
    *,
    max_lag_s: float = 2e-3,
    fit_gain: bool = True,
    trend_order: int = 0,
    min_samples: int = 16,
) -> DelayFit:
    """Least-squares sub-sample delay between a sensor record and a (gappy) truth record.

    Model: ``truth(t) ~ gain * sensor(t + lag_s) + sum_k c_k ((t - t_mid)/T)^k`` on the finite
    truth samples; ``lag_s > 0`` means the sensor is late. ``fit_gain=False`` fixes gain = 1
    (and ``trend_order=-1`` drops the trend). Coarse search over integer lags within
    ``max_lag_s``, then a bounded scalar refinement with cubic-spline interpolation of the
    sensor. For periodic records keep ``max_lag_s`` below half the shortest period.

    Parameters
    ----------
    truth
        Truth record; NaN where unknown.
    sensor
        Sensor record of the same length, all finite.
    fs_hz
        Sample rate.
    """
    y = as_1d(truth, "truth")
    x = as_1d(sensor, "sensor", y.size)
    if not np.all(np.isfinite(x)):
        raise CharacterizationError("sensor record contains non-finite samples")
    n = y.size
    ok = np.isfinite(y)
    if ok.sum() < min_samples:
        raise CharacterizationError(
            f"too few finite truth samples ({int(ok.sum())} < {min_samples})"
        )
    t = np.arange(n, dtype=float)
    idx = np.flatnonzero(ok)
    tc = (t - 0.5 * (n - 1)) / max(1.0, 0.5 * (n - 1))
    trend_cols = [tc**k for k in range(trend_order + 1)] if trend_order >= 0 else []
    max_lag = max(1, math.ceil(max_lag_s * fs_hz))

    def solve(xs: np.ndarray, sel: np.ndarray) -> tuple[float, np.ndarray, float]:
        cols = ([xs] if fit_gain else []) + [c[sel] for c in trend_cols]
        yy = y[sel] - (0.0 if fit_gain else xs)
        if cols:
            a = np.column_stack(cols)
            coef, *_ = np.linalg.lstsq(a, yy, rcond=None)
            r = yy - a @ coef
        else:
            coef, r = np.zeros(0), yy
        gain = float(coef[0]) if fit_gain else 1.0
        trend = coef[1:] if fit_gain else coef
        return gain, trend, float(np.mean(r**2))

    # Coarse: integer lags (keep only truth samples
    # whose shifted sensor sample exists for all lags).
    sel = idx[(idx >= max_lag) & (idx < n - max_lag)]
    if sel.size < min_samples:
        raise CharacterizationError(
            f"too few finite truth samples away from the record ends ({sel.size})"
        )
    costs = np.array([solve(x[sel + m], sel)[2] for m in range(-max_lag, max_lag + 1)])
    m0 = int(np.argmin(costs)) - max_lag
    spline = interpolate.CubicSpline(t, x)

    def cost(lag: float) -> float:
        return solve(spline(sel + lag), sel)[2]

    lo, hi = max(-max_lag, m0 - 1), min(max_lag, m0 + 1)
    res = optimize.minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-4})
    lag = float(res.x)
    gain, trend, mse = solve(spline(sel + lag), sel)
    return DelayFit(lag / fs_hz, gain, trend, math.sqrt(mse), int(sel.size))


def _shift(x: np.ndarray, lag_samples: float) -> np.ndarray:
    """x(t + lag) by cubic-spline interpolation; NaN outside the record."""
    t = np.arange(x.size, dtype=float)
    out: np.ndarray = interpolate.CubicSpline(t, x)(t + lag_samples)
    out[(t + lag_samples < 0) | (t + lag_samples > x.size - 1)] = np.nan
    return out


def time_metrics(
    sensor_rad: np.ndarray,
    truth_rad: np.ndarray,
    fs_hz: float,
    frequency_hz_per_sample: np.ndarray | None = None,
    *,
    band_hz: tuple[float, float],
    max_lag_s: float = 2e-3,
) -> tuple[float, float, float, float, int]:
    """Time-domain figures of one sensor.

    Returns
    -------
    time_rmse_deg, lag_s, time_rmse_lag_corrected_deg, time_rmse_lag_corrected_band_deg, n
        All-sample RMSE; the consistent lag; RMSE after shifting the sensor by that lag, over
        all samples and over the samples whose drive frequency is within ``band_hz``; number of
        finite truth samples.
    """
    s = as_1d(sensor_rad, "sensor_rad")
    y = as_1d(truth_rad, "truth_rad", s.size)
    good = np.isfinite(s)
    n_truth = int(np.isfinite(y).sum())
    rmse = rms(np.degrees(s - y))
    # The lag fit needs a gap-free sensor record: fill unusable sensor samples, drop them after.
    s_fill = s.copy()
    if not good.all():
        if not good.any():
            raise CharacterizationError("sensor_rad has no finite samples")
        i = np.arange(s.size)
        s_fill = np.interp(i, i[good], s[good])
    y_fit = np.where(good, y, np.nan)
    fit = fit_delay(y_fit, s_fill, fs_hz, max_lag_s=max_lag_s, fit_gain=False, trend_order=-1)
    shifted = _shift(s_fill, fit.lag_s * fs_hz)
    shifted_ok = _shift(good.astype(float), fit.lag_s * fs_hz)
    shifted[~(shifted_ok > 0.999)] = np.nan
    err = np.degrees(shifted - y)
    rmse_lag = rms(err)
    if frequency_hz_per_sample is not None:
        track = as_1d(frequency_hz_per_sample, "frequency_hz_per_sample", s.size)
        in_band = (track >= band_hz[0]) & (track <= band_hz[1])
        rmse_band = rms(err[in_band])
    else:
        rmse_band = math.nan
    return rmse, fit.lag_s, rmse_lag, rmse_band, n_truth


# ----------------------------------------------------------------------------- top level


def characterize(
    bode: Bode,
    drive_v: np.ndarray,
    stroke_sensor_rad: np.ndarray,
    pitch_sensor_rad: np.ndarray,
    stroke_truth_rad: np.ndarray,
    pitch_truth_rad: np.ndarray,
    fs_hz: float,
    frequency_hz_per_sample: np.ndarray | None = None,
    *,
    amplitude_band_hz: tuple[float, float],
    time_band_hz: tuple[float, float],
    max_lag_s: float = 2e-3,
) -> Characterization:
    """All paper figures of both sensors from Bode data and the time records.

    ``frequency_hz_per_sample`` selects the in-band samples for the band time RMSE (estimated
    from the drive when omitted).
    """
    sig = run_signals(
        drive_v, stroke_sensor_rad, pitch_sensor_rad, stroke_truth_rad, pitch_truth_rad
    )
    if frequency_hz_per_sample is None:
        _, frequency_hz_per_sample = frequency_track_from_drive(sig["drive"], fs_hz)
    metrics = {}
    for ch, cb in (("stroke", bode.stroke), ("pitch", bode.pitch)):
        amp_all, ph_all = amplitude_phase_rmse(cb)
        amp_band, _ = amplitude_phase_rmse(cb, amplitude_band_hz)
        t_rmse, lag, t_lag, t_band, n_truth = time_metrics(
            sig[f"{ch}_sensor"],
            sig[f"{ch}_truth"],
            fs_hz,
            frequency_hz_per_sample,
            band_hz=time_band_hz,
            max_lag_s=max_lag_s,
        )
        metrics[ch] = ChannelMetrics(
            amplitude_rmse_deg=amp_all,
            amplitude_rmse_band_deg=amp_band,
            amplitude_band_hz=(float(amplitude_band_hz[0]), float(amplitude_band_hz[1])),
            phase_rmse_deg=ph_all,
            time_rmse_deg=t_rmse,
            lag_s=lag,
            time_rmse_lag_corrected_deg=t_lag,
            time_rmse_lag_corrected_band_deg=t_band,
            time_band_hz=(float(time_band_hz[0]), float(time_band_hz[1])),
            n_frequency_points=int(cb.frequency_hz.size),
            n_truth_samples=n_truth,
        )
    return Characterization(bode, metrics["stroke"], metrics["pitch"])


def characterize_run(
    run: Mapping[str, Any],
    params: Any,
    method: str,
    frequency_hz_per_sample: np.ndarray | None = None,
    *,
    sample_rate_hz: float | None = None,
    window_s: float = 0.03,
    settle_fraction: float = 0.5,
    frequencies_hz: Sequence[float] | None = None,
    pitch_phase_reference: str = "truth",
    amplitude_band_hz: tuple[float, float],
    time_band_hz: tuple[float, float],
    max_lag_s: float = 2e-3,
) -> Characterization:
    """Characterize a measured-run record through the front end.

    Parameters
    ----------
    run
        Measured-run columns: ``drive_v``, ``stroke_sensor_v``, ``pitch_sensor_v``,
        ``stroke_deg``, ``pitch_deg`` and ``time_s`` (or give ``sample_rate_hz``).
    params
        ``frontend_params.FrontendParams``; the sensor angles are ``frontend.estimate`` of the
        voltages.
    method
        "chirp" or "stepped" (stepped needs ``frequency_hz_per_sample``).
    """
    # deferred: the front end's numba kernels (0.3-0.5 s); `flaair calibrate` and `flaair health`
    # import this module and never run it
    from .frontend import estimate, initial_state

    for col in ("drive_v", "stroke_sensor_v", "pitch_sensor_v", "stroke_deg", "pitch_deg"):
        if col not in run:
            raise CharacterizationError(f"run has no column '{col}'")
    fs = sample_rate_hz if sample_rate_hz is not None else _rate_from_time(run)
    est = estimate(
        np.asarray(run["stroke_sensor_v"], float),
        np.asarray(run["pitch_sensor_v"], float),
        params,
        initial_state(params),
    )
    stroke_s = np.where(est.stroke_valid, est.stroke_rad, np.nan)
    pitch_s = np.where(est.pitch_valid, est.pitch_rad, np.nan)
    stroke_t = np.radians(np.asarray(run["stroke_deg"], float))
    pitch_t = np.radians(np.asarray(run["pitch_deg"], float))
    drive = np.asarray(run["drive_v"], float)
    if method == "chirp":
        bode = bode_from_chirp(
            drive,
            stroke_s,
            pitch_s,
            stroke_t,
            pitch_t,
            fs,
            frequency_hz_per_sample=frequency_hz_per_sample,
            frequencies_hz=frequencies_hz,
            window_s=window_s,
            pitch_phase_reference=pitch_phase_reference,
        )
    elif method == "stepped":
        if frequency_hz_per_sample is None:
            raise CharacterizationError("method 'stepped' needs frequency_hz_per_sample")
        bode = bode_from_stepped(
            drive,
            stroke_s,
            pitch_s,
            stroke_t,
            pitch_t,
            fs,
            frequency_hz_per_sample,
            settle_fraction=settle_fraction,
            pitch_phase_reference=pitch_phase_reference,
        )
    else:
        raise CharacterizationError(f"method must be 'chirp' or 'stepped', got {method!r}")
    return characterize(
        bode,
        drive,
        stroke_s,
        pitch_s,
        stroke_t,
        pitch_t,
        fs,
        frequency_hz_per_sample,
        amplitude_band_hz=amplitude_band_hz,
        time_band_hz=time_band_hz,
        max_lag_s=max_lag_s,
    )


def _rate_from_time(run: Mapping[str, Any]) -> float:
    if "time_s" not in run:
        raise CharacterizationError("run has no column 'time_s' (or pass sample_rate_hz)")
    t = np.asarray(run["time_s"], float)
    if t.size < 2 or not np.all(np.isfinite(t)):
        raise CharacterizationError("time_s must hold at least two finite samples")
    dt = np.diff(t)
    if np.any(dt <= 0):
        raise CharacterizationError("time_s is not strictly increasing")
    step_s = float(np.median(dt))
    if np.max(np.abs(dt - step_s)) > 1e-3 * step_s:
        raise CharacterizationError("time_s is not uniformly sampled")
    return 1.0 / step_s


def tiled_transfer(
    signals: Mapping[str, np.ndarray],
    drive_v: np.ndarray,
    fs_hz: float,
    window_s: float = 0.025,
    track: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Transfer function from the drive to each signal, in tiled windows of a sweep.

    In each window of ``window_s`` every signal and the drive are fitted as a sine of the drive's
    instantaneous phase plus a constant (`sine_phasor`, NaN samples skipped); the ratio is the
    transfer function at the window's median drive frequency.

    Parameters
    ----------
    signals
        name -> (n,) record (may hold NaN, e.g. video-rate truth).
    drive_v
        (n,) drive.
    fs_hz
        Sample rate.
    window_s
        Window length.
    track
        (phase rad, frequency Hz) of the drive, from `frequency_track_from_drive` if not given.

    Returns
    -------
    (frequency_hz (k,), {name: complex (k,) per volt of drive, NaN where not estimable})
    """
    d = as_1d(drive_v, "drive_v")
    phase, freq = track if track is not None else frequency_track_from_drive(d, fs_hz)
    win = max(8, round(window_s * fs_hz))
    k = d.size // win
    f_out = np.full(k, np.nan)
    out = {name: np.full(k, complex(math.nan, math.nan)) for name in signals}
    for j in range(k):
        sl = slice(j * win, (j + 1) * win)
        dp = sine_phasor(d[sl], phase[sl])
        if not abs(dp) > 1e-9:
            continue
        f_out[j] = float(np.median(freq[sl]))
        for name, x in signals.items():
            out[name][j] = sine_phasor(np.asarray(x[sl], float), phase[sl]) / dp
    return f_out, out
