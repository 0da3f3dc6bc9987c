#!/usr/bin/env bash
# `make bench`'s set-up beside the environment: what two benchmarks build on first use, each
# timed (minutes once per clone or machine, seconds when already there), so that the benchmark's
# wall time measures the benchmarks.
set -euo pipefail
cd "$(dirname "$0")/.."
for part in bench_ros2_conformance bench_stock_numpy; do
    start=$(date +%s)
    mkdir -p out/bench
    if ! python "bench/${part}.py" --prepare > "out/bench/${part}.prepare.log" 2>&1; then
        echo "bench set-up: ${part} --prepare failed (log: out/bench/${part}.prepare.log)" >&2
        tail -20 "out/bench/${part}.prepare.log" >&2
        exit 1
    fi
    echo "[bench set-up] ${part}: $(( $(date +%s) - start )) s"
done
