"""`make bench` / `make bench-full`: run every benchmark of the project and print one table.

Each bench/bench_*.py runs in its own process (so one's numba compile or DDS graph does not
disturb another) and writes its figures as JSON; this collects them into one table, each
figure beside its target, its same-run baseline where one applies, and whether it is met,
and writes the table as JSON (--json).

Two modes, the same parts and the same figures:
- `make bench` (default): the discrepancy benchmark on its fixed subset of robots and
  hidden-effect cases (bench_discrepancy --subset: a few per family and kind, each count
  marked "subset"); its wall time is a figure against `BENCH_TARGET_S` on the 2-core machine;
- `make bench-full` (--full): every family, every draw, all 46 hidden-effect cases.
Each part prints its wall time beside its budget in that mode (`PARTS`, declared once) and says
when it ran over; the run ends with its total time and "N of M comparisons met" (an `info`
figure is printed, never counted).

Every run that ran every part also writes its results file, `docs/results/<date>-<commit>.json`
(`-subset` before `.json` for `make bench`): the mode, commit, date, machine (cores, CPU model)
and wall time beside every figure. `bench/results_table.py` renders the README's and the guides'
figures tables from the newest one; nothing published is typed by hand.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from benchlib import (
    REPO_ROOT,
    Figure,
    compare,
    figure_from_row,
    figure_rows,
    info,
    print_table,
    write_json,
)

RESULTS_DIR = REPO_ROOT / "docs" / "results"
RESULTS_SCHEMA = "flaair-bench-results/1"


@dataclass(frozen=True)
class Part:
    """One benchmark script and its wall-time budgets (s) and arguments in each mode.

    A budget is what the part takes on the quiet 2-core machine with some room; a part over it
    is reported, not stopped.
    """

    name: str
    budget_s: float
    full_budget_s: float
    args: tuple[str, ...] = ()
    full_args: tuple[str, ...] = ()


# Every bench/bench_*.py, in the order they run (tests/test_bench_plan.py checks that each has
# a budget in both modes and that the quick budgets add up to at most BENCH_BUDGET_S). Each
# budget is the part's wall time in `make bench` on the 2-core machine, the larger of the runs
# measured (docs/results), with a few per cent of room; the streaming parts run shorter signals
# than their scripts' defaults (the same in both modes).
PARTS = (
    # the timings: 10 s; make bench-full also a cold numba compile in a fresh process: 55 s
    Part("bench_sim", 15, 80, (), ("--cold-compile",)),
    Part("bench_frontend_core", 3, 10),  # 2 s
    Part("bench_collision", 5, 10),  # 4 s
    # twelve changed robots, 10 min of unchanged flapping over both controllers (the
    # false-alarm runs: 84,000 wingbeats), 3 x 20 s of a robot the model misses, the core's CPU:
    # 25-27 s
    Part("bench_health", 35, 72),
    Part("bench_analysis", 4, 10),  # 3-4 s
    # 2 scenarios x 10 s recorded (the graph scenario measures after a 4 s start: 5 s leaves
    # nothing to measure), the 2 s player bag: 28-42 s
    Part("bench_recorder", 45, 55),
    Part("bench_closed_loop", 64, 90),  # 5 loops of 2 s and 2 composed of 4 s: 55-71 s
    # make bench: the fixed subset of robots and cases, two at once, one numba thread per worker:
    # 229-238 s; make bench-full every family and draw, all 46 cases
    Part("bench_discrepancy", 250, 3600, ("--subset", "--sweep"), ("--sweep",)),
    Part("bench_stroke", 10, 20),  # 8-9 s
    Part("bench_sweep", 20, 40),  # 11-21 s
    # a 10 s UDP echo, then 15 s live with the health monitor beside the loop and 15 s without
    # it (the script's defaults: 25 s each), their starts and stops: 64-70 s; in full, three
    # pairs of 60 s runs, each judged alone
    Part("bench_bridge", 72, 480, ("--duration", "15"), ("--duration", "60", "--runs", "3")),
    Part("bench_import", 44, 55),  # a 200 MB CSV written, imported, read whole: 37-44 s
    Part("bench_lab_import", 15, 20),  # 13-14 s
    Part("bench_foxglove", 20, 40, ("--duration", "5"), ("--duration", "5")),  # 2 x 5 s: 18 s
    # 409 tests per stack, the two stacks at once: 44-81 s (`make bench-setup` installs the stock
    # stack and compiles both stacks' kernels first)
    Part("bench_stock_numpy", 70, 110),
    Part("bench_workspace", 40, 110),  # a plain colcon build and a node from it: 29-45 s
    # the real ROS 2 tools against FLAAIR: 10 launch files parsed, the namespaced loop under
    # `ros2 launch`, 13 stand-in answers: 87-118 s (`make bench-setup` builds the tools first)
    Part("bench_ros2_conformance", 120, 200),
    # frequency-response tables: identify on a 60-point table, then one robot of each of the six
    # families in both modes (no effect, structural damping, hinge stiffening, collision,
    # actuator saturation, dry friction), the plant batches on both cores: 72-126 s
    Part("bench_tables", 130, 600),
    # odd random-phase multisines: closed forms, five robots of 4 realizations x 2.5 s, a whole
    # `multisine analyze` of M=4 x P=4 at 20 kHz, nine refusals; then `discrepancy` on the hinge
    # film's robot's multisine set (the script's --all-discrepancy-robots adds two more): 10-11 s
    Part("bench_multisine", 30, 90),
    # discovery against the independent truth: one robot of each of its eleven kinds (make
    # bench), five of each and ten of each outside kind (make bench-full), two at once, one numba
    # thread each (the truth's simulation 8-10 s a robot), and each inside robot again on one
    # sine, with the suggested run where that leaves a tie: 187 s; make bench-full about 18 min
    Part("bench_truth", 195, 1800, ("--subset",), ()),
)
# the quick budgets add up to 1190 s
BENCH_BUDGET_S = 20 * 60.0
# `make bench`'s wall time on the 2-core machine from a fresh clone (its set-up apart), the
# target: the parts' measured budgets above still add up to more.
BENCH_TARGET_S = 15 * 60.0


def run_part(part: Part, full: bool, out_dir: Path) -> tuple[list[Figure], float, bool]:
    """Run one part in its own process: (its figures, wall time in s, whether it ran)."""
    script = REPO_ROOT / "bench" / f"{part.name}.py"
    budget = part.full_budget_s if full else part.budget_s
    print(f"[bench] {part.name} (budget {budget:.0f} s) ...", flush=True)
    start = time.monotonic()
    json_path = out_dir / f"{part.name}.json"
    json_path.unlink(missing_ok=True)
    result = subprocess.run(
        [
            sys.executable,
            str(script),
            "--json",
            str(json_path),
            *(part.full_args if full else part.args),
        ],
        capture_output=True,
        text=True,
    )
    took = time.monotonic() - start
    # what the part printed, kept whether it passed or not (its own words on a failed figure)
    (out_dir / f"{part.name}.log").write_text(result.stdout + result.stderr)
    over = f", OVER its budget of {budget:.0f} s" if took > budget else ""
    print(f"[bench] {part.name}: {took:.0f} s{over}", flush=True)
    if result.returncode != 0 or not json_path.exists():
        print(result.stdout[-2000:], result.stderr[-2000:], sep="\n")
        return [], took, False
    loaded = json.loads(json_path.read_text())
    entries = loaded if isinstance(loaded, list) else loaded.get("figures", [])
    return [figure_from_row(e) for e in entries], took, True


def cpu_model() -> str:
    """The CPU's model name (/proc/cpuinfo), or the platform's word for it."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def git_commit() -> str:
    """The checked-out commit (short), with '-dirty' when the tree has changes to tracked files."""

    def git(*args: str) -> str:
        return subprocess.run(
            ["git", *args], cwd=REPO_ROOT, capture_output=True, text=True, check=False
        ).stdout.strip()

    commit = git("rev-parse", "--short=10", "HEAD") or "unknown"
    return commit + ("-dirty" if git("status", "--porcelain", "--untracked-files=no") else "")


