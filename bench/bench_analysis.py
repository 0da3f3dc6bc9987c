"""Analysis speed: `flaair analyze` of a 1 s, 20 kHz chirp bag (target: at most 5 s).

The bag is a lab-format chirp of the bench robot imported with `flaair import` (no DDS graph
needed); the same-run baseline is reading the bag's block topics alone.
Run: scripts/in_env.sh python bench/bench_analysis.py [--json PATH]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from benchlib import compare, print_table, write_json

FS_HZ = 20000.0
TARGET_S = 5.0


def make_bag(directory: Path) -> Path:
    """A 1 s chirp of the bench robot, as a lab would import it."""
    from flaair_common.runcsv import write_run
    from flaair_sim.core.drive import DriveParams, drive_record
    from flaair_sim.core.measured_run import synthesize_measured_run
    from flaair_tools.bagio.import_runs import import_runs
    from flaair_tools.orchestration.bench_robot import robot_model

    model = robot_model()
    drive = drive_record(
        DriveParams(kind="chirp", amplitude_v=100.0, start_hz=20.0, stop_hz=200.0, duration_s=1.0),
        FS_HZ,
        int(FS_HZ),
    )
    write_run(
        directory / "chirp.csv",
        synthesize_measured_run(drive, FS_HZ, model, np.random.default_rng(0)),
    )
    bag = directory / "bag"
    import_runs([directory / "chirp.csv"], bag, gap_s=0.1, block_size=10, frame_id="robot")
    return bag


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    from flaair_tools.analysis.analyze import analyze
    from flaair_tools.bagio.runs import load_runs

    with tempfile.TemporaryDirectory() as tmp:
        bag = make_bag(Path(tmp))
        analyze([bag], Path(tmp) / "warm", progress=False)  # imports, numba caches
        start = time.perf_counter()
        analyze([bag], Path(tmp) / "report", progress=False)
        analysis_s = time.perf_counter() - start
        start = time.perf_counter()
        load_runs([bag])
        read_s = time.perf_counter() - start
    figures = [
        compare(
            "analysis of a 1 s 20 kHz chirp bag",
            analysis_s,
            "s",
            "<=",
            TARGET_S,
            f"reading the bag alone: {read_s:.2f} s",
        )
    ]
    print_table(figures)
    if args.json:
        write_json(figures, args.json)


if __name__ == "__main__":
    main()
