"""Regenerate examples/lab_session: a bench session's files as a lab has them (docs/LAB_FILES.md).

Two runs of the paper's bench robot (the project's simulated plant with 23 % strain transfer on
the hinge film, tests/lab_files.py) driven by a 20-200 Hz chirp at 100 V through the 100x
amplifier, logged by the real-time target at 5 kHz on 16-bit converters, and filmed at
2,000 fps for 0.4 s from the camera trigger's rising edge (frame 1 at the edge); the wing put
through the tests' camera geometry (tilted `up`, points numbered out of order):

- ``run01.mat``: MAT v5 (compressed, as ``save -v7``) from a plain ``save`` at the bench: the
  log ``rt_log`` and the target object ``tg`` (an MCOS object) beside it;
- ``run02.mat``: MAT v7.3 (HDF5);
- ``run01_xyzpts.csv``, ``run01_xypts.csv``: DLTdv8a 8.4 (named points, ``_U``/``_V``);
- ``run02_xyzpts.csv``, ``run02_xypts.csv``: DLTdv7 (``ptN_``, 6 significant digits);
- ``bench_rig.yaml`` and the manifest ``session1.yaml``.

Deterministic: seeded noise, fixed MAT header text; running it again writes the same bytes
(tests/test_lab_example.py checks the shipped files against a fresh run).

Run: scripts/in_env.sh python scripts/make_lab_example.py [--out DIR]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO_ROOT / "tests"))

import lab_files as lf  # the tests' generator: one place for both
import lab_writers as lw

LOG_HZ, FPS, DURATION_S = 5000.0, 2000.0, 2.0
TRIGGER_S, FILMED_S = 0.8, 0.4  # the camera starts at the trigger's edge
ADC_LSB_V = 2.0**-13  # 16 bits over +-4 V
NAMES_8_4 = ["spar_tip", "hinge", "trailing_edge"]  # DLTdv8a 8.4 names of points 1, 2, 3
RUNS = {"run01": {"seed": 3, "mat": "v5", "tracks": "DLTdv8a 8.4"}}
RUNS["run02"] = {"seed": 4, "mat": "v7.3", "tracks": "DLTdv7"}

RIG = """\
# The bench of docs/LAB_FILES.md's walk-through (examples/lab_session)
signals:                          # MAT signal label -> role
  drive: "amp_in"                 # the amplifier's input
  stroke_sensor: "pvdf_act"
  pitch_sensor: "pvdf_hinge"
  camera_trigger: "cam_trig"
drive_gain_v_per_v: 100.0         # the paper's 100x amplifier
drive_bias_v: 0.0
video:
  fps: 2000.0
  sync:
    trigger_frame: 1              # DLTdv's frame 1 was taken at the trigger's rising edge
    trigger_threshold_v: 2.5
  length_unit_m: 0.001            # the calibration's unit: mm
points:                           # DLTdv point numbers (or names, e.g. "hinge")
  wing_leading_edge_1: 2
  wing_trailing_edge_1: 3
  wing_leading_edge_2: 1
  actuator_tip: {point: 1, camera: 2}
geometry:
  up: [0.2, -0.3, 0.93]
  rest_span: [1.0, 0.4, 0.1]
  m_per_px: 1.0e-5
  tip_axis_px: [0.6, -0.8]
  transmission_ratio_rad_per_m: 2000.0
stroke_from: actuator_tip
"""

MANIFEST = """\
# A session: paths relative to this file
rig: bench_rig.yaml
runs:
  - {mat: run01.mat, tracks: run01_xyzpts.csv, tip_track: run01_xypts.csv}
  - {mat: run02.mat, tracks: run02_xyzpts.csv, tip_track: run02_xypts.csv}
"""


def adc(values: np.ndarray) -> np.ndarray:
    """A 16-bit converter's reading."""
    return np.round(values / ADC_LSB_V) * ADC_LSB_V


def write_run(out: Path, name: str, seed: int, mat: str, tracks: str) -> None:
    run = lf.chirp_run(seed=seed, duration_s=DURATION_S)
    keep = np.arange(0, run["drive_v"].size, round(lf.FS_HZ / LOG_HZ))
    time_s = np.arange(keep.size) / LOG_HZ
    trigger = np.where(time_s >= TRIGGER_S - 1e-12, 5.0, 0.0)
    log = lf.structure_with_time(
        time_s,
        {
            "amp_in": adc(run["drive_v"][keep] / lf.GAIN_V_PER_V),
            "pvdf_act": adc(run["stroke_sensor_v"][keep]),
            "pvdf_hinge": adc(run["pitch_sensor_v"][keep]),
            "cam_trig": trigger,
        },
    )
    path = out / f"{name}.mat"
    path.unlink(missing_ok=True)  # hdf5storage would write into an existing file
    if mat == "v5":
        lw.write_v5_with_object(path, {"rt_log": log}, {"tg": "slrealtime.Target"})
        lw.fixed_header(path, "5.0")
    else:
        lf.write_mat(path, log, "v7.3")
        lw.fixed_header(path, "7.3")
    # the video: frames 1 ... at the trigger's edge onwards, taken at the simulation's samples
    frames = np.arange(int(FILMED_S * FPS))
    sample = np.rint((TRIGGER_S + frames / FPS) * lf.FS_HZ).astype(int)
    stroke, pitch = run["stroke_rad"][sample], run["pitch_rad"][sample]
    points = lf.wing_points_mm(stroke, pitch)
    tracked = frames % 97 != 40  # the tracker lost the wing now and then
    order = sorted(lf.POINTS, key=lf.POINTS.get)  # points 1, 2, 3
    xyz = np.column_stack([points[key] for key in order])
    xyz[~tracked] = np.nan
    axis = lf.TIP_AXIS_PX / np.linalg.norm(lf.TIP_AXIS_PX)
    deflection_px = stroke / lf.TRANSMISSION_RAD_PER_M / lf.M_PER_PX
    tip = np.array([640.0, 360.0]) + deflection_px[:, None] * axis
    tip[~tracked] = np.nan
    # camera 1 saw the tip only at the start (a mirror's view), camera 2 throughout
    cam1 = tip + np.array([15.0, -3.0])
    cam1[200:] = np.nan
    xy = np.column_stack([cam1, tip])
    if tracks == "DLTdv8a 8.4":
        xyz_header = lw.xyz_header(NAMES_8_4)
        xy_header = lw.xy_header(["tip"], 2, "UV")
    else:
        xyz_header = lw.xyz_header(["pt1", "pt2", "pt3"])
        xy_header = lw.xy_header(["pt1"], 2, "XY")
    lw.write_track(out / f"{name}_xyzpts.csv", xyz_header, xyz, tracks)
    lw.write_track(out / f"{name}_xypts.csv", xy_header, xy, tracks)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--out", type=Path, default=REPO_ROOT / "examples" / "lab_session", help="folder"
    )
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    for name, spec in RUNS.items():
        write_run(args.out, name, **spec)
    (args.out / "bench_rig.yaml").write_text(RIG)
    (args.out / "session1.yaml").write_text(MANIFEST)
    total = sum(p.stat().st_size for p in args.out.iterdir())
    print(f"wrote {args.out} ({total / 1e3:.0f} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
