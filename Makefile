# Two entry points for a fresh machine with only Python:
#   make demo   install, then plan (and replay) the bundled cylinder example
#   make test   install, then run the test suite
#   make wheel-check   build the wheel, install it in a fresh venv, run the CLI outside the repo
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install test demo bench clean wheel-check

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

# two workers (pytest-xdist), a test file's tests on one worker (its module fixtures are
# built once), one BLAS thread per worker (two cores, no oversubscription)
test: $(STAMP)
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m pytest -n 2 --dist loadfile

demo: $(STAMP)
	$(BIN)/python -m planner demo

wheel-check: $(STAMP)
	PYTHON=$(PYTHON) .ci/wheel_check

bench: $(STAMP)
	for f in benchmarks/bench_*.py; do $(BIN)/python $$f || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info
