"""A lab's files generated for the tests: a simulated bench run put through a camera geometry.

The target's log is written as a Simulink Structure-with-time variable in MAT v5 (scipy.io)
and MAT v7.3 (hdf5storage); the wing's points as a DLTdv8 ``*_xyzpts.csv`` (millimetres, points
numbered out of order) and the actuator tip as a ``*_xypts.csv`` (pixels); the rig file as YAML.
The generator's own angles at every frame come back for comparison.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

FS_HZ = 20000.0
FPS = 10000.0
GAIN_V_PER_V = 100.0
BIAS_V = 0.0
TRIGGER_S = 0.0123  # the camera trigger's rising edge
# DLTdv's number (the first row is frame 1) of the frame taken at that edge: frames 1-27
# precede the log
TRIGGER_FRAME = 151
UP = np.array([0.2, -0.3, 0.93])
REST_SPAN = np.array([1.0, 0.4, 0.1])
ORIGIN_MM = np.array([12.0, -4.0, 30.0])
TRANSMISSION_RAD_PER_M = 2.0e3
M_PER_PX = 1.0e-5
TIP_AXIS_PX = np.array([0.6, -0.8])
POINTS = {"wing_leading_edge_1": 2, "wing_trailing_edge_1": 3, "wing_leading_edge_2": 1}


@dataclass(frozen=True)
class LabSession:
    """What `write_lab_run` wrote, and the angles it put into the video."""

    mat: Path
    rig: Path
    tracks: Path
    tip_track: Path
    frame_sample: np.ndarray  # DAQ sample of each frame (-1: outside the log)
    stroke_deg: np.ndarray  # generator's angles per frame (NaN: not tracked)
    pitch_deg: np.ndarray


def bench_model():
    """The paper's bench robot: nominal plant, 23 % strain transfer on the hinge film."""
    from flaair_model.model import with_effects
    from flaair_model.model_io import load_model

    return with_effects(
        load_model(), {"strain_transfer_loss": {"efficiency": 0.23, "channel": "pitch"}}
    )


def chirp_run(seed: int = 3, duration_s: float = 1.0) -> dict[str, np.ndarray]:
    """A 20-200 Hz chirp at 100 V on the bench robot: drive, sensors and true angles (rad)."""
    from flaair_sim.core.drive import DriveParams, drive_record
    from flaair_sim.core.plant import simulate

    n = int(duration_s * FS_HZ)
    drive = drive_record(
        DriveParams(
            kind="chirp", amplitude_v=100.0, start_hz=20.0, stop_hz=200.0, duration_s=duration_s
        ),
        FS_HZ,
        n,
    )
    out = simulate(drive, FS_HZ, bench_model(), noise=True, rng=np.random.default_rng(seed))
    return {
        "drive_v": drive,
        "stroke_sensor_v": out.stroke_sensor_v,
        "pitch_sensor_v": out.pitch_sensor_v,
        "stroke_rad": out.stroke_rad,
        "pitch_rad": out.pitch_rad,
    }


