"""`make bench`: run every benchmark of the project and print one table.

Each bench/bench_*.py runs in its own process (so one's numba compile or DDS graph does not
disturb another) and writes its figures as JSON; this collects them into one table, each
figure beside its target, its same-run baseline where one applies, and whether it is met,
and writes the table as JSON (--json).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from benchlib import REPO_ROOT, Figure, print_table, write_json

BENCHES = [
    "bench_sim",
    "bench_frontend_core",
    "bench_collision",
    "bench_health",
    "bench_analysis",
    "bench_recorder",
    "bench_closed_loop",
    "bench_discrepancy",
    "bench_stroke",
    "bench_sweep",
    "bench_bridge",
    "bench_import",
    "bench_lab_import",
    "bench_foxglove",
    "bench_stock_numpy",
    "bench_workspace",
]
# Extra arguments per benchmark: the discrepancy benchmark also runs the whole fixed hidden-effect
# dataset (45 cases; `make test` runs one case of each kind, tests/test_discrepancy.py).
EXTRA_ARGS = {"bench_discrepancy": ["--sweep"]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, default=REPO_ROOT / "out" / "bench" / "bench.json")
    parser.add_argument("--only", nargs="*", help="run only these benchmarks")
    args = parser.parse_args()
    figures: list[Figure] = []
    failures: list[str] = []
    out_dir = args.json.parent
    out_dir.mkdir(parents=True, exist_ok=True)
    for name in args.only or BENCHES:
        script = REPO_ROOT / "bench" / f"{name}.py"
        if not script.exists():
            print(f"[bench] {name}: not written yet")
            continue
        print(f"[bench] {name} ...", flush=True)
        start = time.monotonic()
        part = out_dir / f"{name}.json"
        result = subprocess.run(
            [sys.executable, str(script), "--json", str(part), *EXTRA_ARGS.get(name, [])],
            capture_output=True,
            text=True,
        )
        print(f"[bench] {name}: {time.monotonic() - start:.0f} s", flush=True)
        if result.returncode != 0 or not part.exists():
            failures.append(name)
            print(result.stdout[-2000:], result.stderr[-2000:], sep="\n")
            continue
        loaded = json.loads(part.read_text())
        entries = loaded if isinstance(loaded, list) else loaded.get("figures", [])
        for entry in entries:
            figures.append(
                Figure(
                    **{
                        k: entry[k]
                        for k in ("name", "value", "unit", "target", "met", "baseline")
                        if k in entry
                    }
                )
            )
    print()
    print_table(figures)
    write_json(figures, args.json)
    met = sum(f.met for f in figures)
    print(f"\n{met} of {len(figures)} figures meet their targets; table in {args.json}")
    if failures:
        print(f"benchmarks that failed to run: {', '.join(failures)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
