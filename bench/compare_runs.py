"""Compare two benchmark tables (`make bench` against `make bench-full`, or two commits).

Figures are matched by name with the count in parentheses removed, so that
`exact-set accuracy, offnominal_single (9/9 robots, subset)` meets
`exact-set accuracy, offnominal_single (29/30 robots)`. Prints the figures whose value moved by
more than `--rel` (relative) or whose verdict against the target changed, then those found in
only one table. Usage:

    python bench/compare_runs.py out/bench/bench.json out/bench/bench-full.json
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path
from typing import Any

_COUNT = re.compile(r"\s*\((\d+)/(\d+)[^)]*\)|\s*\(max of \d+[^)]*\)")


def figure_key(name: str) -> str:
    """A figure's name without its robot/case count: the same figure in either mode."""
    return _COUNT.sub("", name).strip()


def load_table(path: Path) -> dict[str, dict[str, Any]]:
    """A bench table (run_all.py --json) as {key: row}; refuses what is not one, by name."""
    try:
        rows = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a readable benchmark table ({exc})") from None
    if not isinstance(rows, list) or not all(isinstance(r, dict) and "name" in r for r in rows):
        raise ValueError(f"{path}: not a benchmark table (a JSON list of figures with 'name')")
    return {figure_key(r["name"]): r for r in rows}


def moved(a: dict[str, Any], b: dict[str, Any], rel: float) -> bool:
    """Whether a figure's value moved by more than `rel` or its verdict changed."""
    if a.get("met") != b.get("met"):
        return True
    va, vb = a.get("value"), b.get("value")
    if not isinstance(va, (int, float)) or not isinstance(vb, (int, float)):
        return va != vb
    scale = max(abs(va), abs(vb))
    return scale > 0 and math.isfinite(scale) and abs(va - vb) > rel * scale


def compare(
    first: dict[str, dict[str, Any]], second: dict[str, dict[str, Any]], rel: float
) -> list[str]:
    """Lines describing what differs between two tables."""

    def show(row: dict[str, Any]) -> str:
        verdict = "met" if row.get("met") else "NOT met"
        return f"{row.get('value')} {row.get('unit', '')} ({verdict}; {row['name']})"

    lines = [
        f"{key}: {show(first[key])} -> {show(second[key])}"
        for key in first
        if key in second and moved(first[key], second[key], rel)
    ]
    lines += [f"only in the first: {first[k]['name']}" for k in first if k not in second]
    lines += [f"only in the second: {second[k]['name']}" for k in second if k not in first]
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("first", type=Path, help="a bench table, e.g. out/bench/bench.json")
    parser.add_argument("second", type=Path, help="e.g. out/bench/bench-full.json")
    parser.add_argument(
        "--rel", type=float, default=0.05, help="relative change reported (default 0.05)"
    )
    args = parser.parse_args(argv)
    try:
        first, second = load_table(args.first), load_table(args.second)
    except ValueError as exc:
        print(f"compare_runs: {exc}", file=sys.stderr)
        return 2
    lines = compare(first, second, args.rel)
    common = sum(k in second for k in first)
    print(f"{common} figures in both; {len(lines)} moved by > {args.rel:.0%} or differ:")
    print("\n".join(lines) if lines else "none")
    return 0


if __name__ == "__main__":
    sys.exit(main())
