# hbeo: two commands do everything on a fresh Debian machine with Python 3.11.
#   make reproduce   set up, then run every notebook (procedural data, quick profile: ~37 min on 2 cores) into
#                    results/quick-procedural/, training
#                    every model from scratch (RESUME=1: continue an interrupted run from its checkpoints;
#                    SEED=N: train every model with training seed N, into results/$(PROFILE)-$(DATASET)-seedN)
#   make test        set up, then pytest over tests/ and nbval over notebooks/ (ci profile), then the fast
#                    tests again on numpy 2 (test-numpy2); the unit tests in $(TEST_JOBS) worker processes
#                    (pytest-xdist, a test file per worker at a time; TEST_JOBS=0: in this process, one at a time)
#   make test-fast   set up, then pytest over tests/ without the tests marked slow (~3.5 min on 2 cores, as its
#                    numpy-2 run in benchmarks/README.md, "The test command's wall time")
#   make test-numpy2 the fast tests on numpy 2 (the GPU machines' stack): a second venv, $(NP2VENV), with
#                    pip install .[render,dask,notebooks,book,test] under requirements.txt's pins but numpy>=2, no pyrender
#   make book        render a run folder's executed notebooks, tables and figures to a static HTML site that
#                    opens offline: results/$(PROFILE)-$(DATASET)/book/index.html (RUN=DIR: another run folder)
#   make docs        set up, then build the documentation site (Sphinx + MyST-NB, offline, no network when opened):
#                    docs/_build/html/index.html
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
PROFILE ?= quick
DATASET ?= procedural
SEED   ?= 0
# SEED read as a number, as reproduce reads it: SEED=01 and SEED=1 name one run folder
override SEED := $(shell expr '$(SEED)' + 0 2>/dev/null)
ifeq ($(filter-out -%,$(SEED)),)
$(error SEED must be a whole number (0, 1, 2, ...))
endif
RUN    ?= results/$(PROFILE)-$(DATASET)$(if $(filter-out 0,$(SEED)),-seed$(SEED))
NP2VENV ?= .venv-numpy2
# the unit tests' worker processes: this machine's cores, at most 4 (each worker builds the shared ci run again)
TEST_JOBS ?= $(shell n=$$(nproc 2>/dev/null || echo 1); echo $$(( n > 4 ? 4 : n )))
XDIST  := $(if $(filter-out 0,$(TEST_JOBS)),-n $(TEST_JOBS) --dist loadfile)

.PHONY: setup reproduce book docs test test-unit test-fast test-numpy2 test-notebooks benchmark clean-results

setup: $(VENV)/.installed

$(VENV)/.installed: requirements.txt requirements-nodeps.txt scripts/setup.sh
	PYTHON=$(PYTHON) VENV=$(VENV) bash scripts/setup.sh
	touch $@

reproduce: setup
	$(PY) -m hbeo reproduce --profile $(PROFILE) --dataset $(DATASET) $(if $(filter-out 0,$(RESUME)),,--fresh)$(if $(filter-out 0,$(SEED)), --seed $(SEED))

book: setup
	$(PY) -m hbeo book $(RUN)

docs: setup
	$(PY) -m sphinx -b html -q docs docs/_build/html
	@echo "docs: docs/_build/html/index.html"

test: setup test-unit test-notebooks test-numpy2

test-unit: setup
	$(PY) -m pytest -q $(XDIST) tests

test-fast: setup
	$(PY) -m pytest -q $(XDIST) -m "not slow" tests

# pyproject.toml's dependencies and extras, constrained to requirements.txt's versions except numpy (extras
# stripped: pip takes none in a constraints file); hbeo itself from the working tree (PYTHONPATH)
test-numpy2:
	test -x $(NP2VENV)/bin/python || $(PYTHON) -m venv $(NP2VENV)
	sed -e '/^numpy==/d' -e 's/\[[a-z,]*\]//' requirements.txt > $(NP2VENV)/constraints.txt
	$(NP2VENV)/bin/python -m pip -q install -c $(NP2VENV)/constraints.txt ".[render,dask,notebooks,book,test]" "numpy>=2"
	$(NP2VENV)/bin/python -m pip -q uninstall -y hbeo
	$(NP2VENV)/bin/python -m ipykernel install --sys-prefix --name python3 >/dev/null
	$(NP2VENV)/bin/python -c "import numpy; assert int(numpy.__version__.split('.')[0]) >= 2, numpy.__version__"
	PYTHONPATH=$(CURDIR) $(NP2VENV)/bin/python -m pytest -q $(XDIST) -m "not slow" -p no:cacheprovider -rs tests

test-notebooks: setup
	$(PY) -m pytest -q --nbval-lax notebooks

benchmark: setup
	$(PY) benchmarks/bench_voxelize.py

# every untracked (or ignored) file and folder under results/: the run folders made here, the caches, renderings
# and checkpoints inside the committed runs; never a tracked file, so a committed run stays as committed
# (DRY=1: list what would go, delete nothing). Refused unless this folder is the top of a git checkout (a copy
# without git, or one inside another repository, cannot tell the committed runs from generated ones).
clean-results:
	@test "$$(git rev-parse --show-toplevel 2>/dev/null)" = "$$(pwd -P)" || { echo "clean-results: $(CURDIR) is not the top of a git checkout, so committed runs cannot be told from generated ones; nothing deleted (remove run folders under results/ by hand)" >&2; exit 2; }
	git clean -d -x $(if $(filter 1,$(DRY)),-n,-f) -- results/
