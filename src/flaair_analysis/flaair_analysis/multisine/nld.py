"""Best linear approximation, noise and nonlinear distortion from line spectra
(../shared/multisine.md, section 3: the robust method of Pintelon and Schoukens), pure.

From Y_mp(k) (M runs x P periods): Ybar_m = mean over p, the noise variance of Ybar_m
sigma2_m = sum_p |Y_mp - Ybar_m|^2 / (P (P - 1)), and over the M runs the BLA
G = mean_m Ybar_m / Ubar_m with the standard deviations of that mean from noise (std_noise)
and from the nonlinear distortion (std_nl); the band levels in dB (`signal`, `noise`, `odd`,
`even`), the class, and with a model's spectra the distortion it does not predict.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "CLASSES",
    "DB_FLOOR",
    "LEVEL_STEP_DB",
    "MARGIN_DB",
    "ChannelFigures",
    "LineSets",
    "bla",
    "classify",
    "db",
    "disagreements",
    "level_trend",
    "levels_db",
    "line_sets",
    "model_figures",
]

MARGIN_DB = 6.0  # a distortion counts at noise + this
LEVEL_STEP_DB = 1.0  # runs whose drive RMS differ by this much are at two drive levels
DB_FLOOR = 1e-30  # dB = 10 log10(max(x, this))
CLASSES = ("linear", "odd", "even", "odd+even")


@dataclass(frozen=True)
class LineSets:
    """E excited, O odd detection (odd lines of the band not excited), V even lines of the band;
    B every line from min E to max E.
    """

    excited: np.ndarray
    odd: np.ndarray
    even: np.ndarray
    band: np.ndarray


def line_sets(excited: Sequence[int]) -> LineSets:
    """E, O, V and B of the excited lines (sorted, odd, two or more)."""
    e = np.array(sorted(int(k) for k in excited), dtype=np.int64)
    band = np.arange(e[0], e[-1] + 1, dtype=np.int64)
    odd = band[(band % 2 == 1) & ~np.isin(band, e)]
    even = band[band % 2 == 0]
    return LineSets(e, odd, even, band)


def db(x: float) -> float:
    """10 log10(max(x, 1e-30))."""
    return float(10.0 * np.log10(max(float(x), DB_FLOOR)))


@dataclass(frozen=True)
class ChannelFigures:
    """One channel's figures: the mean spectra and their noise, per run and line."""

    ybar: np.ndarray  # (M, K) mean over periods
    sigma2: np.ndarray  # (M, K) noise variance of ybar (zeros when P = 1)

    @staticmethod
    def of(spectra: np.ndarray) -> ChannelFigures:
        """From Y_mp(k), shape (M, P, K)."""
        periods = spectra.shape[1]
        ybar = spectra.mean(axis=1)
        if periods > 1:
            resid = np.abs(spectra - ybar[:, None, :]) ** 2
            sigma2 = resid.sum(axis=1) / (periods * (periods - 1))
        else:
            sigma2 = np.zeros(ybar.shape)
        return ChannelFigures(ybar, sigma2)

    def power(self) -> np.ndarray:
        """|Ybar|^2 averaged over the runs, per line."""
        return np.asarray(np.mean(np.abs(self.ybar) ** 2, axis=0))


def _mean_over(values: np.ndarray, lines: np.ndarray) -> float | None:
    return float(np.mean(values[:, lines])) if lines.size else None


def levels_db(figs: ChannelFigures, sets: LineSets) -> dict[str, float | None]:
    """The levels: signal (over E), noise (sigma2 over B), odd (over O; None if O is empty),
    even (over V).
    """
    p = np.abs(figs.ybar) ** 2
    odd = _mean_over(p, sets.odd)
    even = _mean_over(p, sets.even)
    return {
        "signal": db(float(np.mean(p[:, sets.excited]))),
        "noise": db(float(np.mean(figs.sigma2[:, sets.band]))),
        "odd": None if odd is None else db(odd),
        "even": None if even is None else db(even),
    }


def classify(levels: dict[str, float | None], noise_db: float, margin_db: float = MARGIN_DB) -> str:
    """linear, odd, even or odd+even: a distortion counts at >= noise + margin."""
    odd = levels.get("odd")
    even = levels.get("even")
    has_odd = odd is not None and odd >= noise_db + margin_db
    has_even = even is not None and even >= noise_db + margin_db
    return {
        (False, False): "linear",
        (True, False): "odd",
        (False, True): "even",
        (True, True): "odd+even",
    }[(has_odd, has_even)]


