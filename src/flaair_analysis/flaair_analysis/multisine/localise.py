"""Where a distortion comes from, read from which channels show it
(../shared/multisine.md, section 3, "Reading the pattern"), pure.

This robot's model: the pitch follows the stroke, the stroke never the pitch. With a model the
pattern read is `disagrees` (the distortion the model does not predict); without one, `class`.
- even on the pitch film alone: the film; on pitch film and pitch video, not the stroke: the
  hinge; on stroke and pitch: the stroke or the drive; on the stroke film alone: that film;
- odd (with the model: odd the model does not predict): an odd nonlinearity (stiffening,
  saturation), on the stroke channels the stroke or the drive, on the pitch alone the hinge;
  with the nominal model a plant mismatch shows as odd too (identify the plant first).
An even nonlinearity inside the dynamics also changes the odd lines, so odd with even does not
prove two effects.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

__all__ = ["localise"]

STROKE = ("stroke_sensor_v", "stroke_deg")
PITCH = ("pitch_sensor_v", "pitch_deg")


def _showing(channels: Mapping[str, Any], kind: str, by_model: bool) -> list[str]:
    out = []
    for name, entry in channels.items():
        shows = kind in entry["disagrees"] if by_model else kind in entry["class"].split("+")
        if shows:
            out.append(name)
    return out


def _even_source(showing: list[str], skipped: Mapping[str, str]) -> str:
    s = set(showing)
    on_stroke, on_pitch = bool(s & set(STROKE)), bool(s & set(PITCH))
    if on_stroke and on_pitch:
        return "the stroke or the drive (the pitch follows the stroke)"
    if s == {"pitch_sensor_v"}:
        if "pitch_deg" in skipped:
            return "the hinge film, or the hinge (the pitch video was not analysed)"
        return "the hinge film (the pitch video does not show it)"
    if on_pitch and "pitch_sensor_v" in s:
        return "the hinge"
    if s == {"stroke_sensor_v"}:
        if "stroke_deg" in skipped:
            return "the actuator film, or the stroke (the stroke video was not analysed)"
        return "the actuator film (the stroke video does not show it)"
    if on_stroke:
        return "the stroke or the drive"
    return "the pitch video tracking (the pitch film does not show it)"


def _odd_source(showing: list[str]) -> str:
    s = set(showing)
    if s & set(STROKE):
        return "an odd nonlinearity of the stroke or the drive (stiffening, saturation)"
    return "an odd nonlinearity of the hinge (stiffening)"


def localise(
    channels: Mapping[str, Any], skipped: Mapping[str, str], by_model: bool
) -> dict[str, Any]:
    """The findings: for odd and even, the channels that show it and where it points."""
    findings = []
    for kind in ("even", "odd"):
        showing = _showing(channels, kind, by_model)
        if not showing:
            continue
        if kind == "even":
            points = _even_source(showing, skipped)
        else:
            points = _odd_source(showing)
            if _showing(channels, "even", by_model):
                points += "; or the even nonlinearity's products inside the dynamics"
            elif by_model:
                points += "; or a plant mismatch (compare against an identified model)"
        findings.append({"distortion": kind, "channels": showing, "points_to": points})
    return {"basis": "disagrees" if by_model else "class", "findings": findings}
