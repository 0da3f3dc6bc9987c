"""Residual diagnosis: noise, whiteness, drive
correlation, bands, levels, harmonics, worst stretch.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
from scipy import stats

from flaair_model.effects import SENSOR_CHANNELS
from flaair_model.model import Model
from flaair_model.settings import DiscrepancySettings
from flaair_sensors.core.bode import frequency_track_from_drive
from flaair_sensors.core.characterization import tiled_transfer

from .runs import Run, measured_motion, sensor_voltage
from .vocabulary import CHANNELS, SENSOR_SIDE, UPSTREAM_TRUTH

# ---------------------------------------------------------------------------- residual stats


def _demean(r: np.ndarray) -> np.ndarray:
    ok = np.isfinite(r)
    if ok.any():
        return cast(np.ndarray, r - np.mean(r[ok]))
    return r


def channel_residual(
    run: Run,
    sim: Mapping[str, np.ndarray],
    channel: str,
    model: Model | None = None,
    truth_referenced: bool = False,
) -> np.ndarray:
    """Measured minus simulated record (mean removed); NaN where the measurement is missing.

    truth_referenced (sensor channels): the sensor is simulated with the *measured* angle as its
    input (`measured_motion`), so an error of the simulated angle is not counted against the
    sensor; NaN where the truth is missing.
    """
    if truth_referenced and channel in SENSOR_CHANNELS:
        side = SENSOR_SIDE[channel]
        stroke, pitch = measured_motion(
            run, np.radians(sim["stroke_deg"]), np.radians(sim["pitch_deg"]), side
        )
        r = run.channel(channel) - sensor_voltage(
            cast(Model, model),
            run.fs_hz,
            stroke,
            pitch,
            run.drive_v,
            side,  # given with the ref
        )
        r = np.where(np.isfinite(run.channel(UPSTREAM_TRUTH[channel])), r, np.nan)
    else:
        r = run.channel(channel) - sim[channel]
    return _demean(r)


def _signal_ss(run: Run, channel: str) -> tuple[float, int]:
    x = run.channel(channel)
    x = x[np.isfinite(x)]
    return float(np.sum((x - x.mean()) ** 2)), int(x.size)


def noise_estimates(
    runs: Sequence[Run], sims: Sequence[Mapping[str, np.ndarray]], model: Model
) -> dict[str, float]:
    """Noise RMS of each channel from the residual's second differences (MAD, robust).

    A smooth model error hardly changes second differences at the sample rate (a 200 Hz error
    is scaled by (2 pi 200 / fs)^2 = 0.004 at 20 kHz), while white noise of RMS s gives second
    differences of RMS s sqrt(6). Where fewer than 64 triples of consecutive finite samples
    exist (ground truth at a low frame rate), the model's noise section is used instead.
    """
    spec = {
        "stroke_deg": model.noise.tracking_noise_deg_rms,
        "pitch_deg": model.noise.tracking_noise_deg_rms,
        "stroke_sensor_v": model.noise.sensor_noise_v_rms,
        "pitch_sensor_v": model.noise.sensor_noise_v_rms,
    }
    out = {}
    for c in CHANNELS:
        parts = []
        for run, sim in zip(runs, sims, strict=True):
            r = run.channel(c) - sim[c]
            d2 = r[2:] - 2.0 * r[1:-1] + r[:-2]
            parts.append(d2[np.isfinite(d2)])
        d2 = np.concatenate(parts) if parts else np.zeros(0)
        if d2.size >= 64:
            mad = float(np.median(np.abs(d2 - np.median(d2))))
            est = 1.4826 * mad / math.sqrt(6.0)
            out[c] = est if est > 0 else max(spec[c], 1e-12)
        else:
            out[c] = max(spec[c], 1e-12)
    return out


def _autocorr_sums(x: np.ndarray, lags: int) -> np.ndarray:
    """sum_t x[t] x[t+k] for k = 0..lags (FFT)."""
    n = x.size
    size = 1 << math.ceil(math.log2(max(2 * n, 2)))
    f = np.fft.rfft(x, size)
    return np.fft.irfft(f * np.conj(f), size)[: lags + 1]


def _ljung_box(r: np.ndarray, lags: int) -> tuple[float, float]:
    """Ljung-Box Q and p-value of a record with NaN gaps (pairs with a NaN are skipped)."""
    ok = np.isfinite(r)
    n = int(ok.sum())
    if n < 4 * lags:
        return math.nan, math.nan
    x = np.where(ok, r, 0.0)
    x[ok] -= x[ok].mean()
    var = float(np.dot(x, x)) / n
    if var <= 0:
        return 0.0, 1.0
    sums = _autocorr_sums(x, lags)
    pairs = np.round(_autocorr_sums(ok.astype(float), lags)).astype(np.int64)
    k = np.arange(1, lags + 1)
    m = pairs[1:]
    valid = m >= 8
    rho = np.where(valid, sums[1:] / np.maximum(m, 1) / var, 0.0)
    q = float(n * (n + 2) * np.sum(rho**2 / np.maximum(n - k, 1)))
    return q, float(stats.chi2.sf(q, lags))


def _xcorr_with_drive(r: np.ndarray, drive: np.ndarray, max_lag: int) -> tuple[float, int, int]:
    """Largest |normalised cross-correlation| of residual
    r(t) with drive(t - lag), lag 0..max_lag.
    """
    ok = np.isfinite(r)
    n = int(ok.sum())
    if n < 16:
        return 0.0, 0, n
    x = np.where(ok, r, 0.0)
    x[ok] -= x[ok].mean()
    d = np.where(ok, drive - drive.mean(), 0.0)
    den = math.sqrt(float(np.dot(x, x)) * float(np.dot(d, d)))
    if den <= 0:
        return 0.0, 0, n
    size = 1 << math.ceil(math.log2(2 * x.size))
    cc = (
        np.fft.irfft(np.fft.rfft(x, size) * np.conj(np.fft.rfft(d, size)), size)[: max_lag + 1]
        / den
    )
    lag = int(np.argmax(np.abs(cc)))
    return float(cc[lag]), lag, n


# ------------------------------------------------------------------------------- diagnostics


@dataclass(frozen=True)
class ChannelGap:
    """Where and how one channel's model disagrees with the measurement.

    Attributes
    ----------
    channel : measured channel.
    nrmse : residual RMS / measured RMS, all runs pooled.
    noise_nrmse : noise RMS / measured RMS (the floor an exact model reaches).
    noise_ratio : residual RMS / noise RMS.
    model_error_nrmse : sqrt(max(residual^2 - noise^2, 0)) / measured RMS.
    ljung_box_q, ljung_box_p : whiteness test of the decimated residual.
    xcorr_drive : largest normalised cross-correlation of residual with the drive.
    xcorr_lag_s : its lag (residual after drive).
    xcorr_significant : |rho| sqrt(n) > DiscrepancySettings.xcorr_z.
    band_nrmse : {"lo-hi Hz": model-error NRMSE of the samples whose drive frequency is in the
        band}.
    worst_band_hz : band with the largest model-error NRMSE.
    level_nrmse : {drive level V: model-error NRMSE of the runs at that level}.
    level_ratio : model-error NRMSE at the highest over the lowest drive level (NaN: one level).
    harmonic_fraction : residual power fraction at drive harmonics 1..4 (rest: broadband).
    worst_stretch : (run, start s, stop s, model-error NRMSE) of the worst window.
    has_gap : the channel disagrees beyond noise (see module docstring).
    interpretation : one-line reading of the tests.
    """

    channel: str
    nrmse: float
    noise_nrmse: float
    noise_ratio: float
    model_error_nrmse: float
    ljung_box_q: float
    ljung_box_p: float
    xcorr_drive: float
    xcorr_lag_s: float
    xcorr_significant: bool
    band_nrmse: dict[str, Any]
    worst_band_hz: str
    level_nrmse: dict[str, Any]
    level_ratio: float
    harmonic_fraction: dict[str, Any]
    worst_stretch: tuple[Any, ...]
    has_gap: bool
    interpretation: str


@dataclass(frozen=True)
class Diagnosis:
    """Gap of every channel for one model on a set of runs."""

    channels: dict[str, Any]  # channel -> ChannelGap
    noise: dict[str, Any]  # channel -> noise RMS

    @property
    def gaps(self) -> tuple[str, ...]:
        """Channels that have a gap."""
        return tuple(c for c in CHANNELS if self.channels[c].has_gap)


def _excess(rss: float, n: int, sigma: float, ss: float) -> float:
    if n == 0 or ss <= 0:
        return math.nan
    return math.sqrt(max(rss / n - sigma**2, 0.0)) / math.sqrt(ss / n)


def _harmonic_fractions(
    r: np.ndarray, phase: np.ndarray, win: int, orders: int = 4
) -> dict[str, Any]:
    """Residual power at drive harmonics 1..orders over tiled windows (fractions of total)."""
    k = r.size // win
    if k == 0:
        return {}
    w = np.isfinite(r[: k * win]).reshape(k, win).astype(float)
    x = np.where(w > 0, r[: k * win].reshape(k, win), 0.0)
    total = float(np.sum(x * x))
    if total <= 0:
        return {}
    ph = phase[: k * win].reshape(k, win)
    cols = [np.ones_like(ph)]
    for h in range(1, orders + 1):
        cols += [np.cos(h * ph), np.sin(h * ph)]
    a = np.stack(cols, axis=-1)  # (k, win, 1 + 2 orders)
    aw = a * w[..., None]
    normal = np.einsum("kwi,kwj->kij", aw, a) + 1e-9 * np.eye(a.shape[-1])
    coef = np.linalg.solve(normal, np.einsum("kwi,kw->ki", aw, x)[..., None])[..., 0]
    fractions = {}
    for h in range(orders):
        sl = slice(1 + 2 * h, 3 + 2 * h)
        comp = np.einsum("kwi,ki->kw", a[..., sl], coef[:, sl]) * w
        fractions[str(h + 1)] = float(np.sum(comp * comp) / total)
    return fractions


def drive_tracks(runs: Sequence[Run]) -> list[tuple[np.ndarray, np.ndarray]]:
    return [frequency_track_from_drive(r.drive_v, r.fs_hz) for r in runs]


def _level_groups(runs: Sequence[Run]) -> list[float]:
    """Drive level of each run rounded to 5 % so that equal nominal levels group together."""
    levels = [r.drive_level_v for r in runs]
    top = max(levels)
    return [round(lv / top * 20.0) / 20.0 * top for lv in levels]


def _drive_xcorr(
    runs: Sequence[Run], res: Sequence[np.ndarray], settings: DiscrepancySettings
) -> tuple[tuple[float, int, int], bool]:
    """The residual's strongest cross-correlation with the drive over the runs (rho, lag, n)
    and whether it is significant.
    """
    max_lag = max(1, round(settings.xcorr_max_lag_s * runs[0].fs_hz / settings.decimate))
    best = (0.0, 0, 0)
    for run, r in zip(runs, res, strict=True):
        rho, lag, m = _xcorr_with_drive(
            r[:: settings.decimate], run.drive_v[:: settings.decimate], max_lag
        )
        if abs(rho) * math.sqrt(max(m, 1)) > abs(best[0]) * math.sqrt(max(best[2], 1)):
            best = (rho, lag, m)
    return best, abs(best[0]) * math.sqrt(max(best[2], 1)) > settings.xcorr_z


def _bands(
    runs: Sequence[Run],
    res: Sequence[np.ndarray],
    tracks: Sequence[tuple[np.ndarray, np.ndarray]],
    c: str,
    sigma: float,
    edges: Sequence[float],
    win: int,
) -> tuple[dict[str, float], str]:
    """The model error above noise per band of the drive's instantaneous frequency, and the
    worst band.
    """
    band: dict[str, float] = {}
    worst_band, worst_val = "", -1.0
    for lo, hi in itertools.pairwise(edges):
        rss_b, n_b = 0.0, 0
        ss_b = 0.0
        for run, r, (_, f) in zip(runs, res, tracks, strict=True):
            sel = (f >= lo) & (f < hi) & np.isfinite(r)
            if sel.sum() < win:
                continue
            x = run.channel(c)[sel]
            rss_b += float(np.sum(r[sel] ** 2))
            n_b += int(sel.sum())
            ss_b += float(np.sum((x - np.nanmean(run.channel(c))) ** 2))
        if n_b:
            label = f"{lo:g}-{hi:g}" if hi < 1e8 else f">{lo:g}"
            band[label] = _excess(rss_b, n_b, sigma, ss_b)
            if band[label] > worst_val:
                worst_band, worst_val = label, band[label]
    return band, worst_band


def _drive_levels(
    levels: Sequence[float],
    res: Sequence[np.ndarray],
    ss_n: Sequence[tuple[float, int]],
    sigma: float,
) -> tuple[dict[str, float], float]:
    """The model error above noise per drive level, and highest over lowest level's."""
    level_vals = {}
    for lv in sorted(set(levels)):
        idx = [i for i, l in enumerate(levels) if l == lv]
        rss_l = sum(float(np.nansum(res[i] ** 2)) for i in idx)
        n_l = sum(int(np.isfinite(res[i]).sum()) for i in idx)
        ss_l = sum(ss_n[i][0] for i in idx)
        level_vals[f"{lv:.3g}"] = _excess(rss_l, n_l, sigma, ss_l)
    if len(level_vals) <= 1:
        return level_vals, math.nan
    keys = sorted(level_vals, key=float)
    lo_v, hi_v = level_vals[keys[0]], level_vals[keys[-1]]
    return level_vals, hi_v / lo_v if lo_v > 0 else (math.inf if hi_v > 0 else math.nan)


