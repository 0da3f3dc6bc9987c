"""A lab's own files into a run: the target's MAT log, the DLTdv8 tracks and the rig file.

`read_lab_run` reads and checks everything a run needs before anything is written, and returns
the run in the measured-run columns (the same run a CSV export gives: drive and sensors on the
DAQ clock, video angles at the frames' samples, NaN between them) with what the bag records
about it: the source files, the rig file's text, the sync used and its check. A session of
many runs is a manifest (`read_manifest`):

    rig: bench_rig.yaml            # every run's rig (a run may name its own)
    runs:
      - mat: run01.mat
        tracks: run01_xyzpts.csv
        tip_track: run01_xypts.csv # with stroke_from: actuator_tip
      - {mat: run02.mat, tracks: run02_xyzpts.csv, tip_track: run02_xypts.csv}

Paths are relative to the manifest's folder. Every refusal is a LabFileError naming the file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from flaair_common.runcsv import MeasuredRun
from flaair_model.checked_files import CheckedFileError, read_yaml
from flaair_model.model_io import load_model
from flaair_tools.bagio import lab_run
from flaair_tools.bagio.dlt_tracks import read_xy_point, read_xyz_points
from flaair_tools.bagio.rig import Rig, read_rig
from flaair_tools.bagio.target_log import LabFileError, read_target_log
from flaair_tools.bagio.track_outliers import drop_track_outliers
from flaair_tools.bagio.video_angles import VideoGeometryError

__all__ = [
    "LabRun",
    "LabRunFiles",
    "check_max_lag",
    "read_lab_run",
    "read_manifest",
    "sensor_stroke_deg",
]


@dataclass(frozen=True)
class LabRunFiles:
    """One run's files as a lab has them."""

    mat: Path
    rig: Path
    tracks: Path
    tip_track: Path | None = None


@dataclass(frozen=True)
class LabRun:
    """A run read from lab files: its columns, what its marker records, and what to warn."""

    run: MeasuredRun
    extras: dict[str, Any]
    warnings: list[str]


def sensor_stroke_deg(
    stroke_sensor_v: np.ndarray, pitch_sensor_v: np.ndarray, fs_hz: float
) -> np.ndarray:
    """The stroke the front end estimates from the sensor voltages on the nominal model."""
    # deferred: the front end loads its numba kernels (0.4 s); a CSV import never needs it
    from flaair_sensors import frontend_io
    from flaair_sensors.core import frontend, frontend_params

    params = frontend_params.params_from_model(
        load_model(), fs_hz, **frontend_io.frontend_tuning_from_config()
    )
    return np.degrees(frontend.estimate(stroke_sensor_v, pitch_sensor_v, params).stroke_rad)


def _sync_check(
    mat: Path, columns: dict[str, np.ndarray], fs_hz: float, fps: float, max_lag_s: float
) -> tuple[lab_run.SyncCheck | None, list[str]]:
    """The sync check, or why the log's rate cannot make it (one warning, never a refusal)."""
    # deferred: the front end loads its numba kernels (0.4 s); a CSV import never needs it
    from flaair_sensors.core.frontend_params import FrontendError

    problem = lab_run.sync_check_rate_problem(fs_hz, max_lag_s)
    if problem is None:
        try:
            estimate = sensor_stroke_deg(
                columns["stroke_sensor_v"], columns["pitch_sensor_v"], fs_hz
            )
        except FrontendError as exc:
            problem = f"the front end does not run at {fs_hz:g} Hz ({exc})"
        else:
            check = lab_run.sync_check(columns["stroke_deg"], estimate, fs_hz, fps, max_lag_s)
            return check, []
    return None, [
        f"{mat}: the sync check cannot be made at the log's rate: {problem}; the video's "
        "sync is not checked"
    ]


def _untracked(
    tracks: Path, rig: Rig, stroke_frames: np.ndarray, pitch_frames: np.ndarray
) -> list[str]:
    """A warning for an angle no frame gives (its points never tracked together)."""
    points = ", ".join(f"{name} = {rig.wing_points[name]!r}" for name in rig.wing_points)
    out = []
    if not np.isfinite(pitch_frames).any():
        out.append(
            f"{tracks}: the wing's points ({points}) are never tracked in the same frame: "
            "the run's pitch truth is all NaN"
        )
    if not np.isfinite(stroke_frames).any() and rig.stroke_from == "wing_span":
        out.append(
            f"{tracks}: wing_leading_edge_1 and wing_leading_edge_2 are never tracked in the "
            "same frame: the run's stroke truth is all NaN"
        )
    return out


