"""Odd random-phase multisine design (../shared/multisine.md, section 1), pure.

Lines: the odd lines k with F1 <= k f0 <= F2; the lowest and the highest are excited; the odd
lines between them are taken, from the lowest, in consecutive groups of G and one line of each
complete group, drawn at random, is left out (an odd detection line); no even line is excited.
Realization m is `A sum_k cos(2 pi k n / N + phi_mk)`, A = rms sqrt(2 / |E|), the phases drawn
uniform on [0, 2 pi) from the design's seed (the left-out lines first, then the phases).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from flaair_sim.core.drive import multisine

__all__ = [
    "DesignError",
    "MultisineDesign",
    "design_multisine",
    "period_samples_of",
    "realization_drive",
]


class DesignError(ValueError):
    """A design option out of its range; the message names the option."""


@dataclass(frozen=True)
class MultisineDesign:
    """One odd random-phase multisine design (the fields of multisine.yaml, SI units)."""

    fs_hz: float
    period_samples: int
    band_hz: tuple[float, float]
    lines_per_group: int
    excited_lines: tuple[int, ...]
    odd_detection_lines: tuple[int, ...]
    rms_v: float
    amplitude_v: float
    transient_periods: int
    periods: int
    realizations: int
    seed: int
    phases_rad: tuple[tuple[float, ...], ...]

    @property
    def base_frequency_hz(self) -> float:
        """f0 = fs / N."""
        return self.fs_hz / self.period_samples

    @property
    def n_samples(self) -> int:
        """Samples of one realization's run: (T + P) N."""
        return (self.transient_periods + self.periods) * self.period_samples


def period_samples_of(fs_hz: float, base_hz: float) -> int:
    """N = fs / f0; DesignError unless it is a whole number of samples (>= 4)."""
    if not (math.isfinite(fs_hz) and fs_hz > 0):
        raise DesignError(f"--fs must be a finite rate > 0 Hz, got {fs_hz:g}")
    if not (math.isfinite(base_hz) and base_hz > 0):
        raise DesignError(f"--base-hz must be a finite frequency > 0 Hz, got {base_hz:g}")
    ratio = fs_hz / base_hz
    n = round(ratio)
    if abs(ratio - n) > 1e-9 * ratio or n < 4:
        raise DesignError(
            f"--base-hz {base_hz:g}: fs/f0 = {ratio:.6g} is not a whole number of samples (>= 4)"
        )
    return int(n)


def _lines(
    k_lo: int, k_hi: int, group: int, rng: np.random.Generator
) -> tuple[list[int], list[int]]:
    odd = list(range(k_lo, k_hi + 1, 2))
    inner = odd[1:-1]
    excited, detection = [odd[0]], []
    for start in range(0, len(inner), group):
        chunk = inner[start : start + group]
        if len(chunk) == group:
            out = int(rng.integers(group))
            detection.append(chunk[out])
            excited += [k for i, k in enumerate(chunk) if i != out]
        else:
            excited += chunk
    excited.append(odd[-1])
    return sorted(excited), detection


def design_multisine(
    *,
    band_hz: tuple[float, float],
    base_hz: float,
    lines_per_group: int,
    rms_v: float,
    periods: int,
    transient_periods: int,
    realizations: int,
    fs_hz: float,
    max_v: float,
    seed: int,
) -> MultisineDesign:
    """The design; DesignError names the option at fault (a realization above `max_v` too)."""
    n = period_samples_of(fs_hz, base_hz)
    f1, f2 = (float(b) for b in band_hz)
    if not (math.isfinite(f1) and math.isfinite(f2) and 0 < f1 < f2):
        raise DesignError(f"--band {f1:g}:{f2:g}: needs 0 < F1 < F2")
    if f2 >= fs_hz / 2:
        raise DesignError(f"--band {f1:g}:{f2:g}: F2 must be below fs/2 = {fs_hz / 2:g} Hz")
    if lines_per_group < 2:
        raise DesignError(f"--lines-per-group must be >= 2, got {lines_per_group}")
    if periods < 2:
        raise DesignError(f"--periods must be >= 2, got {periods}")
    if transient_periods < 0:
        raise DesignError(f"--transient-periods must be >= 0, got {transient_periods}")
    if realizations < 1:
        raise DesignError(f"--realizations must be >= 1, got {realizations}")
    if not (math.isfinite(rms_v) and rms_v > 0):
        raise DesignError(f"--rms-v must be a finite voltage > 0, got {rms_v:g}")
    if not (0 <= seed < 2**63):
        raise DesignError(f"--seed must be in [0, 2**63), got {seed}")
    k_lo = math.ceil(f1 / base_hz - 1e-9)
    k_hi = math.floor(f2 / base_hz + 1e-9)
    k_lo += 1 - k_lo % 2  # the first odd line at or above F1
    k_hi -= 1 - k_hi % 2
    if k_hi <= k_lo:
        raise DesignError(f"--band {f1:g}:{f2:g}: fewer than 2 odd lines of {base_hz:g} Hz in it")
    rng = np.random.default_rng(seed)
    excited, detection = _lines(k_lo, k_hi, lines_per_group, rng)
    phases = rng.uniform(0.0, 2.0 * np.pi, size=(realizations, len(excited)))
    amplitude = rms_v * math.sqrt(2.0 / len(excited))
    design = MultisineDesign(
        fs_hz=float(fs_hz),
        period_samples=n,
        band_hz=(f1, f2),
        lines_per_group=int(lines_per_group),
        excited_lines=tuple(excited),
        odd_detection_lines=tuple(detection),
        rms_v=float(rms_v),
        amplitude_v=amplitude,
        transient_periods=int(transient_periods),
        periods=int(periods),
        realizations=int(realizations),
        seed=int(seed),
        phases_rad=tuple(tuple(float(p) for p in row) for row in phases),
    )
    for m in range(realizations):
        peak = float(np.max(np.abs(realization_drive(design, m, design.period_samples))))
        if peak > max_v:
            raise DesignError(
                f"realization {m + 1} peaks at {peak:.4g} V, above --max-v {max_v:g} V "
                "(lower --rms-v, or another --seed)"
            )
    return design


def realization_drive(design: MultisineDesign, m: int, n_samples: int | None = None) -> np.ndarray:
    """drive_v of realization `m` (0-based), samples 0 .. n_samples - 1 (default (T + P) N)."""
    count = design.n_samples if n_samples is None else int(n_samples)
    return multisine(
        np.arange(count, dtype=np.int64),
        design.period_samples,
        design.excited_lines,
        design.phases_rad[m],
        design.amplitude_v,
    )
