# repro: one command per table.  SCALE ?= quick | medium | paper | converged
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
REPRO := $(VENV)/bin/repro
SCALE ?= quick
JOBS ?= 1
RUNFLAGS ?=

.PHONY: setup test test-all bench help browser

help:
	@echo "make setup     create .venv (torch==2.13.0 CPU build first, then repro with dev extras)"
	@echo "make test      fast test suite (+ data tests when the Bandai-Namco-2 archive is present)"
	@echo "make table1..table5   Neural Marionette tables (SCALE=$(SCALE))"
	@echo "make multiact-table1 ... multiact-fig6   MultiAct tables (SCALE=$(SCALE))"
	@echo "make odmo-table1 ... odmo-tableS1   ODMO tables (SCALE=$(SCALE))"

setup:
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e '.[dev]'

test:
	$(PY) -m pytest -q

# Debian's chromium (+ the DejaVu fonts the report and its golden screenshot use) for the
# report's browser tests and `repro report --check`; needs root; skipped when already there.
browser:
	@command -v chromium >/dev/null 2>&1 && fc-list 2>/dev/null | grep -q DejaVuSans || \
	  { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -q \
	    chromium fonts-dejavu-core >/dev/null; }
	@chromium --version

test-all:
	$(PY) -m pytest -q -m ''

# --- tables ----------------------------------------------------------------------------------
# `make table3` = Neural Marionette Table 3 (the brief's main job); every spec also has its own
# target: marionette-table1 ... odmo-tableS1.  SCALE=quick|medium|paper|converged, DATASET=... overrides.
MARIONETTE := table1 table2 table3 table4 table5 fig8 fig10
MULTIACT := table1 table2 table3 tableA tableB fig6
ODMO := table1 table2 table3 table4 tableS1
DATASET_FLAG := $(if $(DATASET),--dataset $(DATASET),)
ALL_TABLES := $(addprefix marionette/,$(MARIONETTE)) $(addprefix multiact/,$(MULTIACT)) $(addprefix odmo/,$(ODMO))
# Tables that CI reruns at the quick scale against tables/baselines/quick: all 18 specs (seven
# Neural Marionette, six MultiAct, five ODMO) in one job graph, so their shared trainings run once.
CI_TABLES ?= $(ALL_TABLES)
BASELINES := tables/baselines/$(SCALE)

.PHONY: table1 table2 table3 table4 table5 tables ci-tables baselines verify \
	$(addprefix marionette-,$(MARIONETTE)) $(addprefix multiact-,$(MULTIACT)) $(addprefix odmo-,$(ODMO))

table1 table2 table3 table4 table5: %: marionette-%

$(addprefix marionette-,$(MARIONETTE)): marionette-%:
	$(REPRO) run marionette/$* --scale $(SCALE) $(DATASET_FLAG) --jobs $(JOBS) $(RUNFLAGS)
$(addprefix multiact-,$(MULTIACT)): multiact-%:
	$(REPRO) run multiact/$* --scale $(SCALE) $(DATASET_FLAG) --jobs $(JOBS) $(RUNFLAGS)
$(addprefix odmo-,$(ODMO)): odmo-%:
	$(REPRO) run odmo/$* --scale $(SCALE) $(DATASET_FLAG) --jobs $(JOBS) $(RUNFLAGS)

tables:
	$(REPRO) run $(ALL_TABLES) --scale $(SCALE) $(DATASET_FLAG) --jobs $(JOBS) $(RUNFLAGS)

# CI regression: rerun the built tables at the quick scale and compare with committed baselines.
# Jobs compute with the profile's `threads` (1), so CI_JOBS changes the wall time, not a number.
CI_JOBS ?= 2
# ... and writes their HTML report, opened in headless chromium when it is installed
REPORT_DIR ?= report
CHECK_FLAG := $(if $(shell command -v chromium 2>/dev/null),--check,)
ci-tables:
	$(REPRO) run $(CI_TABLES) --scale quick --quiet --jobs $(CI_JOBS)
	$(REPRO) verify $(CI_TABLES) --scale quick --baseline tables/baselines/quick
	$(REPRO) report $(CI_TABLES) --scale quick --out $(REPORT_DIR) $(CHECK_FLAG)

# Rewrite the committed baselines of $(SCALE) (default quick) from the newest runs of the built
# tables (review the diff before committing); `make verify` compares without writing.  The medium
# baselines are reference results of one machine (docs/results.md), not a CI gate.
baselines:
	$(REPRO) verify $(CI_TABLES) --scale $(SCALE) --baseline $(BASELINES) --update

verify:
	$(REPRO) verify $(CI_TABLES) --scale $(SCALE) --baseline $(BASELINES)
