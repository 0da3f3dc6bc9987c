#!/usr/bin/env bash
# Run FLAAIR's tests in two phases and print one summary line for both:
#   1. every test not marked `graph` (pure cores, CLIs, files): in parallel on every core (xdist);
#   2. the `graph` tests (ROS 2 processes exchanging data in real time): one at a time, alone on
#      the machine, so a DDS graph never shares the cores with a model fit.
# Usage: scripts/run_tests.sh [full|quick] [extra pytest args...]
#   full   (make test)       everything but `workspace` (a plain colcon build) and `ros2_upstream`
#                            (the real ROS 2 tools against FLAAIR): `make bench` runs those
#   quick  (make test-quick) neither `graph` nor `slow`: the edit-test loop, in parallel only
# Run inside the environment (scripts/in_env.sh). Exit status: non-zero if any phase failed.
set -uo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
MODE="${1:-full}"; shift || true
WORKERS="${FLAAIR_TEST_WORKERS:-$(nproc)}"
REPORTS="$(mktemp -d)"
trap 'rm -rf "$REPORTS"' EXIT

# One BLAS/OpenMP thread per xdist worker: the workers already fill the cores, and a multithreaded
# numpy in each of them only makes them wait for each other.
export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}" OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}" \
       MKL_NUM_THREADS="${MKL_NUM_THREADS:-1}" NUMBA_NUM_THREADS="${NUMBA_NUM_THREADS:-1}"

status=0
phase() {   # phase NAME PYTEST_ARGS...
  local name="$1"; shift
  echo "== $name"
  # --durations: each phase ends with its slowest tests, to see where the time goes
  python -m pytest tests -q --durations=12 --junitxml="$REPORTS/$name.xml" "$@"
  local rc=$?
  # pytest exits 5 when a phase selects no test (e.g. -k matching only the other phase)
  if [ "$rc" -ne 0 ] && [ "$rc" -ne 5 ]; then status=1; fi
}

case "$MODE" in
  full)
    phase parallel -n "$WORKERS" --dist load -m "not graph and not workspace and not ros2_upstream" "$@"
    phase graph -p no:xdist -m "graph and not ros2_upstream" "$@"
    ;;
  quick)
    phase quick -n "$WORKERS" --dist load \
      -m "not graph and not slow and not workspace and not ros2_upstream" "$@"
    ;;
  *) echo "usage: scripts/run_tests.sh [full|quick] [pytest args...]" >&2; exit 2 ;;
esac

# One closing line for all phases, counted from pytest's own JUnit reports.
python - "$REPORTS" <<'PY'
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

totals = dict(tests=0, failures=0, errors=0, skipped=0)
for report in sorted(Path(sys.argv[1]).glob("*.xml")):
    for suite in ET.parse(report).getroot().iter("testsuite"):
        for key in totals:
            totals[key] += int(suite.get(key, 0))
failed = totals["failures"] + totals["errors"]
passed = totals["tests"] - failed - totals["skipped"]
print(f"{passed} passed, {failed} failed, {totals['skipped']} skipped")
PY
exit "$status"
