# Quick start: `make demo`, `make test`. Both create .venv with Python 3.11 when missing.
PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV   := .venv
VPY    := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
BSTAMP := $(VENV)/.installed-bench

.PHONY: demo test bench campaign reliability campaign-test px4-test venv clean

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

# Reliability diagrams (docs/CAMPAIGNS.md): hyperplane and deterministic at c_min 0.5, 0.7 and 0.9
# with the honest noise model (drone and obstacle errors Gauss-Markov, 60 s), one worker each
# under nice; resumable (out/reliability/cXXX.jsonl). The figures go to docs/figures/.
RELIABILITY_EPISODES ?= 100
RELIABILITY_ARGS ?= --family antipodal --methods hyperplane,deterministic --seed 1 --noise-correlation 60 --workers 1
reliability: $(STAMP)
	@for c in 050 070 090; do \
		nice -n 10 $(VENV)/bin/companion campaign $(RELIABILITY_ARGS) --episodes $(RELIABILITY_EPISODES) --c-min 0.$${c#0} \
			--results out/reliability/c$$c.jsonl --resume --json out/reliability/c$$c.json --plot out/reliability/c$$c \
			--progress log || exit $$?; \
		cp out/reliability/c$$c/reliability.png docs/figures/reliability_c$$c.png; \
		cp out/reliability/c$$c/reliability_estimates.png docs/figures/reliability_estimates_c$$c.png; \
	done

campaign-test: $(STAMP)
	$(VENV)/bin/pytest -q -m slow

px4-test: $(STAMP)
	PX4_SITL_DIR=$(PX4_SITL_DIR) $(VENV)/bin/pytest -q -s -m px4 tests/px4

clean:
	rm -rf $(VENV) out bench-results.json
