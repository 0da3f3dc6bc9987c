# FLAAIR: two commands for a newcomer, `make demo` and `make test`. Each first creates or
# refreshes the environment (scripts/setup_env.sh: idempotent, seconds when nothing changed).
SHELL := /bin/bash
.DEFAULT_GOAL := help
IN_ENV := scripts/in_env.sh

.PHONY: help setup demo test test-fast bench lock clean

help:
	@echo "make demo   set up, run every paper experiment on the simulated robot, write the report"
	@echo "make test   set up, run all tests (pure cores, nodes over real DDS, bags, faults)"
	@echo "make bench  set up, run every benchmark and print figures beside their targets"

setup:
	@scripts/setup_env.sh

demo: setup
	@bin/flaair demo --out out/demo

test: setup
	@$(IN_ENV) python -m pytest tests -q -p no:cacheprovider

test-fast: setup
	@$(IN_ENV) python -m pytest tests -q -p no:cacheprovider -m "not slow"

bench: setup
	@$(IN_ENV) python bench/run_all.py --json out/bench/bench.json

# Regenerate requirements.lock from requirements.in in a throwaway venv.
lock:
	@rm -rf /tmp/flaair-lock-venv && python3.11 -m venv /tmp/flaair-lock-venv
	@/tmp/flaair-lock-venv/bin/pip install -q -r requirements.in
	@/tmp/flaair-lock-venv/bin/python scripts/lock.py /tmp/flaair-lock-venv/bin/python > requirements.lock

clean:
	rm -rf build install log out .colcon
