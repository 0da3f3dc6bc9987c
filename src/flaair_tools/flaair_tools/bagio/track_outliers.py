"""track_outliers: a tracking glitch is dropped and counted, never propagated.

One wild cell in a DLTdv8 track (1e308, a digitizing slip) would otherwise move a point's mean
and so every angle computed from it. A frame whose coordinate lies more than `OUTLIER_FACTOR`
times its column's range of motion (between the `OUTLIER_PERCENTILE` and 100 minus it, over the
tracked frames) outside that range is made untracked (NaN) and counted. The range is nearly the
whole motion, not the quartiles: a chirp through resonance moves the wing many times further in
its few resonant frames than in the rest, and those frames are real. Pure numpy.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "OUTLIER_FACTOR",
    "OUTLIER_FLOOR",
    "OUTLIER_PERCENTILE",
    "drop_outliers",
    "drop_track_outliers",
]

# a wing or a tip moving over a bounded range never comes near 10 ranges past its own motion
OUTLIER_FACTOR = 10.0
OUTLIER_PERCENTILE = 0.5
# the least reach past the quartiles, relative to the point's position (or 1 in its unit)
OUTLIER_FLOOR = 1e-3


def drop_outliers(points: np.ndarray) -> tuple[np.ndarray, int]:
    """`points` (frames, d) with each outlying frame set to NaN, and how many were dropped."""
    out = np.array(points, dtype=float)
    tracked = np.isfinite(out).all(axis=1)
    if tracked.sum() < 4:
        return out, 0
    low, high = np.percentile(
        out[tracked], [OUTLIER_PERCENTILE, 100.0 - OUTLIER_PERCENTILE], axis=0
    )
    # a point that barely moves has next to no spread: a tolerance of 0.1 % of its position
    # keeps its tracking jitter and the rounding of the file's number format (a static hinge
    # written with 6 significant digits has steps of 1e-6 of its value)
    floor = OUTLIER_FLOOR * np.maximum(1.0, np.abs(np.median(out[tracked], axis=0)))
    reach = OUTLIER_FACTOR * (high - low) + floor
    with np.errstate(invalid="ignore"):
        outlying = tracked & ((out < low - reach) | (out > high + reach)).any(axis=1)
    out[outlying] = np.nan
    return out, int(outlying.sum())


def drop_track_outliers(
    wing: dict[str, np.ndarray], tip: np.ndarray | None
) -> tuple[dict[str, np.ndarray], np.ndarray | None, int]:
    """`drop_outliers` on every wing point and on the tip track; the frames dropped in all."""
    cleaned, dropped = {}, 0
    for name, xyz in wing.items():
        cleaned[name], n = drop_outliers(xyz)
        dropped += n
    if tip is not None:
        tip, n = drop_outliers(tip)
        dropped += n
    return cleaned, tip, dropped
