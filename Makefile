# microcal: every target sets up (or reuses) the local virtual environment first.
#
# The interpreter: PYTHON if set (`make test PYTHON=/path/to/python3.12`), otherwise the
# newest of python3.13, python3.12, python3.11 on PATH that runs, otherwise python3 if it is
# 3.11 or newer. A candidate counts only if it runs and can make a venv (a pyenv shim of a
# version that is not selected does not, nor Debian's python3 without python3-venv).
PYTHON_CANDIDATES := python3.13 python3.12 python3.11 python3
# prints the interpreter's major.minor if it is Python >= 3.11 with venv, fails otherwise
PYTHON_PROBE := -c 'import sys; ok = sys.version_info >= (3, 11); import ensurepip, venv; \
	ok and print("%d.%d" % sys.version_info[:2]); sys.exit(not ok)'
ifeq ($(strip $(PYTHON)),)
override PYTHON := $(shell for p in $(PYTHON_CANDIDATES); do \
	$$p $(PYTHON_PROBE) >/dev/null 2>&1 && { echo $$p; break; }; done)
PYTHON_MISSING := microcal needs Python 3.11 or newer with venv and found none on PATH \
	($(PYTHON_CANDIDATES)): install one (Debian 12: apt-get install python3 python3-venv) \
	or run make PYTHON=/path/to/python3.X
else
PYTHON_MISSING := microcal needs Python 3.11 or newer with venv: PYTHON=$(PYTHON) does not \
	run, is older or lacks venv (Debian: apt-get install python3-venv)
endif
PYTHON_VERSION := $(if $(PYTHON),$(shell $(PYTHON) $(PYTHON_PROBE) 2>/dev/null))

VENV   ?= .venv
BIN    := $(VENV)/bin
JOBS   ?= auto
# which tests `make test` runs (pytest -m): CI's second Python leaves out the slow ones too
MARKS  ?= not docs_long
# extras to install: dev (tests, lint); CI adds hardware-test (drivers and peers) and docs
EXTRAS ?= dev
comma  := ,
# the stamp names the interpreter's version: a venv made by another Python is rebuilt
STAMP  := $(VENV)/.installed-py$(PYTHON_VERSION)-$(subst $(comma),-,$(EXTRAS))
# `make docs` needs the docs extra (mkdocs, mkdocstrings): in EXTRAS, or added to the venv
ifeq ($(filter docs,$(subst $(comma), ,$(EXTRAS))),)
DOCS_STAMP := $(VENV)/.installed-py$(PYTHON_VERSION)-docs-extra
else
DOCS_STAMP := $(STAMP)
endif

# the targets that need Python stop here, with one line, when there is none
ifeq ($(PYTHON_VERSION),)
ifneq ($(filter-out help clean,$(or $(MAKECMDGOALS),help)),)
$(error $(PYTHON_MISSING))
endif
endif

.PHONY: help demo test test-docs lint docs bench clean

help:  ## list the targets
	@grep -E '^[a-z]+:.*##' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-6s %s\n", $$1, $$2}'

$(STAMP): pyproject.toml
	@if [ -e $(VENV)/pyvenv.cfg ] && [ "$$($(BIN)/python $(PYTHON_PROBE) 2>/dev/null)" != "$(PYTHON_VERSION)" ]; then \
		echo "$(VENV) was made by another Python: rebuilding it with $(PYTHON) ($(PYTHON_VERSION))"; \
		rm -rf $(VENV); fi
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[$(EXTRAS)]'
	@touch $(STAMP)

demo: $(STAMP)  ## run the calibration demo on the simulated platform
	$(BIN)/microcal demo

test: $(STAMP)  ## run the test suite (the long documentation examples: make test-docs)
	$(BIN)/python -m pytest -n $(JOBS) --dist loadgroup -q -m "$(MARKS)"

test-docs: $(STAMP)  ## run the documentation examples that take minutes (whole calibrations)
	$(BIN)/python -m pytest -n $(JOBS) -q -m docs_long tests/docs

lint: $(STAMP)  ## ruff (lint and format check) and mypy
	$(BIN)/ruff check src tests benchmarks scripts
	$(BIN)/ruff format --check src tests benchmarks scripts
	$(BIN)/mypy

ifneq ($(DOCS_STAMP),$(STAMP))
$(DOCS_STAMP): $(STAMP) pyproject.toml
	$(BIN)/python -m pip install --quiet -e '.[docs]'
	@touch $(DOCS_STAMP)
endif

docs: $(DOCS_STAMP)  ## build the documentation site into site/ (warnings are errors)
	$(BIN)/mkdocs build --strict --site-dir site

bench: $(STAMP)  ## run the benchmarks; results in benchmarks/results/
	$(BIN)/python -m benchmarks

clean:  ## remove the virtual environment, caches and the built site
	rm -rf $(VENV) .venv-3.13 .pytest_cache .mypy_cache .ruff_cache build dist site