def wall_figure(wall_s: float, full: bool) -> Figure:
    """The whole run's wall time (set-up apart): against `BENCH_TARGET_S` in `make bench`, an
    `info` figure in `make bench-full`.
    """
    if full:
        return info("make bench-full: wall time of the benchmarks", wall_s / 60, "min")
    return compare(
        "make bench: wall time of the benchmarks (set-up apart)",
        wall_s / 60,
        "min",
        "<=",
        BENCH_TARGET_S / 60,
        f"the parts' budgets add up to {sum(p.budget_s for p in PARTS) / 60:.1f} min",
    )


def results_document(
    mode: str,
    figures_by_part: list[tuple[str, list[Figure]]],
    times: list[tuple[Part, float, bool]],
    wall_s: float,
    full: bool,
) -> dict:
    """The results file's content: where and when it ran, every part's time, every figure."""
    now = dt.datetime.now(dt.UTC)
    return {
        "schema": RESULTS_SCHEMA,
        "mode": mode,
        "commit": git_commit(),
        "date": now.date().isoformat(),
        "finished_utc": now.isoformat(timespec="seconds"),
        "machine": {
            "cores": os.cpu_count(),
            "cpu_model": cpu_model(),
            "python": platform.python_version(),
            # other work on the machine while it ran (1-minute load average at the end)
            "load_average_end": round(os.getloadavg()[0], 2),
        },
        "wall_s": round(wall_s, 1),
        "parts": [
            {
                "name": p.name,
                "wall_s": round(t, 1),
                "budget_s": p.full_budget_s if full else p.budget_s,
                "ran": ran,
            }
            for p, t, ran in times
        ],
        "figures": [
            row | {"part": part}
            for part, figures in figures_by_part
            for row in figure_rows(figures)
        ],
    }