def bla(
    figs: ChannelFigures, ubar: np.ndarray, excited: np.ndarray, f0_hz: float
) -> list[dict[str, Any]]:
    """The BLA at each excited line: freq_hz, mag, phase_deg, std_noise, std_nl (None for M = 1).

    `ubar` (M, K) is the drive's mean spectrum, taken as exact (the logged drive).
    """
    u = ubar[:, excited]
    g_m = figs.ybar[:, excited] / u
    m = g_m.shape[0]
    g = g_m.mean(axis=0)
    var_n = np.sum(figs.sigma2[:, excited] / np.abs(u) ** 2, axis=0) / m**2
    if m > 1:
        var_tot = np.sum(np.abs(g_m - g) ** 2, axis=0) / (m * (m - 1))
        std_nl: list[float | None] = [float(v) for v in np.sqrt(np.maximum(var_tot - var_n, 0.0))]
    else:
        std_nl = [None] * excited.size
    phase = np.degrees(np.angle(g))
    phase = np.where(phase <= -180.0, phase + 360.0, phase)
    return [
        {
            "freq_hz": float(k * f0_hz),
            "mag": float(abs(gk)),
            "phase_deg": float(ph),
            "std_noise": float(np.sqrt(vn)),
            "std_nl": nl,
        }
        for k, gk, ph, vn, nl in zip(excited, g, phase, var_n, std_nl, strict=True)
    ]


def model_figures(
    measured: ChannelFigures,
    model_ybar: np.ndarray,
    sets: LineSets,
    noise_db: float,
    margin_db: float,
) -> dict[str, Any]:
    """The model's levels (noise None), its class against the measured noise, and the distortion
    the model does not predict: <|Ybar - Yhat|^2> over O and over V.
    """
    p = np.abs(model_ybar) ** 2
    odd = _mean_over(p, sets.odd)
    even = _mean_over(p, sets.even)
    levels: dict[str, float | None] = {
        "signal": db(float(np.mean(p[:, sets.excited]))),
        "noise": None,
        "odd": None if odd is None else db(odd),
        "even": None if even is None else db(even),
    }
    resid = np.abs(measured.ybar - model_ybar) ** 2
    u_odd = _mean_over(resid, sets.odd)
    u_even = _mean_over(resid, sets.even)
    return {
        "levels_db": levels,
        "class": classify(levels, noise_db, margin_db),
        "unexplained_db": {
            "odd": None if u_odd is None else db(u_odd),
            "even": None if u_even is None else db(u_even),
        },
    }


def disagreements(
    unexplained: dict[str, float | None], noise_db: float, margin_db: float
) -> list[str]:
    """Those of odd, even (in that order) whose unexplained level is >= noise + margin."""
    return [
        name
        for name in ("odd", "even")
        if (level := unexplained.get(name)) is not None and level >= noise_db + margin_db
    ]


def level_trend(
    figs: ChannelFigures, sets: LineSets, drive_rms_v: np.ndarray
) -> list[dict[str, float]] | None:
    """Signal and odd level per drive level (runs grouped by their drive RMS, to 1 dB), from the
    lowest level up; None when every run is at one level or there is no odd detection line.
    """
    if sets.odd.size == 0:
        return None
    level_db = 20.0 * np.log10(np.asarray(drive_rms_v, dtype=np.float64))
    order = np.argsort(level_db)
    groups: list[list[int]] = []
    for m in order.tolist():
        if groups and level_db[m] - level_db[groups[-1][0]] < LEVEL_STEP_DB:
            groups[-1].append(m)
        else:
            groups.append([m])
    if len(groups) < 2:
        return None
    p = np.abs(figs.ybar) ** 2
    return [
        {
            "rms_v": float(np.mean(np.asarray(drive_rms_v)[g])),
            "signal_db": db(float(np.mean(p[np.ix_(np.array(g), sets.excited)]))),
            "odd_db": db(float(np.mean(p[np.ix_(np.array(g), sets.odd)]))),
        }
        for g in groups
    ]
