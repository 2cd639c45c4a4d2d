# maglevid: `make demo` and `make test` are the two set-up commands (see README).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test test-slow lint format bench clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/maglevid demo --out demo-out

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests benchmarks
	$(VENV)/bin/ruff format --check src tests benchmarks

# One BLAS thread per process: the suite's matrices are small, and threads only
# fight each other on a 2-core machine (measured 3x slower with threads). One pytest
# worker per core (pytest-xdist; TEST_WORKERS=0 runs in this process).
TEST_WORKERS ?= auto
test: lint
	bash scripts/install-browser.sh
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 $(PY) -m pytest -q -n $(TEST_WORKERS)

# The `slow`-marked tests (left out of `make test`; `make bench` runs them too).
test-slow: $(STAMP)
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 $(PY) -m pytest -q -n $(TEST_WORKERS) -m slow

format: $(STAMP)
	$(VENV)/bin/ruff format src tests benchmarks
	$(VENV)/bin/ruff check --fix src tests benchmarks

# The peers (SLICOT through ctrlsys, SIPPY, nfoursid) come with the `bench` extra; GNU
# Octave's control package is used when the system has it, and skipped with a message
# otherwise. run_all refuses to write BENCHMARKS.md from a modified tree (commit first).
# The slow tests' PostgreSQL cases need a server: the same throwaway one as CI's
# (.ci/postgres.sh; without one they skip, and the report names them).
bench: $(STAMP)
	$(PY) -m pip install -q -e '.[bench]'
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 bash -c 'source .ci/postgres.sh || true; \
		$(PY) -m benchmarks.run_all --huge --plot docs/images/speed_accuracy.png'

clean:
	rm -rf $(VENV) demo-out .pytest_cache .ruff_cache
