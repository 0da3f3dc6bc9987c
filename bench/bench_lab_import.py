"""`flaair import RUN.mat --rig --tracks --tip-track`: a 10 s run at 20 kHz, video at 10,000 fps.

The lab files are made here: the target's log as a Structure-with-time MAT file (v5 through
scipy.io, and v7.3 through hdf5storage), the wing's three points as a DLTdv8 xyzpts CSV of
100,000 frames and the actuator tip as an xypts CSV. Each import runs in a fresh interpreter
(`import_cli.main`, everything a lab's call does: read, angles, sync check, bag), timed from
its first line; its peak RSS (sampled every 2 ms from /proc/self/statm) is taken against the
same interpreter's RSS once its imports are loaded (the same-run baseline: what the data
costs, not the interpreter and its libraries; ru_maxrss would keep the imports' own transient
peak, which hid the data's cost).
A v7.3 log is read in a child process of its own (docs/LAB_FILES.md); its peak is reported.
A third import reads the same run from a MAT v5 log that holds 40 unused signals beside the
four it needs (only the log's used signals are kept while reading: its peak should stay that
of the four-signal file, not grow with the 40). Targets (#24): <= 5 s, and peak memory <= 3x
the files' size (the wide case: the four-signal run's files).

Run: scripts/in_env.sh python bench/bench_lab_import.py
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

from benchlib import REPO_ROOT, compare, print_table, write_json

FS_HZ, FPS, DURATION_S = 20000.0, 10000.0, 10.0
CHILD = """
import json, os, resource, sys, threading, time
from pathlib import Path
t0 = time.perf_counter()
from flaair_tools.bagio import import_cli
from flaair_tools.bagio.lab_import import sensor_stroke_deg
import numpy as np
sensor_stroke_deg(np.full(100, 1.25), np.full(100, 1.25), 20000.0)   # numba kernels loaded
PAGE = os.sysconf("SC_PAGE_SIZE")
def rss():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * PAGE
# the peak is sampled (every 2 ms): ru_maxrss keeps the imports' own transient peak, which
# can hide what the data costs
base, peak, done = rss(), [0], threading.Event()
def watch():
    while not done.is_set():
        peak[0] = max(peak[0], rss())
        done.wait(0.002)
watcher = threading.Thread(target=watch, daemon=True)
watcher.start()
start = time.perf_counter()
code = import_cli.main(sys.argv[1:])
wall = time.perf_counter() - start
done.set()
watcher.join()
peak = max(peak[0], rss())
child = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024
print(json.dumps({"code": code, "wall_s": wall, "startup_s": start - t0, "base": base,
                  "peak": peak, "child_peak": child}))
"""


def write_files(root: Path) -> dict[str, Path]:
    """The lab's files of one run (both MAT versions) and its rig file."""
    import hdf5storage
    import scipy.io

    n = int(DURATION_S * FS_HZ)
    t = np.arange(n) / FS_HZ
    rng = np.random.default_rng(0)
    drive = 100.0 * np.sin(2 * np.pi * 120.0 * t)
    signals = {
        "amp_in": drive / 100.0,
        "pvdf_act": 1.25 - 0.3 * np.sin(2 * np.pi * 120.0 * t) + rng.normal(0, 0.002, n),
        "pvdf_hinge": 1.25 - 0.1 * np.sin(2 * np.pi * 120.0 * t - 1.0) + rng.normal(0, 0.002, n),
        "cam_trig": np.where(t >= 0.01, 5.0, 0.0),
    }
    array = np.zeros(
        (1, len(signals)), dtype=[("values", object), ("label", object), ("blockName", object)]
    )
    for k, (label, values) in enumerate(signals.items()):
        array[0, k] = (values.reshape(-1, 1), label, f"bench/{label}")
    log = {"time": t.reshape(-1, 1), "signals": array, "blockName": "bench"}
    files = {"v5": root / "run_v5.mat", "v7.3": root / "run_v73.mat"}
    scipy.io.savemat(str(files["v5"]), {"rt_log": log}, do_compression=True)
    # a bench's wide log: 40 unused signals (other channels, noise) beside the four it needs
    wide = np.zeros((1, 44), dtype=array.dtype)
    for k in range(40):
        wide[0, k] = (rng.normal(0, 0.01, (n, 1)), f"aux_{k:02d}", f"bench/aux_{k:02d}")
    wide[0, 40:] = array[0]
    files["v5-wide"] = root / "run_v5_wide.mat"
    scipy.io.savemat(
        str(files["v5-wide"]), {"rt_log": {**log, "signals": wide}}, do_compression=True
    )
    hdf5storage.savemat(str(files["v7.3"]), {"rt_log": log}, format="7.3", matlab_compatible=True)
    frames = int(DURATION_S * FPS)
    tf = 0.01 + np.arange(frames) / FPS
    stroke, pitch = (
        np.radians(30) * np.sin(2 * np.pi * 120 * tf),
        np.radians(40) * np.cos(2 * np.pi * 120 * tf),
    )
    span = np.column_stack([np.cos(stroke), np.sin(stroke), np.zeros(frames)])
    chord = np.column_stack(
        [np.sin(pitch) * -np.sin(stroke), np.sin(pitch) * np.cos(stroke), -np.cos(pitch)]
    )
    le1 = np.zeros((frames, 3)) + np.array([10.0, 5.0, 20.0])
    table = np.column_stack([le1 + 9 * span, le1, le1 + 4 * chord])
    files["tracks"] = root / "run_xyzpts.csv"
    with open(files["tracks"], "w") as handle:
        handle.write(",".join(f"pt{p}_{a}" for p in (1, 2, 3) for a in "XYZ") + "\n")
        np.savetxt(handle, table, delimiter=",", fmt="%.6f")
    files["tip"] = root / "run_xypts.csv"
    tip = np.column_stack([640 + 1e3 * stroke, 360 + 0 * stroke])
    with open(files["tip"], "w", newline="") as handle:
        csv.writer(handle).writerow(["pt1_cam1_X", "pt1_cam1_Y"])
        np.savetxt(handle, tip, delimiter=",", fmt="%.4f")
    files["rig"] = root / "rig.yaml"
    files["rig"].write_text(
        yaml.safe_dump(
            {
                "signals": {
                    "drive": "amp_in",
                    "stroke_sensor": "pvdf_act",
                    "pitch_sensor": "pvdf_hinge",
                    "camera_trigger": "cam_trig",
                },
                "drive_gain_v_per_v": 100.0,
                "video": {
                    "fps": FPS,
                    "sync": {"trigger_frame": 1, "trigger_threshold_v": 2.5},
                    "length_unit_m": 0.001,
                },
                "points": {
                    "wing_leading_edge_1": 2,
                    "wing_trailing_edge_1": 3,
                    "wing_leading_edge_2": 1,
                    "actuator_tip": {"point": 1, "camera": 1},
                },
                "geometry": {
                    "up": [0, 0, 1],
                    "rest_span": [1, 0, 0],
                    "m_per_px": 1e-5,
                    "tip_axis_px": [1, 0],
                    "transmission_ratio_rad_per_m": 100.0,
                },
                "stroke_from": "actuator_tip",
            }
        )
    )
    return files


