# Set-up and entry points. Every target creates .venv if missing and installs what it needs.
#   make test                       lint + format check + the whole pytest suite
#   make demo                       the built-in demo on the CPU
#   make bench                      renderer, SLAM and bag benchmarks (append to BENCHMARKS.md)
#   make test TORCH_REQ='torch'     choose another torch requirement (default: local CPU build)

PYTHON ?= python3
VENV ?= .venv
TORCH_REQ ?= torch==2.13.0
PY := $(VENV)/bin/python
STAMP := $(VENV)/.sgs-slam-installed

export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: setup test lint demo bench bench-render bench-slam bench-bags clean

setup: $(STAMP)

$(STAMP): setup.py setup.cfg Makefile
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet "$(TORCH_REQ)"
	$(PY) -m pip install --quiet "ros-jazzy-rclpy[fastrtps]" ros-jazzy-common-interfaces
	$(PY) -m pip install --quiet -e ".[test]"
	touch $(STAMP)

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

test: lint
	$(PY) -m pytest

demo: setup
	$(VENV)/bin/sgs-slam demo

bench: bench-render bench-slam bench-bags

bench-render: setup
	$(PY) bench/bench_render.py

bench-slam: setup
	$(PY) bench/bench_slam.py --profile 10

bench-bags: setup
	$(PY) bench/bench_bags.py

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache
