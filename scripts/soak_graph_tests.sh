#!/usr/bin/env bash
# The graph tests RUNS times in a row (default 20) while scripts/cpu_load.py keeps every core busy:
# the reliability check of the end-to-end tests. Prints each run's result and "K of RUNS runs
# passed"; exit 0 only if every run passed. Logs: out/soak/run_N.txt; a failed run keeps its
# temporary files (bags, node logs) in out/soak/tmp_run_N.
# Usage (inside the environment, or `make test-graph-soak RUNS=N`): scripts/soak_graph_tests.sh [RUNS]
set -uo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
RUNS="${1:-20}"
mkdir -p out/soak
python scripts/cpu_load.py --duration 86400 &
LOAD=$!
trap 'kill "$LOAD" 2>/dev/null; wait "$LOAD" 2>/dev/null' EXIT
passed=0
for run in $(seq 1 "$RUNS"); do
  start=$(date +%s)
  # each run's temporary files (bags, node logs) kept while it runs, and afterwards if it failed
  tmp="out/soak/tmp_run_$run"
  rm -rf "$tmp"
  if python -m pytest tests -q -p no:xdist -m "graph and not ros2_upstream" --basetemp "$tmp" > "out/soak/run_$run.txt" 2>&1; then
    passed=$((passed + 1)); verdict=passed; rm -rf "$tmp"
  else
    verdict="FAILED ($(grep -E '^(FAILED|ERROR) ' "out/soak/run_$run.txt" | cut -c1-160 | tr '\n' ';'))"
  fi
  echo "run $run: $verdict in $(( $(date +%s) - start )) s, load average $(cut -d' ' -f1 /proc/loadavg)"
done
echo "$passed of $RUNS runs passed"
[ "$passed" -eq "$RUNS" ]
