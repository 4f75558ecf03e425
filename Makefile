# repro: one command per table.  SCALE ?= quick | medium | paper
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
REPRO := $(VENV)/bin/repro
SCALE ?= quick
JOBS ?= 1
RUNFLAGS ?=

.PHONY: setup test test-all bench help

help:
	@echo "make setup     create .venv (torch==2.13.0 CPU build first, then repro with dev extras)"
	@echo "make test      fast test suite (+ data tests when the Bandai-Namco-2 archive is present)"
	@echo "make table1..table5   Neural Marionette tables (SCALE=$(SCALE))"

setup:
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e '.[dev]'

test:
	$(PY) -m pytest -q

test-all:
	$(PY) -m pytest -q -m ''