def run_import(files: dict[str, Path], version: str, out: Path) -> dict:
    args = [
        str(files[version]),
        "--rig",
        str(files["rig"]),
        "--tracks",
        str(files["tracks"]),
        "--tip-track",
        str(files["tip"]),
        "--out",
        str(out),
    ]
    done = subprocess.run(
        [sys.executable, "-c", CHILD, *args], capture_output=True, text=True, check=True
    )
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["code"] == 0, done.stderr
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--json", type=Path, default=REPO_ROOT / "out" / "bench" / "bench_lab_import.json"
    )
    args = parser.parse_args()
    mb = 1e6
    figures = []
    peaks: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        files = write_files(Path(tmp))
        for version in ("v5", "v7.3"):
            size = sum(files[k].stat().st_size for k in (version, "tracks", "tip"))
            r = run_import(files, version, Path(tmp) / f"bag_{version}")
            data_peak = r["peak"] - r["base"]
            peaks[version] = data_peak
            figures += [
                compare(
                    f"lab import (MAT {version}), 10 s at 20 kHz + 10,000 fps: wall time",
                    r["wall_s"],
                    "s",
                    "<=",
                    5.0,
                    f"interpreter start and imports: {r['startup_s']:.1f} s",
                ),
                compare(
                    f"lab import (MAT {version}): peak RSS above the imports / files' size",
                    data_peak / size,
                    "x",
                    "<=",
                    3.0,
                    f"files {size / mb:.1f} MB; interpreter + imports {r['base'] / mb:.0f} MB"
                    + (
                        f"; v7.3 reader process peak {r['child_peak'] / mb:.0f} MB"
                        if version == "v7.3"
                        else ""
                    ),
                ),
            ]
        # the same run, its MAT v5 log holding 40 unused signals beside the four it needs
        wide_mat = files["v5-wide"].stat().st_size
        size = sum(files[k].stat().st_size for k in ("v5", "tracks", "tip"))
        r = run_import(files, "v5-wide", Path(tmp) / "bag_v5_wide")
        data_peak = r["peak"] - r["base"]
        figures += [
            compare(
                "lab import (MAT v5, 44 signals of which 4 used): wall time",
                r["wall_s"],
                "s",
                "<=",
                5.0,
                f"the MAT file {wide_mat / mb:.0f} MB (the 4-signal file: "
                f"{files['v5'].stat().st_size / mb:.1f} MB)",
            ),
            compare(
                "lab import (MAT v5, 44 signals of which 4 used): peak RSS above the imports / "
                "the 4-signal run's files",
                data_peak / size,
                "x",
                "<=",
                3.0,
                f"peak {data_peak / mb:.0f} MB against {peaks['v5'] / mb:.0f} MB for the "
                f"4-signal file; the 40 unused signals alone are "
                f"{40 * DURATION_S * FS_HZ * 8 / mb:.0f} MB as doubles",
            ),
        ]
    print_table(figures)
    write_json(figures, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
