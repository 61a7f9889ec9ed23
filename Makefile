# Two commands for a new user: `make demo` and `make test`. Each creates or refreshes .venv first
# (fast when nothing changed); `make lint` is what CI checks besides the tests. ROS 2 Jazzy's PyPI wheels need CPython 3.12.
SHELL := /bin/bash
VENV := .venv
STAMP := $(VENV)/.installed
MIN_VENV := .venv-min
PYTHON312 := $(shell for c in python3.12 $$HOME/.pyenv/versions/3.12*/bin/python3.12 /usr/bin/python3.12 /usr/local/bin/python3.12; do \
	$$c -c 'import sys; assert sys.version_info[:2] == (3, 12)' >/dev/null 2>&1 && { echo $$c; break; }; done)
# Keep DDS on this machine and away from other runs.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export ROS_DOMAIN_ID ?= 42

.PHONY: venv compile compile-min test test-min demo lint lock bench-docs clean

venv: $(STAMP)

# A venv holds exactly one lock file's versions (every package pinned, nothing resolved on the way), so a
# fresh machine runs what CI ran; tools/check_lock.py fails the install if the venv disagrees with it.
# --no-compile: a module's bytecode is written when it is first imported, not for all ~1 GB at install.
define install_locked
	@test -n "$(PYTHON312)" || { echo "ERROR: Python 3.12 not found (ROS 2 Jazzy wheels need it): install it, e.g. 'pyenv install 3.12'" >&2; exit 1; }
	@test -x $(1)/bin/python || $(PYTHON312) -m venv $(1)
	$(1)/bin/python -m pip install --quiet --no-deps --no-compile -r $(2)
	$(1)/bin/python -m pip install --quiet --no-deps --no-build-isolation -e .
	$(1)/bin/python tools/check_lock.py $(2)
	@touch $(1)/.installed
endef

$(STAMP): requirements.lock setup.py setup.cfg tools/check_lock.py
	$(call install_locked,$(VENV),requirements.lock)

$(MIN_VENV)/.installed: requirements-min.lock setup.py setup.cfg tools/check_lock.py
	$(call install_locked,$(MIN_VENV),requirements-min.lock)

# Re-resolve both locks from the ranges (requirements*.txt), for CPython 3.12 on Linux x86_64: the newest
# versions for requirements.lock; the oldest that requirements.txt allows for requirements-min.lock (test
# tools as in requirements.lock). Run `make test` and `make test-min` before committing new locks.
UV_COMPILE := $(VENV)/bin/uv pip compile --quiet --upgrade --python-version 3.12 \
	--python-platform x86_64-manylinux_2_28 --custom-compile-command "make lock"
$(VENV)/bin/uv:  # only when there is no venv yet (the lock's own venv has uv)
	@test -x $(VENV)/bin/python || $(PYTHON312) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --quiet uv

lock: $(VENV)/bin/uv
	$(UV_COMPILE) requirements-dev.txt -o requirements.lock
	grep -iE "^($$(sed -nE 's/^([A-Za-z0-9_.-]+).*/\1/p' requirements-test.txt | paste -sd'|'))==" requirements.lock \
		> $(VENV)/test-tool-pins.txt
	$(UV_COMPILE) --resolution lowest-direct -c $(VENV)/test-tool-pins.txt requirements.txt requirements-test.txt \
		-o requirements-min.lock

# numba's machine code (census core, temporal filter, RVL codec), built once (a minute or two the first
# time, a second once cached) before the test workers start: else each worker would build it.
compile: venv
	$(VENV)/bin/stereo-depth compile

# Three workers, each test file on one of them (its module fixtures start its nodes once); each worker
# has a ROS domain id of its own (test/conftest.py), so their DDS traffic never mixes. Three on two cores:
# a worker spends much of its time waiting for nodes to start and for DDS, and a third fills that time
# (the suite in 207 s against 260 s with two, one after the other on a 2-core Zen 1, 2026-12-03).
TEST_WORKERS := -n 3 --dist loadfile
test: compile
	$(VENV)/bin/python -m pytest -q $(TEST_WORKERS) test

# The oldest versions requirements.txt claims (OpenCV 4.6, numpy 1.26, numba, rosbags, mcap at their lower
# bounds; requirements-min.lock): what an Ubuntu 24.04 / rosdep user has. Every test file but those that
# need a tool only requirements-dev.txt installs (colcon); docs/development.md lists them and why.
MIN_SKIPPED := package
MIN_TESTS := $(filter-out $(MIN_SKIPPED:%=test/test_%.py),$(wildcard test/test_*.py))
# Its numba keeps a cache of its own: one beside the sources is rewritten by whichever numba compiled last.
MIN_NUMBA := NUMBA_CACHE_DIR=$(MIN_VENV)/numba-cache
compile-min: $(MIN_VENV)/.installed
	$(MIN_NUMBA) $(MIN_VENV)/bin/stereo-depth compile

test-min: compile-min
	$(MIN_NUMBA) $(MIN_VENV)/bin/python -m pytest -q $(TEST_WORKERS) $(MIN_TESTS)

demo: venv
	$(VENV)/bin/stereo-depth demo

# Style and types, as CI checks them: any finding fails. Tests and bench call into rclpy's partly
# unannotated API, so there (and only there) untyped calls are allowed.
LINTED := stereo_depth test bench launch tools
lint: venv
	$(VENV)/bin/ruff check $(LINTED)
	$(VENV)/bin/ruff format --check $(LINTED)
	$(VENV)/bin/mypy stereo_depth
	$(VENV)/bin/mypy --allow-untyped-calls test bench tools

# docs/performance.md and the README's performance-at-a-glance table, remeasured in one run under the CPU
# lock (bench/performance_docs.py; progress on stderr). ARGS="--quick" checks that it works; ARGS="--anchor DIR
# --data DIR" adds the rows that need the ROS 1 C++ anchor and the Middlebury/KITTI scenes (left out without
# them); ARGS="--simd avx2" or "--simd 128" measures another SIMD level on this machine.
bench-docs: compile
	$(VENV)/bin/python bench/performance_docs.py $(ARGS)

clean:
	rm -rf $(VENV) $(MIN_VENV) build install log out
