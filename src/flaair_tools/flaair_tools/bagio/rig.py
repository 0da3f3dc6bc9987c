"""A lab's rig file (YAML, written once per bench): how to read its MAT logs and video tracks.

The contract is docs/LAB_FILES.md (section "The rig file"). Every key is checked: a missing,
unknown or ill-typed key is refused with the file and the key's path, so a typo cannot silently
fall back to anything. `drive_gain_v_per_v` (1), `drive_bias_v` (0) and `log_variable` are the only
keys that may be left out; the trigger, actuator-tip and transmission keys are required where
used. Points are DLTdv's numbers (from 1) or the names DLTdv8a 8.4 writes; `trigger_frame` is
DLTdv's frame number (the first row is frame 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from flaair_model.checked_files import CheckedFileError, load_yaml_text, read_text
from flaair_tools.bagio.target_log import LabFileError, split_label

__all__ = ["ROLES", "WING_POINTS", "Rig", "TipPoint", "read_rig", "rig_from_mapping"]

ROLES = ("drive", "stroke_sensor", "pitch_sensor", "camera_trigger")
WING_POINTS = ("wing_leading_edge_1", "wing_trailing_edge_1", "wing_leading_edge_2")
STROKE_SOURCES = ("actuator_tip", "wing_span")
_TOP = {
    "log_variable",
    "signals",
    "drive_gain_v_per_v",
    "drive_bias_v",
    "video",
    "points",
    "geometry",
    "stroke_from",
}
_VIDEO = {"fps", "sync", "length_unit_m"}
_SYNC = {"trigger_frame", "trigger_threshold_v", "frame0_time_s"}
_POINTS = set(WING_POINTS) | {"actuator_tip"}
_GEOMETRY = {"up", "rest_span", "m_per_px", "tip_axis_px", "transmission_ratio_rad_per_m"}


@dataclass(frozen=True)
class TipPoint:
    """The actuator tip in the 2D track: its DLTdv point (number from 1, or name) and camera."""

    point: int | str
    camera: int


@dataclass(frozen=True)
class Rig:
    """A rig file's content, checked (SI units; angles and positions as the file gives them)."""

    source: str  # the file's text, recorded in every bag imported with it
    signals: dict[str, str]  # role -> MAT signal label, or "label[j]": column j (from 1)
    drive_gain_v_per_v: float
    drive_bias_v: float
    fps: float
    trigger_frame: int | None  # DLTdv's frame number (from 1) at the trigger; None: frame0
    trigger_threshold_v: float | None
    frame0_time_s: float | None
    length_unit_m: float
    wing_points: dict[str, int | str]  # WING_POINTS -> DLTdv point number (from 1) or name
    tip: TipPoint | None
    up: tuple[float, float, float]
    rest_span: tuple[float, float, float]
    m_per_px: float | None
    tip_axis_px: tuple[float, float] | None
    transmission_ratio_rad_per_m: float | None
    stroke_from: str
    log_variable: str | None = None  # the MAT variable holding the log; None: the only one

    @property
    def labels(self) -> list[str]:
        """The MAT signal labels to read, in ROLES order."""
        return [self.signals[role] for role in ROLES if role in self.signals]