def _harmonics(
    res: Sequence[np.ndarray], tracks: Sequence[tuple[np.ndarray, np.ndarray]], win: int
) -> dict[str, float]:
    """The residual's power fractions at the drive's harmonics 1-4 (runs pooled, power-weighted)."""
    hp = np.zeros(4)
    total = 0.0
    for r, (phase, _) in zip(res, tracks, strict=True):
        fr = _harmonic_fractions(r, phase, win)
        tot = float(np.nansum(r**2))
        for h in range(4):
            hp[h] += fr.get(str(h + 1), 0.0) * tot
        total += tot
    return {str(h + 1): float(hp[h] / total) if total > 0 else 0.0 for h in range(4)}


def _worst_stretch(
    runs: Sequence[Run], res: Sequence[np.ndarray], c: str, sigma: float, win: int
) -> tuple[str, float, float, float]:
    """The window of the largest model error above noise: (run, start s, end s, its NRMSE)."""
    worst = ("", math.nan, math.nan, -1.0)
    for run, r in zip(runs, res, strict=True):
        k = r.size // win
        if k == 0:
            continue
        x = run.channel(c)
        blocks = r[: k * win].reshape(k, win)
        ok = np.isfinite(blocks)
        cnt = ok.sum(axis=1)
        ms = np.where(cnt > 0, np.nansum(blocks**2, axis=1) / np.maximum(cnt, 1), np.nan)
        sig_ms = np.nanvar(x[np.isfinite(x)]) if np.isfinite(x).any() else math.nan
        if not sig_ms > 0:
            continue
        ex = np.sqrt(np.maximum(ms - sigma**2, 0.0) / sig_ms)
        if np.all(np.isnan(ex)):
            continue
        j = int(np.nanargmax(ex))
        if ex[j] > worst[3]:
            worst = (run.name, j * win / run.fs_hz, (j + 1) * win / run.fs_hz, float(ex[j]))
    return worst


