"""track_outliers: a tracking glitch is dropped and counted, never propagated.

One wild cell in a DLTdv8 track (1e308, a digitizing slip) would otherwise move a point's mean
and so every angle computed from it. A frame whose coordinate lies more than
`OUTLIER_IQR_FACTOR` interquartile ranges outside its column's quartiles (over the tracked
frames) is made untracked (NaN) and counted. Pure numpy.
"""

from __future__ import annotations

import numpy as np

__all__ = ["OUTLIER_IQR_FACTOR", "drop_outliers", "drop_track_outliers"]

# a wing or a tip moving over a bounded range never comes near 10 IQR past its quartiles
OUTLIER_IQR_FACTOR = 10.0


def drop_outliers(points: np.ndarray) -> tuple[np.ndarray, int]:
    """`points` (frames, d) with each outlying frame set to NaN, and how many were dropped."""
    out = np.array(points, dtype=float)
    tracked = np.isfinite(out).all(axis=1)
    if tracked.sum() < 4:
        return out, 0
    low, high = np.percentile(out[tracked], [25.0, 75.0], axis=0)
    # a point that never moves has no spread: a relative tolerance keeps its rounding
    floor = 1e-9 * np.maximum(1.0, np.abs(np.median(out[tracked], axis=0)))
    reach = OUTLIER_IQR_FACTOR * (high - low) + floor
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
