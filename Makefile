# CLIS on ROS 2 — every target brings the workspace up to date first (idempotent `setup`).
#   make run    set up, then run the main job on the simulator
#   make test   set up, then lint and run the test suite
#   make bench  set up, then run the benchmarks (results in docs/benchmarks.md)
#   make test-cpus  the bit-for-bit tests under each CPU's BLAS, numpy and numba kernels
#   make reproduce  the paper preset's claims table of docs/results.md (10 seeds x 1000 episodes)
#   make reproduce-improved  the improved preset's claims table and its ablation
SHELL := /bin/bash
.DEFAULT_GOAL := help
.DELETE_ON_ERROR:

VENV := .venv
# A Python 3.10-3.13 (the ROS 2 Jazzy wheels exist for cp310-cp313).
PYTHON ?= $(shell for p in python3.11 python3.12 python3.10 python3.13 python3; do \
  command -v $$p >/dev/null 2>&1 && $$p -c 'import sys; sys.exit(not (3, 10) <= sys.version_info[:2] <= (3, 13))' 2>/dev/null && { echo $$p; break; }; done)
# A system ROS 2 Jazzy that is sourced is used instead of the PyPI wheels.
SYSTEM_ROS := $(shell [ "$$ROS_DISTRO" = jazzy ] && python3 -c 'import rclpy' >/dev/null 2>&1 && echo 1)
ENV := source ./env.sh
SOURCES := $(shell find src examples -type f \( -name '*.py' -o -name package.xml -o -name setup.cfg \
  -o -path '*/scripts/*' -o -path '*/resource/*' \) -not -path '*/__pycache__/*') $(wildcard config/*) \
  $(wildcard config/robots/*)
RUN_ARGS ?=
# make run records its run as a bag (MCAP) here; RECORD= turns it off.
RECORD ?= bags/run-$(shell date +%Y%m%d-%H%M%S)

# The claims tables of docs/results.md: each preset on the five conditions, 10 seeds.
REPRO_SEEDS ?= 10
REPRO_EPISODES ?= 1000

.PHONY: help setup run test test-cpus lint bench clean reproduce reproduce-improved
help:
	@sed -n '2,7p' Makefile | sed 's/^# *//'

setup: $(VENV)/.stamp install/.stamp test/foxglove_reader/.stamp $(VENV)/.gym.stamp

$(VENV)/.stamp: requirements.txt requirements-py.txt
ifeq ($(SYSTEM_ROS),1)
	@echo "setup: using the sourced system ROS 2 $$ROS_DISTRO"
	python3 -m venv --system-site-packages $(VENV)
	$(VENV)/bin/pip install -q -r requirements-py.txt
else
	@test -n "$(PYTHON)" || { echo "setup: need Python 3.10-3.13 (python3.11 recommended)"; exit 1; }
	@echo "setup: creating $(VENV) with $(PYTHON) and the ROS 2 Jazzy wheels"
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install -q -r requirements.txt -r requirements-py.txt
endif
	@touch $@

install/.stamp: $(VENV)/.stamp $(SOURCES)
	@echo "setup: colcon build"
	@mkdir -p log; $(ENV) 2>/dev/null; AMENT_PREFIX_PATH="$(CURDIR)/$(VENV)$${AMENT_PREFIX_PATH:+:$$AMENT_PREFIX_PATH}" \
	  $(VENV)/bin/colcon --log-base log build --base-paths src examples --symlink-install \
	  --event-handlers console_cohesion- summary- >log/colcon-build.txt 2>&1 \
	  || { mkdir -p log; cat log/colcon-build.txt; exit 1; }
	@touch $@

# gymnasium.make('CRNav-v0') in any interpreter of the venv with no import first (docs/gym.md):
# Gymnasium 1.x loads no plugins, so a start-up hook registers it when gymnasium is imported.
GYM_HOOK := src/cr_sim/cr_sim/gym_plugin.py
$(VENV)/.gym.stamp: $(VENV)/.stamp $(GYM_HOOK)
	@d=$$($(VENV)/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])') \
	  && cp $(GYM_HOOK) $$d/_cr_sim_gym_hook.py \
	  && $(VENV)/bin/python -m py_compile $$d/_cr_sim_gym_hook.py \
	  && echo 'import _cr_sim_gym_hook; _cr_sim_gym_hook.install_hook()' > $$d/cr_sim_gym.pth
	@touch $@

# The Foxglove app's MCAP reader for test/test_bag_readers.py (npm, pinned by package-lock.json);
# without npm (or the registry), setup goes on and that test fails saying why.
FOX := test/foxglove_reader
$(FOX)/.stamp: $(FOX)/package.json $(FOX)/package-lock.json
	@if command -v npm >/dev/null 2>&1; then echo "setup: npm ci ($(FOX))"; \
	  (cd $(FOX) && npm ci --no-audit --no-fund --loglevel=error) && touch $@ \
	  || echo "setup: npm ci failed: test/test_bag_readers.py will fail"; \
	else echo "setup: no npm: test/test_bag_readers.py needs Node.js 18+"; fi

# The main job on the simulator: check the ROS setup, then the CLIS node graph (simulator,
# innate/view/place modules, arbiter, learner as processes) learning live in the Async
# condition for 5 minutes with the improved preset (the one that learns; RUN_ARGS='--preset
# paper' for the paper's rules as printed, whose values diverge: the run says so), with a
# summary and the learning curve (OUT/curve.png); the run is
# recorded as a bag in bags/ (clis bag info, clis replay, clis learn).
# The headless experiment is one command away: clis experiment --help.
run: setup
	@$(ENV) && clis doctor
	@$(ENV) && clis run --condition async --episodes 1000 --time-limit 5 \
	  $(if $(RECORD),--record $(RECORD)) $(RUN_ARGS)

lint: setup
	$(VENV)/bin/ruff check --no-cache src test bench tools examples

# The suite on TEST_WORKERS pytest-xdist workers (each with its own ROS_DOMAIN_ID, test/
# conftest.py; tests that share a module fixture stay on one worker: --dist loadscope). Every
# failure fails make test: no test is run again.
TEST_WORKERS ?= 2
test: lint
	@$(ENV) && python -m pytest -n $(TEST_WORKERS) --dist loadscope $(PYTEST_ARGS)

# The tests that pin results bit for bit (marker bits), once per BLAS kernel set, numpy
# dispatch level and numba CPU users' machines pick: one line each (tools/cpu_check.py). Run it
# before a change that touches arithmetic.
test-cpus: setup
	@$(ENV) && python tools/cpu_check.py $(CPU_ARGS)

bench: setup
	@$(ENV) && python bench/run_all.py

reproduce: setup
	@$(ENV) && clis experiment --preset paper --conditions innate,view,place,sync,async \
	  --episodes $(REPRO_EPISODES) --seeds $(REPRO_SEEDS) --eval-episodes 5 --out results/paper --resume
	@$(ENV) && python -m clis_app.experiments.claims results/paper

# The improved preset (docs/results.md), then its ablation: Async with each change alone.
reproduce-improved: setup
	@$(ENV) && clis experiment --preset improved --conditions innate,view,place,sync,async \
	  --episodes $(REPRO_EPISODES) --seeds $(REPRO_SEEDS) --eval-episodes 5 --out results/improved --resume
	@$(ENV) && python -m clis_app.experiments.claims results/improved
	@$(ENV) && clis experiment --preset improved --ablation --conditions async \
	  --episodes $(REPRO_EPISODES) --seeds $(REPRO_SEEDS) --eval-every 100 --eval-episodes 4 \
	  --out results/ablation --resume

clean:
	rm -rf build install log $(VENV)