def diagnose(
    runs: Sequence[Run],
    sims: Sequence[Mapping[str, np.ndarray]],
    model: Model,
    noise: Mapping[str, float],
    settings: DiscrepancySettings,
    tracks: Sequence[tuple[np.ndarray, np.ndarray]] | None = None,
) -> Diagnosis:
    """Localise the disagreement of `sims` (one per run) with the runs, channel by channel.

    Parameters
    ----------
    runs, sims
        Measured runs and the model's simulation of each.
    model
        The simulated model (sensor gains for truth-referenced residuals are not used here).
    noise
        Noise RMS per channel (`noise_estimates`).
    settings
        Thresholds.
    tracks
        Drive phase and frequency of each run (computed if not given).
    """
    tracks = list(tracks) if tracks is not None else drive_tracks(runs)
    levels = _level_groups(runs)
    win = max(8, round(settings.window_s * runs[0].fs_hz))
    out = {}
    for c in CHANNELS:
        sigma = float(noise[c])
        res = [channel_residual(run, sim, c) for run, sim in zip(runs, sims, strict=True)]
        ss_n = [_signal_ss(run, c) for run in runs]
        rss = sum(float(np.nansum(r**2)) for r in res)
        n = sum(int(np.isfinite(r).sum()) for r in res)
        ss = sum(s for s, _ in ss_n)
        has_gap, ratio, q, p = gap_test(res, sigma, settings)
        best, xsig = _drive_xcorr(runs, res, settings)
        band, worst_band = _bands(runs, res, tracks, c, sigma, settings.band_edges_hz, win)
        level_vals, level_ratio = _drive_levels(levels, res, ss_n, sigma)
        harmonics = _harmonics(res, tracks, win)
        out[c] = ChannelGap(
            channel=c,
            nrmse=math.sqrt(rss / ss) if ss > 0 else math.nan,
            noise_nrmse=sigma / math.sqrt(ss / n) if ss > 0 and n else math.nan,
            noise_ratio=ratio,
            model_error_nrmse=_excess(rss, n, sigma, ss),
            ljung_box_q=q,
            ljung_box_p=p,
            xcorr_drive=best[0],
            xcorr_lag_s=best[1] * settings.decimate / runs[0].fs_hz,
            xcorr_significant=bool(xsig),
            band_nrmse=band,
            worst_band_hz=worst_band,
            level_nrmse=level_vals,
            level_ratio=level_ratio,
            harmonic_fraction=harmonics,
            worst_stretch=_worst_stretch(runs, res, c, sigma, win),
            has_gap=has_gap,
            interpretation=interpret(ratio, p, xsig, harmonics, level_ratio, has_gap, settings),
        )
    return Diagnosis(channels=out, noise=dict(noise))


