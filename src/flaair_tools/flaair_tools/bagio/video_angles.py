"""Wing stroke and pitch from tracked video points (DLTdv8), as a lab's rig file describes them.

Pure numpy, one row per video frame, NaN where a point was not tracked. The conventions are
those of the lab-file contract (docs/LAB_FILES.md):

- span ``s``: the unit part of (LE2 - LE1) perpendicular to ``up``;
- stroke from the wing: the signed angle from ``rest_span`` (its part perpendicular to ``up``)
  to ``s``, positive about +``up`` (right-hand rule);
- stroke from the actuator tip: ``transmission_ratio_rad_per_m * m_per_px * (tip - rest) .
  tip_axis_px``, rest being the tip's mean position over the tracked frames;
- pitch: the signed angle, about +``s``, from the rest chord (``-up`` perpendicular to ``s``:
  the wing hangs chord-down) to the chord (TE1 - LE1 perpendicular to ``s``).

Angles are in radians here; the importer writes degrees, as the measured-run CSV does.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "VideoGeometryError",
    "pitch_rad",
    "signed_angle_rad",
    "span_directions",
    "stroke_from_span_rad",
    "stroke_from_tip_rad",
]

# Below this length (relative to the run's median) two points count as one: no span or chord.
DEGENERATE_FRACTION = 1e-6


class VideoGeometryError(ValueError):
    """Points or rig geometry that define no angle (coinciding points, a zero axis); names which."""


def _unit_axis(vector: np.ndarray, name: str, size: int) -> np.ndarray:
    v = np.asarray(vector, dtype=float).reshape(-1)
    if v.size != size or not np.isfinite(v).all() or not np.linalg.norm(v) > 0:
        raise VideoGeometryError(
            f"geometry.{name} must be {size} finite numbers, not all zero; got {list(v)}"
        )
    return v / np.linalg.norm(v)


def _perpendicular(v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Rows of `v` without their component along the unit rows (or single vector) `axis`."""
    return v - np.sum(v * axis, axis=-1, keepdims=True) * axis


def _normalise(v: np.ndarray, what: str) -> np.ndarray:
    """Unit rows; a row of (near) zero length among tracked frames is refused, naming its frame
    as DLTdv numbers it (row k is frame k + 1).
    """
    length = np.linalg.norm(v, axis=-1)
    tracked = np.isfinite(length)
    if tracked.any():
        scale = float(np.median(length[tracked]))
        short = tracked & (length <= DEGENERATE_FRACTION * max(scale, np.finfo(float).tiny))
        if short.any():
            raise VideoGeometryError(
                f"{what}: the points coincide in frame "
                f"{int(np.flatnonzero(short)[0]) + 1} ({int(short.sum())} "
                "frame(s)): no direction"
            )
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / length[:, None]


def signed_angle_rad(a: np.ndarray, b: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Signed angle from rows `a` to rows `b`, both
    perpendicular to `axis`, positive about +`axis`.
    """
    return np.arctan2(np.sum(np.cross(a, b) * axis, axis=-1), np.sum(a * b, axis=-1))


def span_directions(le1: np.ndarray, le2: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(n, 3) unit spans: LE2 - LE1 perpendicular to `up`, NaN where a point is untracked."""
    u = _unit_axis(up, "up", 3)
    return _normalise(
        _perpendicular(np.asarray(le2, float) - np.asarray(le1, float), u), "span (LE1, LE2)"
    )


def stroke_from_span_rad(
    le1: np.ndarray, le2: np.ndarray, up: np.ndarray, rest_span: np.ndarray
) -> np.ndarray:
    """Stroke per frame from the span's direction about `up`, zero along `rest_span`."""
    u = _unit_axis(up, "up", 3)
    rest = _perpendicular(_unit_axis(rest_span, "rest_span", 3), u)
    if not np.linalg.norm(rest) > 1e-9:
        raise VideoGeometryError(
            "geometry.rest_span is parallel to geometry.up: no zero-stroke direction"
        )
    rest = rest / np.linalg.norm(rest)
    span = span_directions(le1, le2, u)
    return signed_angle_rad(np.broadcast_to(rest, span.shape), span, u)


def stroke_from_tip_rad(
    tip_px: np.ndarray,
    tip_axis_px: np.ndarray,
    m_per_px: float,
    transmission_ratio_rad_per_m: float,
) -> np.ndarray:
    """Stroke per frame from the actuator tip's image
    position (n, 2), about its mean over tracked frames.
    """
    if not (np.isfinite(m_per_px) and m_per_px > 0):
        raise VideoGeometryError(f"geometry.m_per_px must be finite and > 0, got {m_per_px}")
    if not (np.isfinite(transmission_ratio_rad_per_m) and transmission_ratio_rad_per_m != 0):
        raise VideoGeometryError(
            "geometry.transmission_ratio_rad_per_m must be finite and "
            f"non-zero, got {transmission_ratio_rad_per_m}"
        )
    axis = _unit_axis(tip_axis_px, "tip_axis_px", 2)
    tip = np.asarray(tip_px, dtype=float)
    tracked = np.isfinite(tip).all(axis=1)
    if not tracked.any():
        raise VideoGeometryError("points.actuator_tip is never tracked")
    rest = tip[tracked].mean(axis=0)
    deflection_m = m_per_px * ((tip - rest) @ axis)
    return transmission_ratio_rad_per_m * deflection_m


def pitch_rad(le1: np.ndarray, te1: np.ndarray, le2: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Pitch per frame: the chord's rotation about the span from hanging straight down (-`up`)."""
    u = _unit_axis(up, "up", 3)
    span = span_directions(le1, le2, u)
    chord = _normalise(
        _perpendicular(np.asarray(te1, float) - np.asarray(le1, float), span), "chord (LE1, TE1)"
    )
    rest_chord = _normalise(
        _perpendicular(np.broadcast_to(-u, span.shape), span), "rest chord (-up)"
    )
    return signed_angle_rad(rest_chord, chord, span)