class _Checker:
    def __init__(self, path: str) -> None:
        self.path = path

    def fail(self, key: str, what: str) -> LabFileError:
        return LabFileError(f"{self.path}: {key}: {what}")

    def mapping(self, value: Any, key: str, allowed: set[str], required: set[str]) -> dict:
        if not isinstance(value, dict):
            raise self.fail(key, f"must be a mapping, got {type(value).__name__}")
        unknown = sorted(str(k) for k in value if k not in allowed)
        if unknown:
            raise self.fail(
                key, f"unknown key(s) {', '.join(unknown)} (allowed: {', '.join(sorted(allowed))})"
            )
        missing = sorted(required - set(value))
        if missing:
            raise self.fail(key, f"missing key(s) {', '.join(missing)}")
        return value

    def number(self, value: Any, key: str, positive: bool = False) -> float:
        if (
            isinstance(value, bool)
            or not isinstance(value, (int, float))
            or not math.isfinite(value)
        ):
            raise self.fail(key, f"must be a finite number, got {value!r}")
        if positive and not value > 0:
            raise self.fail(key, f"must be > 0, got {value!r}")
        return float(value)

    def point(self, value: Any, key: str) -> int | str:
        if isinstance(value, str) and value.strip():
            return value.strip()
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise self.fail(
                key, f"must be a DLTdv point number (from 1) or a point's name, got {value!r}"
            )
        return int(value)

    def integer(self, value: Any, key: str, minimum: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise self.fail(key, f"must be an integer >= {minimum}, got {value!r}")
        return int(value)

    def vector(self, value: Any, key: str, size: int) -> tuple[float, ...]:
        if not isinstance(value, (list, tuple)) or len(value) != size:
            raise self.fail(key, f"must be a list of {size} numbers, got {value!r}")
        numbers = tuple(self.number(v, key) for v in value)
        if not any(numbers):
            raise self.fail(key, "must not be all zero")
        return numbers


def _checked_sync(c: _Checker, video: dict[str, Any]) -> tuple[dict[str, Any], bool]:
    """The video's sync section and whether it is by trigger (else by frame 0's time)."""
    sync = c.mapping(video["sync"], "video.sync", _SYNC, set())
    by_trigger = "trigger_frame" in sync or "trigger_threshold_v" in sync
    if by_trigger == ("frame0_time_s" in sync):
        raise c.fail(
            "video.sync",
            "give either trigger_frame and trigger_threshold_v (trigger "
            "sync) or frame0_time_s, not both and not neither",
        )
    if by_trigger:
        c.mapping(sync, "video.sync", _SYNC, {"trigger_frame", "trigger_threshold_v"})
        if sync["trigger_frame"] == 0 and not isinstance(sync["trigger_frame"], bool):
            raise c.fail(
                "video.sync.trigger_frame",
                "0: DLTdv numbers frames from 1 (the first row is frame 1); give the number "
                "DLTdv's frame slider shows for the frame taken at the trigger's edge",
            )
    return sync, by_trigger


def _checked_signals(c: _Checker, top: dict[str, Any], by_trigger: bool) -> dict[str, Any]:
    """The signal labels of each role (the camera trigger's too with a trigger sync)."""
    signals = c.mapping(
        top["signals"],
        "signals",
        set(ROLES),
        {"drive", "stroke_sensor", "pitch_sensor"} | ({"camera_trigger"} if by_trigger else set()),
    )
    for role, label in signals.items():
        if not isinstance(label, str) or not label:
            raise c.fail(f"signals.{role}", f"must be a signal label (text), got {label!r}")
        if label.endswith("]") and split_label(label)[1] is None:
            raise c.fail(
                f"signals.{role}",
                f"{label!r}: a column is named as 'label[j]', j a whole number from 1",
            )
    return signals


def _checked_points(
    c: _Checker, top: dict[str, Any], tip_used: bool
) -> tuple[dict[str, Any], TipPoint | None]:
    """The wing's tracked points (each a different one) and the actuator tip's, if tracked."""
    points = c.mapping(
        top["points"],
        "points",
        _POINTS,
        set(WING_POINTS) | ({"actuator_tip"} if tip_used else set()),
    )
    wing_points = {name: c.point(points[name], f"points.{name}") for name in WING_POINTS}
    if len(set(wing_points.values())) != len(wing_points):
        raise c.fail("points", f"the wing points must be different points, got {wing_points}")
    tip = None
    if "actuator_tip" in points:
        tip_map = c.mapping(
            points["actuator_tip"], "points.actuator_tip", {"point", "camera"}, {"point", "camera"}
        )
        tip = TipPoint(
            c.point(tip_map["point"], "points.actuator_tip.point"),
            c.integer(tip_map["camera"], "points.actuator_tip.camera", 1),
        )
    return wing_points, tip


def rig_from_mapping(data: Any, path: str, source: str = "") -> Rig:
    """A checked `Rig` from the parsed YAML `data` of the file `path` (named in every error)."""
    c = _Checker(path)
    top = c.mapping(data, "rig", _TOP, {"signals", "video", "points", "geometry", "stroke_from"})
    stroke_from = top["stroke_from"]
    if stroke_from not in STROKE_SOURCES:
        raise c.fail(
            "stroke_from", f"must be one of {', '.join(STROKE_SOURCES)}, got {stroke_from!r}"
        )
    video = c.mapping(top["video"], "video", _VIDEO, _VIDEO)
    sync, by_trigger = _checked_sync(c, video)
    signals = _checked_signals(c, top, by_trigger)
    log_variable = top.get("log_variable")
    if log_variable is not None and (not isinstance(log_variable, str) or not log_variable):
        raise c.fail("log_variable", f"must be a MAT variable's name, got {log_variable!r}")
    tip_used = stroke_from == "actuator_tip"
    wing_points, tip = _checked_points(c, top, tip_used)
    geometry = c.mapping(
        top["geometry"],
        "geometry",
        _GEOMETRY,
        {"up", "rest_span"}
        | ({"m_per_px", "tip_axis_px", "transmission_ratio_rad_per_m"} if tip_used else set()),
    )
    fps = c.number(video["fps"], "video.fps", positive=True)
    return Rig(
        source=source,
        signals=dict(signals),
        drive_gain_v_per_v=c.number(top.get("drive_gain_v_per_v", 1.0), "drive_gain_v_per_v"),
        drive_bias_v=c.number(top.get("drive_bias_v", 0.0), "drive_bias_v"),
        fps=fps,
        trigger_frame=(
            c.integer(sync["trigger_frame"], "video.sync.trigger_frame", 1) if by_trigger else None
        ),
        trigger_threshold_v=(
            c.number(sync["trigger_threshold_v"], "video.sync.trigger_threshold_v")
            if by_trigger
            else None
        ),
        frame0_time_s=(
            None if by_trigger else c.number(sync["frame0_time_s"], "video.sync.frame0_time_s")
        ),
        length_unit_m=c.number(video["length_unit_m"], "video.length_unit_m", positive=True),
        wing_points=wing_points,
        tip=tip,
        up=c.vector(geometry["up"], "geometry.up", 3),
        rest_span=c.vector(geometry["rest_span"], "geometry.rest_span", 3),
        m_per_px=(
            c.number(geometry["m_per_px"], "geometry.m_per_px", positive=True)
            if "m_per_px" in geometry
            else None
        ),
        tip_axis_px=(
            c.vector(geometry["tip_axis_px"], "geometry.tip_axis_px", 2)
            if "tip_axis_px" in geometry
            else None
        ),
        transmission_ratio_rad_per_m=(
            c.number(
                geometry["transmission_ratio_rad_per_m"], "geometry.transmission_ratio_rad_per_m"
            )
            if "transmission_ratio_rad_per_m" in geometry
            else None
        ),
        stroke_from=stroke_from,
        log_variable=log_variable,
    )


def read_rig(path: Path | str) -> Rig:
    """The rig file at `path`, checked; a LabFileError names the file and the key."""
    path = Path(path)
    try:  # regular, bounded, aliases bounded, a key written twice refused
        text = read_text(path, "rig")
        data = load_yaml_text(text, str(path))
    except CheckedFileError as exc:
        raise LabFileError(str(exc)) from None
    return rig_from_mapping(data, str(path), text)
