"""Test systems for the multisine tests and benchmark, and the classic closed forms of their
distortion levels, computed here from the design alone (not by the code under test).

For u(t) = sum_{k in E} A cos(k w0 t + phi_k) with independent uniform phases, the expected power
(|Y|^2 with |Y| = a / sqrt(2) for a sine of amplitude a) at a line k left empty is, for c u^3,
2 c^2 (A/2)^6 sum over the multisets {k1, k2, k3} of +-E with k1 + k2 + k3 = k of (their
orderings)^2, and for c u^2 the same over pairs with (A/2)^4.
"""

from __future__ import annotations

import numpy as np

from flaair_analysis.multisine.design import MultisineDesign, design_multisine, realization_drive


def static_design(seed: int = 7, realizations: int = 4, periods: int = 2) -> MultisineDesign:
    """A design for static test systems: f0 = 1 Hz, N = 4096, 201 odd lines 1-401 Hz."""
    return design_multisine(
        band_hz=(1.0, 401.0),
        base_hz=1.0,
        lines_per_group=3,
        rms_v=1.0,
        periods=periods,
        transient_periods=1,
        realizations=realizations,
        fs_hz=4096.0,
        max_v=10.0,
        seed=seed,
    )


def drives(design: MultisineDesign) -> np.ndarray:
    """Every realization's drive, (M, (T + P) N)."""
    return np.stack([realization_drive(design, m) for m in range(design.realizations)])


def _signed(excited: tuple[int, ...]) -> np.ndarray:
    e = np.array(excited)
    return np.concatenate([-e[::-1], e])


def cubic_power(design: MultisineDesign, coefficient: float, lines: np.ndarray) -> np.ndarray:
    """Expected |Y(k)|^2 of coefficient * u^3 at each of `lines` (lines no triple of excited
    lines with a pair {q, -q} reaches, i.e. not excited).
    """
    s = _signed(design.excited_lines)
    a = design.amplitude_v / 2.0
    k1, k2 = np.meshgrid(s, s, indexing="ij")
    upper = k2 >= k1
    k1, k2 = k1[upper], k2[upper]
    out = []
    for k in lines:
        k3 = k - k1 - k2
        ok = (k3 >= k2) & np.isin(k3, s)
        a1, a2, a3 = k1[ok], k2[ok], k3[ok]
        distinct = 1 + (a1 != a2).astype(int) + ((a3 != a2) & (a3 != a1)).astype(int)
        orderings = np.choose(distinct - 1, [1.0, 3.0, 6.0])
        out.append(2.0 * coefficient**2 * a**6 * float(np.sum(orderings**2)))
    return np.array(out)


def square_power(design: MultisineDesign, coefficient: float, lines: np.ndarray) -> np.ndarray:
    """Expected |Y(k)|^2 of coefficient * u^2 at each of `lines` (k >= 1)."""
    s = _signed(design.excited_lines)
    a = design.amplitude_v / 2.0
    members = set(s.tolist())
    out = []
    for k in lines:
        total = 0.0
        for k1 in s:
            k2 = k - k1
            if k2 < k1 or k2 not in members:
                continue
            total += 4.0 if k1 != k2 else 1.0
        out.append(2.0 * coefficient**2 * a**4 * total)
    return np.array(out)


def noise_line_power(sigma: float, period_samples: int, periods: int) -> float:
    """The variance of the mean over P periods of a line of white noise of std sigma."""
    return 2.0 * sigma**2 / (period_samples * periods)


def db(x: float) -> float:
    """10 log10(x)."""
    return float(10.0 * np.log10(x))
