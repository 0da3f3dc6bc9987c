"""The in-process tests on the numerical stack a stock ROS 2 Jazzy install has (Ubuntu 24.04).

A lab that builds FLAAIR in its own Jazzy workspace runs it on the distribution's numpy 1.26,
scipy 1.11 and numba 0.59, not on requirements.lock's. This builds a throwaway environment with
those versions (bench/stock_jazzy.txt) layered over the project's .venv for everything else,
runs the in-process tests of the cores, files and tools on it, and, as the same-run baseline,
the same tests on the locked stack, both at once (one pytest process each, a core each on the
2-core machine). Target: every test passes on both.

Run: scripts/in_env.sh python bench/bench_stock_numpy.py [--json out.json]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import sysconfig
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from benchlib import REPO_ROOT, compare, passed_pct, print_table, pytest_counts, write_json

PINS = REPO_ROOT / "bench" / "stock_jazzy.txt"
VENV = REPO_ROOT / "out" / "bench" / "stock-jazzy-venv"
# In-process tests: they run in the interpreter under test (a test that starts bin/flaair would
# run the project's own .venv instead, and a graph test measures nothing about numpy).
TESTS = [
    "test_sim_plant.py",
    "test_sim_model.py",
    "test_sim_actuator.py",
    "test_sim_drive.py",
    "test_sensors_frontend.py",
    "test_sensors_calibration.py",
    "test_sensors_characterization.py",
    "test_control_collision.py",
    "test_control_dsa.py",
    "test_control_hopf.py",
    "test_control_safety.py",
    "test_control_stroke.py",
    "test_control_transition.py",
    "test_cdr.py",
    "test_cdr_layouts.py",
    "test_lfilter_kernels.py",
    "test_wingbeat.py",
    "test_effect_table.py",
    "test_model_per_channel.py",
    "test_bag_io.py",
    "test_runcsv.py",
    "test_bridge_core.py",
    "test_bridge_protocol.py",
    "test_core_properties.py",
    "test_identify.py",
    "test_composed_loop.py",
    "test_diagnostics.py",
]


def stock_python() -> Path:
    """The throwaway interpreter: the stock pins first on its path, then the project's .venv."""
    python = VENV / "bin" / "python"
    stamp = VENV / ".pins"
    if not (python.exists() and stamp.exists() and stamp.read_text() == PINS.read_text()):
        subprocess.run([sys.executable, "-m", "venv", "--clear", str(VENV)], check=True)
        subprocess.run(
            [
                str(python),
                "-m",
                "pip",
                "install",
                "--quiet",
                "--no-deps",
                "--disable-pip-version-check",
                "-r",
                str(PINS),
            ],
            check=True,
        )
        site = subprocess.run(
            [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
            capture_output=True,
            text=True,
            check=True,
        )
        project_site = sysconfig.get_paths()["purelib"]
        (Path(site.stdout.strip()) / "zz_flaair_project_venv.pth").write_text(
            f"import site; site.addsitedir({project_site!r})\n"
        )
        stamp.write_text(PINS.read_text())
    return python


def _env(numba_cache: Path) -> dict[str, str]:
    """The environment either interpreter runs in: its own numba cache, one BLAS thread, the ROS
    wheels' bundled libraries (their start-up hook finds them only in its own prefix).
    """
    env = dict(
        os.environ,
        NUMBA_CACHE_DIR=str(numba_cache),
        OPENBLAS_NUM_THREADS="1",
        _ROS_WHEELS_BOOTSTRAP_COMPLETE="1",
    )
    project_site = Path(sysconfig.get_paths()["purelib"])
    libs = [str(p) for p in sorted(project_site.glob("ros_*.libs"))] + [
        str(Path(sys.prefix) / "lib")
    ]
    env["LD_LIBRARY_PATH"] = os.pathsep.join([*libs, env.get("LD_LIBRARY_PATH", "")])
    return env


def warm_caches(python: Path, numba_cache: Path) -> None:
    """Compile every kernel `scripts/warm_numba.py` names into `numba_cache` under `python` (a
    first use's compile, paid in make bench's set-up, not inside the benchmark's time).
    """
    subprocess.run(
        [str(python), str(REPO_ROOT / "scripts" / "warm_numba.py")],
        cwd=REPO_ROOT,
        env=_env(numba_cache),
        check=True,
        capture_output=True,
    )


def run_tests(python: Path, numba_cache: Path) -> tuple[int, int, str, int]:
    """(passed, failed, versions line, pytest's exit code) of TESTS under `python`."""
    env = _env(numba_cache)
    versions = subprocess.run(
        [
            str(python),
            "-c",
            "import numpy, scipy, numba; print("
            "f'numpy {numpy.__version__}, scipy {scipy.__version__}, "
            "numba {numba.__version__}')",
        ],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    done = subprocess.run(
        [
            str(python),
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:xdist",
            "-p",
            "no:cacheprovider",
            "-m",
            "not graph and not slow",
            *[f"tests/{t}" for t in TESTS],
        ],
        cwd=REPO_ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=3600,
    )
    passed, failed = pytest_counts(done.stdout)
    if done.returncode not in (0, 1):
        print(done.stdout[-3000:], done.stderr[-3000:], sep="\n")
    return passed, failed, versions, done.returncode


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path)
    parser.add_argument(
        "--prepare",
        action="store_true",
        help="only build the stock stack's environment and compile both stacks' kernels into "
        "their caches (make bench's set-up: paid once, not inside the benchmark's time)",
    )
    args = parser.parse_args()
    caches = REPO_ROOT / "out" / "bench" / "numba-cache"
    if args.prepare:
        stock_stack = stock_python()
        with ThreadPoolExecutor(max_workers=2) as pool:
            for done in [
                pool.submit(warm_caches, stock_stack, caches / "stock"),
                pool.submit(warm_caches, Path(sys.executable), caches / "locked"),
            ]:
                done.result()
        return
    stock_stack = stock_python()
    with ThreadPoolExecutor(max_workers=2) as pool:
        stock_run = pool.submit(run_tests, stock_stack, caches / "stock")
        locked_run = pool.submit(run_tests, Path(sys.executable), caches / "locked")
        stock, locked = stock_run.result(), locked_run.result()
    figures = [
        compare(
            f"in-process tests on a stock Jazzy stack ({stock[2]})",
            passed_pct(stock[0], stock[1], stock[3] == 0),
            "% passed",
            ">=",
            100.0,
            f"{stock[0]} passed, {stock[1]} failed (exit code {stock[3]}); locked stack "
            f"({locked[2]}): {locked[0]} passed, {locked[1]} failed",
        )
    ]
    print_table(figures)
    if args.json:
        write_json(figures, args.json)


if __name__ == "__main__":
    main()
