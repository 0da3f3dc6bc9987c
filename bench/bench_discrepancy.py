"""Discrepancy workflow speed: one robot's data set analysed end to end.

Run: python bench/bench_discrepancy.py [--json out.json] [--no-sweep]

The data set is the standard run set of one robot (chirp 20-200 Hz 1 s at 100 V and at 50 V,
stepped sine 60-200 Hz in 10 Hz steps of 0.2 s at 100 V: 5 s at 20 kHz, noise on) with three
hidden effects: structural damping (stroke), a 100 us acquisition delay on both sensors and the
paper's pitch-sensor strain-transfer loss (x0.23).

Figures:
- the core analysis (`discrepancy.analyse`), target <= 120 s; baseline: one simulation of
  the whole data set;
- the command line end to end (`bin/flaair discrepancy` in-process: read 3 CSV files, analyse,
  write model.yaml, discrepancy.json, figures and report.html), target <= 120 s;
- with the sweep (default): every hidden-effect dataset case, cases right (confusion table in
  out/bench/discrepancy_validation/validation.html) and the time per case.
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from benchlib import REPO_ROOT, Figure, best_time_s, print_table, write_json

from flaair_common.runcsv import write_run
from flaair_model.model_io import load_model
from flaair_sim.plant import simulate
from flaair_tools import discrepancy
from flaair_tools.discrepancy import analyse
from flaair_tools.discrepancy.datasets import DatasetCase, confusion_table, dataset_cases, make_runs, score_case
from flaair_tools.discrepancy.report import write_validation

TARGET_S = 120.0
ROBOT = DatasetCase(
    "bench_robot", "pair",
    (("structural_damping", {"damping_ratio": 0.03}),
     ("sensor_delay", {"delay_s": 1e-4, "channel": "both"}),
     ("strain_transfer_loss", {"efficiency": 0.23, "channel": "pitch"})),
    seed=11)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, help="write the figures as JSON here")
    parser.add_argument("--no-sweep", action="store_true", help="skip the dataset sweep")
    args = parser.parse_args()
    model = load_model()
    runs = make_runs(ROBOT, model)
    n = sum(r.n for r in runs)
    simulate(runs[0].drive_v[:10], runs[0].fs_hz, model)  # numba cache load, not timed
    t_sim = best_time_s(lambda: [simulate(r.drive_v, r.fs_hz, model) for r in runs], repeats=3)
    figures: list[Figure] = []

    results = []
    t_core = best_time_s(lambda: results.append(analyse(runs, model)), repeats=2)
    result = results[-1]
    outcome = score_case(ROBOT, result)
    found = ", ".join(f"{e.name}" for e in result.effects)
    figures.append(Figure(f"analyse one robot ({n / runs[0].fs_hz:.0f} s @ 20 kHz, 3 runs), core", t_core, "s",
                          f"<= {TARGET_S:g} s", t_core <= TARGET_S and outcome.correct,
                          f"1 simulation of the set {t_sim * 1e3:.0f} ms; {result.status}: {found}"))

    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for r in runs:
            path = Path(tmp) / f"{r.name}.csv"
            write_run(path, {"time_s": np.arange(r.n) / r.fs_hz, "drive_v": r.drive_v, "stroke_sensor_v": r.stroke_sensor_v,
                             "pitch_sensor_v": r.pitch_sensor_v, "stroke_deg": r.stroke_deg, "pitch_deg": r.pitch_deg})
            paths.append(str(path))
        start = time.perf_counter()
        code = discrepancy.main(paths + ["--out", str(Path(tmp) / "out")])
        t_cli = time.perf_counter() - start
    figures.append(Figure("bin/flaair discrepancy, 3 CSV runs -> model + report", t_cli, "s", f"<= {TARGET_S:g} s",
                          code == 0 and t_cli <= TARGET_S, f"core {t_core:.1f} s"))

    if not args.no_sweep:
        outcomes = []
        start = time.perf_counter()
        for case in dataset_cases():
            case_runs = make_runs(case, model)
            t0 = time.perf_counter()
            res = analyse(case_runs, model)
            outcomes.append(score_case(case, res, time.perf_counter() - t0))
        total = time.perf_counter() - start
        table = confusion_table(outcomes)
        out_dir = REPO_ROOT / "out" / "bench" / "discrepancy_validation"
        write_validation(out_dir, [o.as_dict() for o in outcomes], table, total)
        times = [o.elapsed_s for o in outcomes]
        wrong = ", ".join(o.case for o in outcomes if not o.correct) or "none wrong"
        figures.append(Figure(f"hidden-effect dataset cases right ({len(outcomes)} cases)", table["correct"], "cases",
                              f"all {table['total']}", table["correct"] == table["total"], wrong))
        figures.append(Figure("analysis time per dataset case (median)", statistics.median(times), "s",
                              f"<= {TARGET_S:g} s", max(times) <= TARGET_S, f"max {max(times):.1f} s, sweep {total:.0f} s"))

    print_table(figures)
    if args.json:
        write_json(figures, args.json)


if __name__ == "__main__":
    main()
