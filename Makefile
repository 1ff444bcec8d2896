# Two entry points for a fresh machine with only Python:
#   make demo   install the package (no dev extra), then plan, verify and replay the bundled cylinder example
#   make test   install, then run the test suite
#   make wheel-check   build the wheel, install it in a fresh venv, run the CLI outside the repo
# Another Python in its own venv: make test PYTHON=python3.13 VENV=.venv-3.13 (.ci/run does so)
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install test demo bench clean wheel-check api-docs

# the demo needs the package alone; the tests add the dev extra (pytest, hypothesis, dask, ...)
RUNTIME := $(VENV)/.installed-runtime

$(RUNTIME): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e .
	touch $(RUNTIME)

$(STAMP): pyproject.toml $(RUNTIME)
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

# two workers (pytest-xdist), a test file's tests on one worker (its module fixtures are
# built once), one BLAS thread per worker (two cores, no oversubscription)
test: $(STAMP)
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m pytest -n 2 --dist loadfile

demo: $(RUNTIME)
	$(BIN)/python -m planner demo

# the API reference from the docstrings (pdoc, in the dev extra): build/api/index.html; every
# module of the package (planner's __all__ alone would list only what it re-exports)
MODULES = $(filter-out planner.plan,$(subst /,.,$(basename $(filter-out %__init__.py %__main__.py,$(wildcard planner/*.py planner/sim/*.py)))))
api-docs: $(STAMP)
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m pdoc -o build/api planner $(MODULES)

wheel-check: $(STAMP)
	PYTHON=$(PYTHON) VENV=$(VENV) .ci/wheel_check

bench: $(STAMP)
	for f in benchmarks/bench_*.py; do $(BIN)/python $$f || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info
