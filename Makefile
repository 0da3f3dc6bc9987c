# FLAAIR: two commands for a newcomer, `make demo` and `make test`. Each first creates or
# refreshes the environment (scripts/setup_env.sh: idempotent, seconds when nothing changed).
SHELL := /bin/bash
.DEFAULT_GOAL := help
IN_ENV := scripts/in_env.sh

.PHONY: help setup bench-setup demo test test-quick test-graph-soak bench bench-full lock clean

help:
	@echo "make demo   set up, run every paper experiment on the simulated robot, write the report"
	@echo "make test   set up, run all tests (pure cores, nodes over real DDS, bags, faults)"
	@echo "make test-quick  the edit-test loop: no graph and no slow tests, in parallel (< 2 min)"
	@echo "make test-graph-soak RUNS=20  the graph tests RUNS times in a row with every core loaded"
	@echo "make bench  set up, run every benchmark and print figures beside their targets; the"
	@echo "            discrepancy families on a fixed subset of robots (<= 20 min on 2 cores)"
	@echo "make bench-full  the same with every discrepancy family and draw (about 75 min)"
	@echo "make bench-setup what two benchmarks build on first use (both benches run it first)"

setup:
	@scripts/setup_env.sh

demo: setup
	@bin/flaair demo --out out/demo

# Pure and CLI tests in parallel, then the graph tests a module per core (scripts/run_tests.sh).
test: setup
	@$(IN_ENV) scripts/run_tests.sh full

test-quick: setup
	@$(IN_ENV) scripts/run_tests.sh quick

# The graph tests N times in a row while another job loads every core (scripts/soak_graph_tests.sh).
test-graph-soak: setup
	@$(IN_ENV) scripts/soak_graph_tests.sh $(or $(RUNS),20)

# What two benchmarks build on first use (the real ROS 2 tools, the stock Jazzy numerical stack):
# minutes once per clone or machine, seconds after, and not inside the benchmark's own time.
bench-setup: setup
	@$(IN_ENV) scripts/bench_setup.sh

# Every benchmark; the discrepancy benchmark on its fixed subset (docs/TESTING.md: which to run when).
bench: bench-setup
	@$(IN_ENV) python bench/run_all.py --json out/bench/bench.json

bench-full: bench-setup
	@$(IN_ENV) python bench/run_all.py --full --json out/bench/bench-full.json

# Regenerate requirements.lock from requirements.in in a throwaway venv.
lock:
	@rm -rf /tmp/flaair-lock-venv && python3.11 -m venv /tmp/flaair-lock-venv
	@/tmp/flaair-lock-venv/bin/pip install -q -r requirements.in
	@/tmp/flaair-lock-venv/bin/python scripts/lock.py /tmp/flaair-lock-venv/bin/python > requirements.lock

clean:
	rm -rf build install log out .colcon
