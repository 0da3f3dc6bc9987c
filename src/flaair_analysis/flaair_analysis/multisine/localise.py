"""Where a distortion comes from, read from which channels show it
(../shared/multisine.md, section 3, "Reading the pattern"), pure.

This robot's model: the pitch follows the stroke, the stroke never the pitch. With a model the
pattern read is `disagrees` (the distortion the model does not predict); without one, `class`.
- even on the pitch film alone: the film; on pitch film and pitch video, not the stroke: the
  hinge; on stroke and pitch: the stroke or the drive; on the stroke film alone: that film;
- odd (with the model: odd the model does not predict): an odd nonlinearity (stiffening,
  saturation), on the stroke channels the stroke or the drive, on the pitch alone the hinge;
  with the nominal model a plant mismatch shows as odd too (identify the plant first). When the
  runs come at two or more drive levels and the odd level grows faster than the signal with the
  level (odd - signal rising >= 1 dB per dB of drive), the finding says so: stiffening or
  saturation, not a linear mismatch.
An even nonlinearity inside the dynamics also changes the odd lines, so odd with even does not
prove two effects.
Each finding also names the term sites (`flaair_model.terms.SITES`) it points to: where the
discrepancy workflow would look first.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

__all__ = ["GROWTH_DB_PER_DB", "growth_db_per_db", "localise"]

# where each reading points, as the term library's sites
_EVEN_SITES = {
    "film": ("pitch_sensor_v",),
    "actuator film": ("stroke_sensor_v",),
    "hinge": ("pitch_dynamics",),
    "stroke": ("stroke_dynamics", "drive"),
    "tracking": (),
}

GROWTH_DB_PER_DB = 1.0  # odd - signal rising this fast with the drive level: growing with level
STROKE = ("stroke_sensor_v", "stroke_deg")
PITCH = ("pitch_sensor_v", "pitch_deg")


def _showing(channels: Mapping[str, Any], kind: str, by_model: bool) -> list[str]:
    out = []
    for name, entry in channels.items():
        shows = kind in entry["disagrees"] if by_model else kind in entry["class"].split("+")
        if shows:
            out.append(name)
    return out


def _even_source(showing: list[str], skipped: Mapping[str, str]) -> tuple[str, tuple[str, ...]]:
    s = set(showing)
    on_stroke, on_pitch = bool(s & set(STROKE)), bool(s & set(PITCH))
    if on_stroke and on_pitch:
        return "the stroke or the drive (the pitch follows the stroke)", _EVEN_SITES["stroke"]
    if s == {"pitch_sensor_v"}:
        if "pitch_deg" in skipped:
            return (
                "the hinge film, or the hinge (the pitch video was not analysed)",
                _EVEN_SITES["film"] + _EVEN_SITES["hinge"],
            )
        return "the hinge film (the pitch video does not show it)", _EVEN_SITES["film"]
    if on_pitch and "pitch_sensor_v" in s:
        return "the hinge", _EVEN_SITES["hinge"]
    if s == {"stroke_sensor_v"}:
        if "stroke_deg" in skipped:
            return (
                "the actuator film, or the stroke (the stroke video was not analysed)",
                _EVEN_SITES["actuator film"] + _EVEN_SITES["stroke"],
            )
        return "the actuator film (the stroke video does not show it)", _EVEN_SITES["actuator film"]
    if on_stroke:
        return "the stroke or the drive", _EVEN_SITES["stroke"]
    return "the pitch video tracking (the pitch film does not show it)", _EVEN_SITES["tracking"]


def _odd_source(showing: list[str]) -> tuple[str, tuple[str, ...]]:
    s = set(showing)
    if s & set(STROKE):
        return (
            "an odd nonlinearity of the stroke or the drive (stiffening, saturation)",
            ("stroke_dynamics", "drive"),
        )
    return "an odd nonlinearity of the hinge (stiffening)", ("pitch_dynamics",)


def growth_db_per_db(trend: list[dict[str, float]]) -> float:
    """How fast odd - signal rises with the drive level, lowest to highest level (dB per dB)."""
    low, high = trend[0], trend[-1]
    span = 20.0 * math.log10(high["rms_v"] / low["rms_v"])
    rise = (high["odd_db"] - high["signal_db"]) - (low["odd_db"] - low["signal_db"])
    return rise / span


def localise(
    channels: Mapping[str, Any],
    skipped: Mapping[str, str],
    by_model: bool,
    trends: Mapping[str, list[dict[str, float]]] | None = None,
) -> dict[str, Any]:
    """The findings: for odd and even, the channels that show it and where it points (and, with
    `trends` of two or more drive levels, whether the odd distortion grows with the level).
    """
    trends = trends or {}
    findings = []
    for kind in ("even", "odd"):
        showing = _showing(channels, kind, by_model)
        if not showing:
            continue
        if kind == "even":
            points, sites = _even_source(showing, skipped)
        else:
            points, sites = _odd_source(showing)
            if _showing(channels, "even", by_model):
                points += "; or the even nonlinearity's products inside the dynamics"
            elif by_model:
                points += "; or a plant mismatch (compare against an identified model)"
        finding: dict[str, Any] = {
            "distortion": kind,
            "channels": showing,
            "points_to": points,
            "sites": list(sites),
        }
        growing = [
            c for c in showing if c in trends and growth_db_per_db(trends[c]) >= GROWTH_DB_PER_DB
        ]
        if kind == "odd" and growing:
            finding["grows_with_level"] = growing
            finding["points_to"] = (
                "stiffening or saturation: the odd distortion grows faster than the signal with "
                f"the drive level on {', '.join(growing)}; " + points
            )
        findings.append(finding)
    doc: dict[str, Any] = {"basis": "disagrees" if by_model else "class", "findings": findings}
    if trends:
        doc["level_trend"] = {c: list(t) for c, t in trends.items()}
    return doc
