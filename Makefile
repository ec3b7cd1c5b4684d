# Quick start: `make demo`, `make test`. Both create .venv with Python 3.11 when missing.
PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV   := .venv
VPY    := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
BSTAMP := $(VENV)/.installed-bench

.PHONY: demo test bench campaign campaign-test realtime-test px4-test venv clean

# PX4 SITL build with start-sih (see docs/PX4.md); `make px4-test` flies the companion against it.
PX4_SITL_DIR ?= ../shared/px4-sitl

$(VPY):
	@$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 11), "Python 3.11 or newer is needed, found " + sys.version' 
	$(PYTHON) -m venv $(VENV)
	$(VPY) -m pip install -q --upgrade pip

$(STAMP): pyproject.toml | $(VPY)
	$(VPY) -m pip install -q -e '.[test]'
	@touch $(STAMP)

$(BSTAMP): pyproject.toml $(STAMP)
	$(VPY) -m pip install -q -e '.[test,bench]'
	@touch $(BSTAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/companion demo antipodal

test: $(STAMP)
	$(VENV)/bin/pytest -q

bench: $(BSTAMP)
	$(VPY) -m tests.benchmarks

# The campaign appends every finished run to out/campaign.jsonl and resumes from it: run
# `make campaign` again after an interruption. SCHEDULER=tcp://HOST:8786 runs it on a Dask
# cluster (docs/CAMPAIGNS.md); CAMPAIGN_ARGS replaces the campaign's definition.
CAMPAIGN_ARGS ?= --family antipodal --episodes 200 --methods hyperplane,paper,deterministic,bhattacharyya --seed 1
campaign: $(STAMP)
	$(VENV)/bin/companion campaign $(CAMPAIGN_ARGS) $(if $(SCHEDULER),--scheduler $(SCHEDULER)) \
		--results out/campaign.jsonl --resume --json out/campaign.json --plot out/campaign

campaign-test: $(STAMP)
	$(VENV)/bin/pytest -q -m slow

# Closed loops in wall-clock time over loopback UDP (mavsim and the companion as two processes).
realtime-test: $(STAMP)
	$(VENV)/bin/pytest -q -m realtime

px4-test: $(STAMP)
	PX4_SITL_DIR=$(PX4_SITL_DIR) $(VENV)/bin/pytest -q -s -m px4 tests/px4

clean:
	rm -rf $(VENV) out bench-results.json
