"""A lab's ROS 2 workspace: the `workspace` tests (tests/test_workspace_build.py) build src/ with a
plain `colcon build` into a throwaway workspace and start a node from that install tree, outside
the source tree. Target: every one passes. Baseline: the time of this checkout's own setup check
(scripts/setup_env.sh with nothing to rebuild) in the same run.

Run: scripts/in_env.sh python bench/bench_workspace.py [--json out.json]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

from benchlib import REPO_ROOT, compare, info, passed_pct, print_table, pytest_counts, write_json


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    start = time.monotonic()
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:xdist",
            "-m",
            "workspace",
            "tests/test_workspace_build.py",
        ],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
    )
    took_s = time.monotonic() - start
    passed, failed = pytest_counts(result.stdout)
    if result.returncode != 0:
        print(result.stdout[-3000:], result.stderr[-2000:], sep="\n")
    start = time.monotonic()
    subprocess.run([str(REPO_ROOT / "scripts" / "setup_env.sh")], capture_output=True)
    setup_s = time.monotonic() - start
    figures = [
        compare(
            "plain colcon build + a node from its install tree: tests passed",
            passed_pct(passed, failed, result.returncode == 0),
            "% of tests",
            ">=",
            100.0,
            f"{passed} passed, {failed} failed (pytest exit code {result.returncode})",
        ),
        info(
            "plain colcon build + node start: wall time",
            round(took_s, 1),
            "s",
            f"setup check with nothing to rebuild: {setup_s:.1f} s",
        ),
    ]
    print_table(figures)
    if args.json:
        write_json(figures, args.json)


if __name__ == "__main__":
    main()
