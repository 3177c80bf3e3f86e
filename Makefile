# train_calib: set-up, demo, tests and benchmarks from a fresh clone.
#
#   make demo    create .venv, install, build the messages, replay the bundled bag, print the result
#   make test    the same set-up, then the whole test suite
#   make bench   benchmarks (bench/), results in bench/RESULTS.md; never part of make test
#   make validate  validation family + external runs scored (bench/validation/), PRESET=name for a preset
#   make lint    ruff
#   make clean   remove .venv and build/
#
# Every step is guarded by a stamp file, so a second `make test` installs nothing.

SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
.DEFAULT_GOAL := help

PYTHON ?= python3.11
VENV := .venv
VPY := $(VENV)/bin/python
PIP := $(VPY) -m pip --disable-pip-version-check
ABS_VENV = $(abspath $(VENV))
MSG_BUILD := build/msg_defs

STAMP_DEPS := $(VENV)/.stamp-deps
STAMP_MSGS := $(VENV)/.stamp-msgs
STAMP_PKG := $(VENV)/.stamp-pkg

MSG_SOURCES := $(wildcard msg_defs/msg/*.msg) msg_defs/CMakeLists.txt msg_defs/package.xml \
	cmake/prune_missing_include_dirs.cmake
REQUIREMENTS := requirements/ros.txt requirements/python.txt requirements/constraints.txt

# Isolate DDS for everything run from here: localhost only; tests pick their own domain id.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export PYTHONDONTWRITEBYTECODE := 1

.PHONY: help setup demo test bench validate lint clean freeze

help:
	@sed -n '2,10p' Makefile | sed 's/^# \{0,1\}//'

$(VPY):
	$(PYTHON) -m venv $(VENV)

$(STAMP_DEPS): $(REQUIREMENTS) | $(VPY)
	$(PIP) install --quiet -c requirements/constraints.txt \
		-r requirements/ros.txt -r requirements/python.txt
	touch $@

# train_calib_msgs: plain cmake into the venv prefix (see README, "How the messages are built").
$(STAMP_MSGS): $(STAMP_DEPS) $(MSG_SOURCES)
	rm -rf $(MSG_BUILD)
	mkdir -p $(MSG_BUILD)
	cd $(MSG_BUILD) && AMENT_PREFIX_PATH=$(ABS_VENV) PATH=$(ABS_VENV)/bin:$$PATH \
		cmake $(CURDIR)/msg_defs \
		-DCMAKE_PREFIX_PATH=$(ABS_VENV) \
		-DCMAKE_INSTALL_PREFIX=$(ABS_VENV) \
		-DPython3_EXECUTABLE=$(ABS_VENV)/bin/python \
		-DCMAKE_PROJECT_INCLUDE=$(CURDIR)/cmake/prune_missing_include_dirs.cmake \
		-DBUILD_TESTING=OFF > cmake.log 2>&1 || { tail -40 cmake.log; exit 1; }
	cd $(MSG_BUILD) && AMENT_PREFIX_PATH=$(ABS_VENV) PATH=$(ABS_VENV)/bin:$$PATH \
		$(MAKE) --no-print-directory -j2 install > make.log 2>&1 || { tail -40 make.log; exit 1; }
	touch $@

$(STAMP_PKG): $(STAMP_MSGS) setup.py setup.cfg package.xml train_calib/window/_kernel.c train_calib/estimation/_ukf_kernel.c \
		train_calib/ingest/_kernel.c
	$(PIP) install --quiet --no-deps --no-build-isolation -e .
	@# setup.cfg puts executables in lib/train_calib (where `ros2 run` looks); expose them on PATH too
	for exe in $(VENV)/lib/train_calib/*; do ln -sf ../lib/train_calib/$$(basename $$exe) $(VENV)/bin/; done
	touch $@

setup: $(STAMP_PKG)

demo: $(STAMP_PKG)
	$(VENV)/bin/train-calib demo

# Two workers (pytest-xdist), one test file per worker at a time; each worker claims its own ROS domain id.
# `make test PYTEST_ARGS=-n0` runs serially.
PYTEST_ARGS ?= -n 2 --dist loadfile
test: $(STAMP_PKG)
	$(VPY) -m pytest $(PYTEST_ARGS)

bench: $(STAMP_PKG)
	$(VPY) bench/run_all.py

# The estimator's validation family (generated into build/validation/ when missing) and the external runs,
# scored with the plain UKFConfig() or `make validate PRESET=converging` (bench/validation/README.md).
PRESET ?=
validate: $(STAMP_PKG)
	$(VPY) bench/validation/family.py
	$(VPY) bench/validation/score.py $(if $(PRESET),--preset $(PRESET))

lint: $(STAMP_PKG)
	$(VENV)/bin/ruff check train_calib test bench launch setup.py
	$(VENV)/bin/ruff format --check train_calib test bench launch setup.py

# Re-pin requirements/constraints.txt from the current venv (after changing a requirement).
freeze: $(STAMP_DEPS)
	$(PIP) freeze --all --exclude-editable | grep -v -i -E '^(pip|train[-_]calib[-_]msgs|train[-_]calib)[=@ ]' \
		| sort -f > requirements/constraints.txt

clean:
	rm -rf $(VENV) build *.egg-info