def results_path(document: dict, directory: Path = RESULTS_DIR) -> Path:
    """docs/results/<date>-<commit>.json (`-subset` for `make bench`)."""
    suffix = "" if document["mode"] == "make bench-full" else "-subset"
    return directory / f"{document['date']}-{document['commit']}{suffix}.json"


def comparisons_met(figures: list[Figure]) -> tuple[int, int]:
    """(comparisons met, comparisons): `info` figures are not counted."""
    verdicts = [f.met for f in figures if f.is_comparison]
    return sum(bool(v) for v in verdicts), len(verdicts)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, default=REPO_ROOT / "out" / "bench" / "bench.json")
    parser.add_argument(
        "--full", action="store_true", help="every family and draw (make bench-full)"
    )
    parser.add_argument("--only", nargs="*", help="run only these benchmarks")
    args = parser.parse_args()
    known = {p.name: p for p in PARTS}
    if unknown := [n for n in args.only or () if n not in known]:
        parser.error(f"unknown benchmark {', '.join(unknown)} (known: {', '.join(known)})")
    mode = "make bench-full" if args.full else "make bench"
    figures: list[Figure] = []
    by_part: list[tuple[str, list[Figure]]] = []
    failures: list[str] = []
    times: list[tuple[Part, float, bool]] = []
    start = time.monotonic()
    for part in [known[n] for n in args.only] if args.only else PARTS:
        got, took, ran = run_part(part, args.full, args.json.parent)
        figures += got
        by_part.append((part.name, got))
        times.append((part, took, ran))
        if not ran:
            failures.append(part.name)
    total = time.monotonic() - start
    if not args.only:
        wall = wall_figure(total, args.full)
        figures.append(wall)
        by_part.append(("run_all", [wall]))
    print()
    print_table(figures)
    write_json(figures, args.json)
    met, compared = comparisons_met(figures)
    print(
        f"\n{met} of {compared} comparisons met ({len(figures) - compared} info figures, not "
        f"counted); table in {args.json}"
    )
    if not args.only and not failures:
        document = results_document(mode, by_part, times, total, args.full)
        path = results_path(document)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(document, indent=1, allow_nan=False) + "\n")
        print(f"results file {path.relative_to(REPO_ROOT)} (README: python bench/results_table.py)")
    over = [
        f"{p.name} {t:.0f} s > {p.full_budget_s if args.full else p.budget_s:.0f} s"
        for p, t, _ in times
        if t > (p.full_budget_s if args.full else p.budget_s)
    ]
    if over:
        print(f"parts over their budget: {'; '.join(over)}")
    limit = "" if args.full or args.only else f" (target {BENCH_TARGET_S / 60:.0f} min)"
    print(f"{mode} took {total / 60:.1f} min wall{limit}")
    if failures:
        print(f"benchmarks that failed to run: {', '.join(failures)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
