# Two-command set-up (README.md, "Quick start"): `make demo` and `make test` on a machine with
# only Python 3.11 (+ pip, venv). Both create .venv if missing and install what is missing:
#   $(DEPS_STAMP) third-party packages from requirements.txt (ROS wheels, numpy, ..., pytest), at the
#                 exact versions of constraints.txt (the lock: what the test suite last passed with;
#                 `make lock` refreshes it in a fresh venv, only if the whole suite passes there)
#   $(PKG_STAMP)  the package itself, `pip install .` (not editable: an editable install gets
#                 no data_files, so `ros2 run` could not see it), which also compiles the search
#                 kernel (setup.py); redone only when a file of the package changes or is
#                 added/removed.
# A second `make test` therefore installs nothing.

SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
.DEFAULT_GOAL := help

VENV ?= .venv
# The ROS wheels are built for CPython 3.11.
PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
BIN := $(VENV)/bin
DEPS_STAMP := $(VENV)/.stamp-deps
PKG_STAMP := $(VENV)/.stamp-package
SOURCE_LIST := $(VENV)/.package-files
PIP := $(BIN)/python -m pip --disable-pip-version-check

# Files that end up in the installed package (setup.py: packages, data_files).
PKG_SOURCES := setup.py setup.cfg package.xml $(sort $(shell find pomdp_planner config resource launch -type f \
	! -path '*/__pycache__/*' ! -name '*.pyc' 2>/dev/null))

# The list of those files is rewritten only when it changes, so that deleting or renaming a file
# (which makes no file newer than the stamp) reinstalls the package as well.
ifneq ($(wildcard $(VENV)/.),)
_ := $(shell printf '%s\n' $(PKG_SOURCES) > $(SOURCE_LIST).new; \
	cmp -s $(SOURCE_LIST).new $(SOURCE_LIST) && rm -f $(SOURCE_LIST).new || mv -f $(SOURCE_LIST).new $(SOURCE_LIST))
endif

# The lock. UNLOCKED=1 installs the newest versions requirements.txt allows instead (`make lock`).
CONSTRAINTS := constraints.txt
UNLOCKED ?=
LOCK_VENV := .venv-lock

# For the tests: wrong ROS message field types raise instead of serialising garbage, the
# installed-layout test fails (instead of skipping) when the package is not installed, and the
# kernel test fails when the compiled search kernel was not built (so the suite cannot silently
# test the numpy reference twice).
TEST_ENV := ROS_PYTHON_CHECK_FIELDS=1 POMDP_PLANNER_REQUIRE_INSTALLED=1 POMDP_PLANNER_REQUIRE_KERNEL=1 \
	$(if $(UNLOCKED),POMDP_PLANNER_UNLOCKED=1)
PYTEST_ARGS ?=

DEMO_ARGS ?=
DEMO_CMD := $(BIN)/python -m pomdp_planner.nodes.demo --steps 30 --model perimeter_s8 $(DEMO_ARGS)

.PHONY: help setup demo test lint clean experiments lock

help:
	@echo "make demo   set up .venv (if needed) and run the demo"
	@echo "make test   set up .venv (if needed), then ruff and the whole test suite"
	@echo "make lint   ruff only"
	@echo "make lock   refresh constraints.txt: the newest versions requirements.txt allows, in a fresh venv,"
	@echo "            written only if the whole test suite passes with them (long)"
	@echo "make experiments  regenerate docs/RESULTS.md and docs/img (long; EXPERIMENTS_ARGS=--quick for a smoke run)"
	@echo "make clean  remove .venv and build output"

setup: $(PKG_STAMP)

demo: $(PKG_STAMP)
	$(DEMO_CMD)

test: $(PKG_STAMP)
	$(BIN)/ruff check .
	$(TEST_ENV) $(BIN)/python -m pytest $(PYTEST_ARGS)

# The optional extras `experiments` (matplotlib) and `bench` (pomdp-py) of setup.py, then every
# experiment into docs/ (docs/benchmarks.md). matplotlib is also in requirements.txt (the smoke test).
EXPERIMENTS_EXTRAS := matplotlib pomdp-py
EXPERIMENTS_ARGS ?=

experiments: $(PKG_STAMP)
	$(PIP) install $(EXPERIMENTS_EXTRAS)
	$(BIN)/pomdp-planner bench all --output docs $(EXPERIMENTS_ARGS)

lint: $(DEPS_STAMP)
	$(BIN)/ruff check .

$(BIN)/python:
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' || \
		echo "warning: $(PYTHON) is not Python 3.11; the ROS 2 wheels are built for 3.11 only" >&2
	$(PYTHON) -m venv $(VENV) || { rm -rf $(VENV); \
		echo "error: cannot create $(VENV) (on Debian/Ubuntu: apt-get install python3.11-venv)" >&2; exit 1; }

$(DEPS_STAMP): requirements.txt $(CONSTRAINTS) | $(BIN)/python
	$(PIP) install -r requirements.txt $(if $(UNLOCKED),,-c $(CONSTRAINTS))
	touch $@

# The lock: a fresh venv with the newest versions requirements.txt allows, the whole suite in it,
# and only then its versions (`pip freeze`, without the package and pip) into constraints.txt.
lock:
	rm -rf $(LOCK_VENV)
	$(MAKE) VENV=$(LOCK_VENV) UNLOCKED=1 test
	$(LOCK_VENV)/bin/python -m pip freeze --all --exclude pomdp-planner --exclude pip | LC_ALL=C sort > $(CONSTRAINTS).new
	mv $(CONSTRAINTS).new $(CONSTRAINTS)
	rm -rf $(LOCK_VENV)

$(SOURCE_LIST): | $(BIN)/python
	printf '%s\n' $(PKG_SOURCES) > $@

# Built from a clean tree: a stale build/lib would put deleted modules back into the wheel.
$(PKG_STAMP): $(DEPS_STAMP) $(SOURCE_LIST) $(PKG_SOURCES)
	rm -rf build pomdp_planner.egg-info
	$(PIP) install --no-build-isolation .
	rm -rf build pomdp_planner.egg-info
	touch $@

clean:
	rm -rf $(VENV) $(LOCK_VENV) build install log dist pomdp_planner.egg-info .pytest_cache .ruff_cache .hypothesis
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
