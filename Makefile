# hbeo: two commands do everything on a fresh Debian machine with Python 3.11.
#   make reproduce   set up, then run every notebook (procedural data, cpu profile) into results/, training
#                    every model from scratch (RESUME=1: continue an interrupted run from its checkpoints)
#   make test        set up, then pytest over tests/ and nbval over notebooks/ (ci profile)
#   make test-fast   set up, then pytest over tests/ without the tests marked slow (about a minute)
#   make book        render a run folder's executed notebooks, tables and figures to a static HTML site that
#                    opens offline: results/$(PROFILE)-$(DATASET)/book/index.html (RUN=DIR: another run folder)
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
PROFILE ?= cpu
DATASET ?= procedural
RUN    ?= results/$(PROFILE)-$(DATASET)

.PHONY: setup reproduce book test test-unit test-fast test-notebooks benchmark clean-results

setup: $(VENV)/.installed

$(VENV)/.installed: requirements.txt requirements-nodeps.txt scripts/setup.sh
	PYTHON=$(PYTHON) VENV=$(VENV) bash scripts/setup.sh
	touch $@

reproduce: setup
	$(PY) -m hbeo reproduce --profile $(PROFILE) --dataset $(DATASET) $(if $(filter 1,$(RESUME)),,--fresh)

book: setup
	$(PY) -m hbeo book $(RUN)

test: setup test-unit test-notebooks

test-unit: setup
	$(PY) -m pytest -q tests

test-fast: setup
	$(PY) -m pytest -q -m "not slow" tests

test-notebooks: setup
	$(PY) -m pytest -q --nbval-lax notebooks

benchmark: setup
	$(PY) benchmarks/bench_voxelize.py

clean-results:
	rm -rf results/ci-* results/cpu-* results/full-*