def read_lab_run(files: LabRunFiles, sync_max_lag_s: float, rig: Rig | None = None) -> LabRun:
    """Read and check one run's files (see module docstring)."""
    rig = read_rig(files.rig) if rig is None else rig
    log = read_target_log(files.mat, rig.labels, rig.log_variable)
    signal = {role: log.signals[label] for role, label in rig.signals.items()}
    wing = read_xyz_points(files.tracks, rig.wing_points, rig.length_unit_m)
    tip = None
    if rig.stroke_from == "actuator_tip":
        if files.tip_track is None:
            raise LabFileError(
                f"{files.rig}: stroke_from: actuator_tip needs the 2D track "
                "(--tip-track RUN_xypts.csv)"
            )
        assert rig.tip is not None
        tip = read_xy_point(files.tip_track, rig.tip.point, rig.tip.camera, "points.actuator_tip")
    wing, tip, outliers = drop_track_outliers(wing, tip)
    try:
        stroke_frames, pitch_frames = lab_run.video_angles_deg(rig, wing, tip)
    except VideoGeometryError as exc:
        raise LabFileError(f"{files.tracks}: {exc}") from None
    placement = lab_run.place_frames(
        stroke_frames.size, rig, log.time_s, signal.get("camera_trigger"), str(files.mat)
    )
    n, fs_hz = log.time_s.size, log.sample_rate_hz
    stroke_deg, pitch_deg = lab_run.truth_columns(n, placement, stroke_frames, pitch_frames)
    columns = {
        "time_s": log.time_s - log.time_s[0],
        "drive_v": lab_run.drive_v(signal["drive"], rig),
        "stroke_sensor_v": signal["stroke_sensor"],
        "pitch_sensor_v": signal["pitch_sensor"],
        "stroke_deg": stroke_deg,
        "pitch_deg": pitch_deg,
    }
    check, warnings = _sync_check(files.mat, columns, fs_hz, rig.fps, sync_max_lag_s)
    tracked = np.isfinite(stroke_frames) & np.isfinite(pitch_frames)
    warnings += _untracked(files.tracks, rig, stroke_frames, pitch_frames)
    if outliers:
        warnings.append(f"{files.tracks}: {outliers} outlying frame(s) dropped")
    if placement.placed == 0:
        raise LabFileError(
            f"{files.mat}: none of the video's {stroke_frames.size} frames falls "
            "inside the log: check the sync (trigger frame or frame0_time_s)"
        )
    if check is not None and check.suspicious:
        warnings.append(
            f"{files.mat}: the video's stroke lines up with the stroke sensor's estimate "
            f"{1e3 * check.offset_s:+.3f} ms off, more than one frame "
            f"({1e3 * check.frame_period_s:.3f} ms): check the sync (trigger frame, threshold "
            "or frame0_time_s)"
        )
    extras = {
        "lab_files": {
            "mat": str(files.mat),
            "variable": log.variable,
            "tracks": str(files.tracks),
            "tip_track": None if files.tip_track is None else str(files.tip_track),
            "rig_file": str(files.rig),
        },
        "rig": rig.source,
        "sync": {
            "method": "trigger" if rig.trigger_frame is not None else "frame0_time_s",
            "trigger_time_s": placement.trigger_time_s,
            "trigger_frame": rig.trigger_frame,
            "frame0_time_s": rig.frame0_time_s,
            "frames_placed": placement.placed,
            "frames_dropped": placement.dropped,
            "offset_s": None if check is None else check.offset_s,
            "correlation": None if check is None else check.correlation,
        },
        "video": {
            "fps": rig.fps,
            "frames": int(stroke_frames.size),
            "tracked_share": float(tracked.mean()),
            "outliers_dropped": outliers,
            "stroke_from": rig.stroke_from,
        },
    }
    return LabRun(MeasuredRun(files.mat.stem, fs_hz, columns), extras, warnings)


def _path(base: Path, value: Any, where: str) -> Path:
    if not isinstance(value, str) or not value:
        raise LabFileError(f"{where}: must be a file path, got {value!r}")
    return base / value


def read_manifest(path: Path | str) -> list[LabRunFiles]:
    """A session's runs from its manifest (see module docstring)."""
    path = Path(path)
    try:
        data = read_yaml(path, "manifest")
    except CheckedFileError as exc:
        raise LabFileError(str(exc)) from None
    if not isinstance(data, dict) or set(data) - {"rig", "runs"} or "runs" not in data:
        raise LabFileError(
            f"{path}: a manifest is a mapping with 'runs' (a list) and optionally 'rig'"
        )
    runs = data["runs"]
    if not isinstance(runs, list) or not runs:
        raise LabFileError(f"{path}: runs: must be a non-empty list")
    base = path.parent
    out = []
    for k, entry in enumerate(runs, start=1):
        where = f"{path}: runs[{k}]"
        if not isinstance(entry, dict) or set(entry) - {"mat", "tracks", "tip_track", "rig"}:
            raise LabFileError(
                f"{where}: must be a mapping of mat, tracks and optionally "
                f"tip_track and rig; got {entry!r}"
            )
        if "rig" not in entry and "rig" not in data:
            raise LabFileError(f"{where}: no rig (give 'rig' for the session or for this run)")
        for key in ("mat", "tracks"):
            if key not in entry:
                raise LabFileError(f"{where}: missing '{key}'")
        out.append(
            LabRunFiles(
                mat=_path(base, entry["mat"], f"{where}.mat"),
                rig=_path(base, entry.get("rig", data.get("rig")), f"{where}.rig"),
                tracks=_path(base, entry["tracks"], f"{where}.tracks"),
                tip_track=(
                    _path(base, entry["tip_track"], f"{where}.tip_track")
                    if entry.get("tip_track") is not None
                    else None
                ),
            )
        )
    return out


def check_max_lag(value: float) -> float:
    """The sync check's lag range [s] from config (import_runs.sync_check_max_lag_s)."""
    if not (math.isfinite(value) and value > 0):
        raise LabFileError(
            f"config/flaair.yaml: import_runs.sync_check_max_lag_s must be > 0 s, got {value}"
        )
    return value
