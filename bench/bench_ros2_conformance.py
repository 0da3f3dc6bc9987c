"""The real ROS 2 tools against FLAAIR: tests/test_ros2_conformance.py (`ros2 launch` parses
every launch file and runs the namespaced loop; each stand-in answers as the real command on the
same graph). Target: every test passes. Reported: the upstream install's time (minutes on a fresh
machine; an instant once .cache/ros2-upstream is complete) and the tests' wall time.

Run: scripts/in_env.sh python bench/bench_ros2_conformance.py [--json out.json]
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import time
from pathlib import Path

from benchlib import REPO_ROOT, compare, info, passed_pct, print_table, pytest_counts, write_json

INSTALL = REPO_ROOT.parent / "shared" / "ros2-upstream" / "install.sh"
PREFIX = REPO_ROOT / ".cache" / "ros2-upstream"
TESTS = "tests/test_ros2_conformance.py"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path)
    parser.add_argument(
        "--prepare",
        action="store_true",
        help="only build the upstream tools into .cache/ros2-upstream (make bench's set-up: the "
        "minutes a first build takes are paid once, not inside the benchmark's time)",
    )
    args = parser.parse_args()
    if not INSTALL.is_file():
        print(f"[bench] no {INSTALL}: the real ROS 2 tools cannot be built here; nothing measured")
        return
    if args.prepare:
        built = subprocess.run(["bash", str(INSTALL), str(PREFIX)], cwd=REPO_ROOT)
        raise SystemExit(built.returncode)
    cached = (PREFIX / "env.sh").is_file()
    start = time.monotonic()
    built = subprocess.run(
        ["bash", str(INSTALL), str(PREFIX)], cwd=REPO_ROOT, capture_output=True, text=True
    )
    install_s = time.monotonic() - start
    start = time.monotonic()
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:xdist",
            "-s",
            "-rfE",  # the summary names each failed test: the figure's baseline carries them
            "-m",
            "ros2_upstream",
            TESTS,
        ],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
    )
    took_s = time.monotonic() - start
    passed, failed = pytest_counts(result.stdout)
    if result.returncode != 0 or built.returncode != 0:
        print(built.stderr[-2000:], result.stdout[-4000:], result.stderr[-2000:], sep="\n")
    tries = m.group(1) if (m := re.search(r"tries: (\[.*\])", result.stdout)) else "?"
    failed_names = re.findall(r"^(?:FAILED|ERROR) \S+::(\S+)", result.stdout, re.MULTILINE)
    # the first failure's own words (pytest's "E   " lines), for the figure's baseline
    why = next(iter(re.findall(r"^E +(.+)$", result.stdout, re.MULTILINE)), "")
    # each stand-in's answer against the real command's (the test prints one line each)
    for found in re.finditer(r"(?:same|DIFFERENT): .*", result.stdout):
        print(f"[bench] {found.group(0)[:160]}")
    figures = [
        compare(
            "real ROS 2 tools vs FLAAIR: tests passed",
            passed_pct(passed, failed, result.returncode == 0),
            "% of tests",
            ">=",
            100.0,
            f"{passed} passed, {failed} failed (pytest exit code {result.returncode})"
            + (f": {', '.join(failed_names)}" if failed_names else "")
            + (f" ({why[:200]})" if why else "")
            + f"; real lists' tries until the whole graph was seen: {tries}",
        ),
        compare(
            "upstream tools install (install.sh): exit code",
            built.returncode,
            "",
            "==",
            0,
            ("already in .cache/ros2-upstream" if cached else "built from ../shared sources")
            + f" in {install_s:.1f} s",
        ),
        info(
            "upstream tools install (install.sh)",
            round(install_s, 1),
            "s",
            "already in .cache/ros2-upstream" if cached else "built from ../shared sources",
        ),
        info("conformance tests: wall time", round(took_s, 1), "s"),
    ]
    print_table(figures)
    if args.json:
        write_json(figures, args.json)


if __name__ == "__main__":
    main()