def interpret(
    ratio: float,
    p: float,
    xsig: bool,
    harmonics: Mapping[str, float],
    level_ratio: float,
    has_gap: bool,
    settings: DiscrepancySettings,
) -> str:
    if not has_gap:
        return "residual at noise level and white: the model explains this channel"
    parts = [f"residual {ratio:.2f}x noise, not white (Ljung-Box p={p:.1e})"]
    parts.append(
        "correlated with the drive: a linear path from the drive is mis-modelled"
        if xsig
        else "not linearly correlated with the drive: a nonlinear or time-varying path"
    )
    if harmonics:
        higher = sum(v for k, v in harmonics.items() if k != "1")
        if higher > 0.05:
            parts.append(f"{higher:.0%} of it at drive harmonics 2-4 (a nonlinearity)")
    if math.isinf(level_ratio):
        parts.append("only at the highest drive level (an amplitude threshold, e.g. a stop)")
    elif level_ratio == 0:
        parts.append("only at the lower drive levels (none at full drive)")
    elif math.isfinite(level_ratio):
        if level_ratio > 1.5:
            parts.append(
                f"relative error {level_ratio:.2f}x larger at full drive (grows with amplitude)"
            )
        elif level_ratio < 1 / 1.5:
            parts.append(
                f"relative error {1 / level_ratio:.2f}x larger at low drive (shrinks with "
                "amplitude)"
            )
        else:
            parts.append(
                "relative error about the same at every drive level (amplitude independent)"
            )
    return "; ".join(parts)