def _rotate(v: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rows of `v` turned by `angle` about the unit rows (or vector) `axis` (Rodrigues)."""
    cos, sin = np.cos(angle)[:, None], np.sin(angle)[:, None]
    dot = np.sum(axis * v, axis=-1, keepdims=True)
    return v * cos + np.cross(axis, v) * sin + axis * dot * (1 - cos)


def wing_points_mm(stroke_rad: np.ndarray, pitch_rad: np.ndarray) -> dict[str, np.ndarray]:
    """LE1, TE1, LE2 per frame (mm) of a wing at those angles: LE2 out along the span and a
    little above the stroke plane, TE1 down the chord and a little along the span.
    """
    u = UP / np.linalg.norm(UP)
    r = REST_SPAN - np.dot(REST_SPAN, u) * u
    r = np.broadcast_to(r / np.linalg.norm(r), (stroke_rad.size, 3))
    s = _rotate(r, u, stroke_rad)
    c = _rotate(np.broadcast_to(-u, s.shape), s, pitch_rad)
    le1 = np.tile(ORIGIN_MM, (stroke_rad.size, 1))
    return {
        "wing_leading_edge_1": le1,
        "wing_leading_edge_2": le1 + 9.0 * s + 0.7 * u,
        "wing_trailing_edge_1": le1 + 4.0 * c + 0.5 * s,
    }


def rig_mapping(
    sync: str = "trigger",
    stroke_from: str = "wing_span",
    trigger_frame: int = TRIGGER_FRAME,
    fps: float = FPS,
) -> dict:
    """The rig file's content for these files."""
    video = {
        "fps": fps,
        "length_unit_m": 0.001,
        "sync": (
            {"trigger_frame": trigger_frame, "trigger_threshold_v": 2.5}
            if sync == "trigger"
            else {"frame0_time_s": TRIGGER_S - (TRIGGER_FRAME - 1) / FPS}
        ),
    }
    return {
        "signals": {
            "drive": "amp_in",
            "stroke_sensor": "pvdf_act",
            "pitch_sensor": "pvdf_hinge",
            "camera_trigger": "cam_trig",
        },
        "drive_gain_v_per_v": GAIN_V_PER_V,
        "drive_bias_v": BIAS_V,
        "video": video,
        "points": {**POINTS, "actuator_tip": {"point": 1, "camera": 2}},
        "geometry": {
            "up": UP.tolist(),
            "rest_span": REST_SPAN.tolist(),
            "m_per_px": M_PER_PX,
            "tip_axis_px": TIP_AXIS_PX.tolist(),
            "transmission_ratio_rad_per_m": TRANSMISSION_RAD_PER_M,
        },
        "stroke_from": stroke_from,
    }


def structure_with_time(time_s: np.ndarray, signals: dict[str, np.ndarray]) -> dict:
    """Simulink's Structure with time: time N x 1, signals a 1 x k struct array."""
    array = np.zeros(
        (1, len(signals)), dtype=[("values", object), ("label", object), ("blockName", object)]
    )
    for k, (label, values) in enumerate(signals.items()):
        array[0, k] = (values.reshape(-1, 1), label, f"bench/{label}")
    return {"time": time_s.reshape(-1, 1), "signals": array, "blockName": "bench"}


def write_mat(path: Path, log: dict, version: str) -> Path:
    """`log` as variable `rt_log` of a MAT file, version "v5" or "v7.3"."""
    if version == "v5":
        import scipy.io

        scipy.io.savemat(str(path), {"rt_log": log}, do_compression=True)
    else:
        import hdf5storage

        hdf5storage.savemat(str(path), {"rt_log": log}, format="7.3", matlab_compatible=True)
    return path


def write_xyzpts(path: Path, points_mm: dict[str, np.ndarray], numbers: dict[str, int]) -> None:
    """DLTdv8 3D points: pt1_X,pt1_Y,pt1_Z,... in point order; empty cells where untracked."""
    order = sorted(numbers, key=numbers.get)
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow([f"pt{numbers[name]}_{axis}" for name in order for axis in "XYZ"])
        frames = next(iter(points_mm.values())).shape[0]
        for k in range(frames):
            row = []
            for name in order:
                xyz = points_mm[name][k]
                row += ["" if not math.isfinite(x) else f"{x:.6f}" for x in xyz]
            writer.writerow(row)


def write_lab_run(
    directory: Path,
    name: str,
    run: dict[str, np.ndarray],
    version: str = "v5",
    untracked_every: int = 50,
    log_hz: float = FS_HZ,
    never_together: bool = False,
    **rig_options,
) -> LabSession:
    """The run's MAT log (`version`), tracks and rig file in `directory`.

    The target logs every (FS_HZ / `log_hz`)-th sample of the simulation; the video runs at
    the rig's fps. `never_together`: each frame lacks one of the wing's three points in turn.
    """
    fps = rig_options.get("fps", FPS)
    keep = np.arange(0, run["drive_v"].size, round(FS_HZ / log_hz))
    run = {key: values[keep] for key, values in run.items()}
    n = keep.size
    time_s = np.arange(n) / log_hz
    trigger = np.where(time_s >= TRIGGER_S - 1e-12, 5.0, 0.0)
    t_trig = time_s[np.argmax(trigger > 0)]  # the first logged sample of the edge
    log = structure_with_time(
        time_s,
        {
            "amp_in": (run["drive_v"] + BIAS_V) / GAIN_V_PER_V,
            "pvdf_act": run["stroke_sensor_v"],
            "pvdf_hinge": run["pitch_sensor_v"],
            "cam_trig": trigger,
        },
    )
    mat = write_mat(directory / f"{name}.mat", log, version)
    # frames (DLTdv's numbers, from 1) from before the log starts to past its end: dropped
    frames = np.arange(1, int((time_s[-1] + 0.002 - t_trig) * fps) + TRIGGER_FRAME)
    frame_t = t_trig + (frames - TRIGGER_FRAME) / fps
    sample = np.rint(frame_t * log_hz).astype(int)
    inside = (sample >= 0) & (sample < n)
    stroke = np.where(inside, run["stroke_rad"][np.clip(sample, 0, n - 1)], 0.0)
    pitch = np.where(inside, run["pitch_rad"][np.clip(sample, 0, n - 1)], 0.0)
    tracked = frames % untracked_every != 7 if untracked_every else np.ones(frames.size, bool)
    points = wing_points_mm(stroke, pitch)
    for xyz in points.values():
        xyz[~tracked] = np.nan
    if never_together:
        for k, name_ in enumerate(sorted(points)):
            points[name_][frames % 3 == k] = np.nan
    tracks = directory / f"{name}_xyzpts.csv"
    write_xyzpts(tracks, points, POINTS)
    tip_px = np.array([640.0, 360.0]) + (stroke / TRANSMISSION_RAD_PER_M / M_PER_PX)[
        :, None
    ] * TIP_AXIS_PX / np.linalg.norm(TIP_AXIS_PX)
    tip_px[~tracked] = np.nan
    tip_track = directory / f"{name}_xypts.csv"
    with open(tip_track, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["pt1_cam1_X", "pt1_cam1_Y", "pt1_cam2_X", "pt1_cam2_Y"])
        for xy in tip_px:
            cells = ["NaN" if not math.isfinite(v) else f"{v:.5f}" for v in xy]
            writer.writerow(["NaN", "NaN", *cells])
    rig = directory / f"{name}_rig.yaml"
    rig.write_text(yaml.safe_dump(rig_mapping(**rig_options), sort_keys=False))
    truth_stroke = np.where(inside & tracked, np.degrees(stroke), np.nan)
    truth_pitch = np.where(inside & tracked & ~never_together, np.degrees(pitch), np.nan)
    return LabSession(
        mat, rig, tracks, tip_track, np.where(inside, sample, -1), truth_stroke, truth_pitch
    )
