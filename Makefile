# Two commands for a new user: `make demo` and `make test`. Each creates or refreshes .venv first
# (fast when nothing changed); `make lint` is what CI checks besides the tests. ROS 2 Jazzy's PyPI wheels need CPython 3.12.
SHELL := /bin/bash
VENV := .venv
STAMP := $(VENV)/.installed
PYTHON312 := $(shell for c in python3.12 $$HOME/.pyenv/versions/3.12*/bin/python3.12 /usr/bin/python3.12 /usr/local/bin/python3.12; do \
	$$c -c 'import sys; assert sys.version_info[:2] == (3, 12)' >/dev/null 2>&1 && { echo $$c; break; }; done)
# Keep DDS on this machine and away from other runs.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export ROS_DOMAIN_ID ?= 42

.PHONY: venv test demo lint clean

venv: $(STAMP)

$(STAMP): requirements.txt setup.py setup.cfg
	@test -n "$(PYTHON312)" || { echo "ERROR: Python 3.12 not found (ROS 2 Jazzy wheels need it): install it, e.g. 'pyenv install 3.12'" >&2; exit 1; }
	@test -x $(VENV)/bin/python || $(PYTHON312) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --quiet --upgrade pip
	$(VENV)/bin/python -m pip install --quiet -r requirements.txt
	$(VENV)/bin/python -m pip install --quiet --no-deps --no-build-isolation -e .
	@touch $@

# Two workers, each test file on one of them (its module fixtures start its nodes once); each worker
# has a ROS domain id of its own (test/conftest.py), so their DDS traffic never mixes.
test: venv
	$(VENV)/bin/python -m pytest -q -n 2 --dist loadfile test

demo: venv
	$(VENV)/bin/stereo-depth demo

# Style and types, as CI checks them: any finding fails. Tests and bench call into rclpy's partly
# unannotated API, so there (and only there) untyped calls are allowed.
LINTED := stereo_depth test bench launch
lint: venv
	$(VENV)/bin/ruff check $(LINTED)
	$(VENV)/bin/ruff format --check $(LINTED)
	$(VENV)/bin/mypy stereo_depth
	$(VENV)/bin/mypy --allow-untyped-calls test bench

clean:
	rm -rf $(VENV) build install log out