def nrmse_by_channel(
    runs: Sequence[Run], sims: Sequence[Mapping[str, np.ndarray]]
) -> dict[str, float]:
    """Residual RMS / measured RMS per channel, pooled over runs (means removed per run)."""
    out = {}
    for c in CHANNELS:
        rss = sum(
            float(np.nansum(channel_residual(run, sim, c) ** 2))
            for run, sim in zip(runs, sims, strict=True)
        )
        ss = sum(_signal_ss(run, c)[0] for run in runs)
        out[c] = math.sqrt(rss / ss) if ss > 0 else math.nan
    return out


def gap_test(
    res: Sequence[np.ndarray], sigma: float, settings: DiscrepancySettings
) -> tuple[bool, float, float, float]:
    """(has_gap, noise ratio, Ljung-Box Q, p) of residual records."""
    rss = sum(float(np.nansum(r**2)) for r in res)
    n = sum(int(np.isfinite(r).sum()) for r in res)
    ratio = math.sqrt(rss / n) / sigma if n and sigma > 0 else math.inf
    dec = settings.whiteness_decimate
    joined = np.concatenate(
        [np.r_[r[::dec], np.full(settings.ljung_box_lags, np.nan)] for r in res]
    )
    q, p = _ljung_box(joined, settings.ljung_box_lags)
    has_gap = bool(
        ratio > settings.gap_noise_ratio and (not math.isfinite(p) or p < settings.whiteness_alpha)
    )
    return has_gap, ratio, q, p


# ----------------------------------------------------------------------------------- Bode


def bode_points(
    run: Run,
    sim: Mapping[str, np.ndarray],
    window_s: float = 0.025,
    track: tuple[np.ndarray, np.ndarray] | None = None,
) -> dict[str, Any]:
    """Amplitude and phase (relative to the drive) of measured and simulated channels per window.

    `flaair_sensors.core.characterization.tiled_transfer` on every channel, measured and model.
    Returns {"frequency_hz": (k,), channel: {"measured": complex (k,), "model": complex (k,)}}
    with phasors per volt of drive.
    """
    signals = {
        f"{c}/{src}": (run.channel(c) if src == "measured" else sim[c])
        for c in CHANNELS
        for src in ("measured", "model")
    }
    freq, tf = tiled_transfer(signals, run.drive_v, run.fs_hz, window_s, track)
    out: dict[str, Any] = {"frequency_hz": freq}
    for c in CHANNELS:
        out[c] = {src: tf[f"{c}/{src}"] for src in ("measured", "model")}
    return out
