# cnfmp: the README's commands. `make setup` is idempotent; `make test` and `make demo` run it
# first, so each works on a fresh machine on its own.
SHELL := /bin/bash
.DEFAULT_GOAL := help

VENV      := .venv
PYTHON    := $(VENV)/bin/python
CNFMP     := target/release/cnfmp
# Tests and CI run torch on one thread (facts.md: spin-waiting OpenMP threads on 2 cores).
export OMP_NUM_THREADS ?= 1
export CARGO_TERM_COLOR ?= never

.PHONY: help setup setup-system setup-venv build demo test test-rust test-python bench table1 models lock clean

help:  ## list the targets
	@grep -E '^[a-z0-9-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-13s %s\n", $$1, $$2}'

setup: setup-system setup-venv build  ## install Debian packages, the Python venv and build cnfmp (idempotent)

setup-system:  ## Debian packages for MuJoCo rendering (EGL/Mesa, OSMesa)
	@bash scripts/setup-system.sh

setup-venv:  ## the Python venv (.venv, on a base venv cached by the lock's hash)
	@bash scripts/setup-venv.sh

build: setup-venv  ## release build of the cnfmp binary
	cargo build --release --locked --workspace

demo: setup  ## the main job: serve the shipped models, send a held-out scene over HTTP, execute the answer
	$(CNFMP) demo

test: setup test-rust test-python  ## every test: cargo test --workspace, then pytest

test-rust:
	cargo test --release --locked --workspace

test-python:
	$(PYTHON) -m pytest -q

bench: setup  ## benchmarks that print figures (see docs/benchmarks.md)
	bash scripts/bench-sim.sh
	bash scripts/bench-core.sh
	bash scripts/bench-segmenter.sh
	bash scripts/bench-serve.sh
	bash scripts/bench-convert.sh
	bash scripts/bench-setup.sh
	bash scripts/bench-startup.sh
	bash scripts/bench-joint-space.sh

table1: setup  ## the paper's Table I on our benchmark: every method trained and evaluated (~1 h on 2 cores)
	$(CNFMP) benchmark table1 --out reports

models: setup  ## retrain the shipped core models under models/ (scripts/train-models.sh)
	bash scripts/train-models.sh

lock:  ## re-resolve requirements.lock from pyproject.toml (then run make setup)
	bash scripts/lock.sh

clean:  ## remove build outputs and the clone's .venv (the cached base venv stays)
	cargo clean
	rm -rf $(VENV) build python/*.egg-info
