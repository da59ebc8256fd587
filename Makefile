# pfx: the two commands a newcomer runs are `make reproduce-papers` and `make test`.
# Both create the virtual environment in .venv on first use.

PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
INSTALLED := $(VENV)/.installed

.PHONY: install test check-plain-install reproduce-papers reproduce-benchmarks bench gpu-check clean

$(INSTALLED): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(INSTALLED)

install: $(INSTALLED)

# The house rules first (seconds): lint and import order (ruff), the layering (import-linter).
# Then the suite on one pytest-xdist worker per logical CPU (-n logical; -n auto counts physical
# cores, 1 on a machine whose 2 vCPUs share one). `pytest tests/test_x.py` runs one file in one
# process; `pytest -m "not slow"` leaves out the few full-size statistical checks. The plain
# install's checks build an environment of their own: `make check-plain-install` runs them, and CI
# runs it after `make test`.
test: $(INSTALLED)
	$(BIN)/ruff check pfx tests
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -q -n logical -m "not plain_install"

# What a plain `pip install .` (no extras) runs, in its own environment .venv-plain (built once,
# then only pfx is reinstalled): every module imports but an extra's backends, every example
# config runs, and the jax backend and the Dask executors are refused naming their extra
# (tests/test_plain_install.py).
check-plain-install: $(INSTALLED)
	$(BIN)/python -m pytest -q -m plain_install tests/test_plain_install.py

reproduce-papers: $(INSTALLED)
	$(BIN)/pfx reproduce

# The field's published benchmarks (DAPPER's Lorenz tables, stochastic volatility on GBP/USD,
# King et al.'s cholera): longer runs than the papers', in their own gallery; their plugins' code
# shares the papers' store, results/plugins/, so that results/ keeps each plugin once.
reproduce-benchmarks: $(INSTALLED)
	$(BIN)/pfx reproduce --configs configs/benchmarks --out results/benchmarks --plugin-store results/plugins

# The benchmark runs in its own environment: the peer libraries (`particles` needs numpy < 2)
# would not fit the main one. pfx is installed editable, so `make bench` measures this tree;
# numba's cache for that environment lives inside it.
BENCH_VENV := .venv-bench
BENCH_INSTALLED := $(BENCH_VENV)/.installed

$(BENCH_INSTALLED): pyproject.toml
	$(PYTHON) -m venv $(BENCH_VENV)
	$(BENCH_VENV)/bin/python -m pip install --quiet --upgrade pip
	$(BENCH_VENV)/bin/python -m pip install --quiet 'numpy<2' -e . particles filterpy pfilter
	touch $(BENCH_INSTALLED)

bench: $(BENCH_INSTALLED)
	NUMBA_CACHE_DIR=$(BENCH_VENV)/numba-cache $(BENCH_VENV)/bin/pfx bench $(BENCH_ARGS)

# The GPU check: `pfx bench --backend jax`, the JAX backend's tests and, on a GPU, pomp's two models
# on the jax backend (replicates per second), in under 9 minutes, made for a GPU machine without
# network access (it installs wheels carried in .whl/); on a machine without a GPU it says so and
# runs on JAX's CPU build. Output in $OUT or gpu-check-output/.
# It uses .venv/bin/python where there is one (else python3) and creates no environment.
gpu-check:
	bash examples/gpu_check.sh

clean:
	rm -rf $(VENV) $(BENCH_VENV) .venv-plain .jax-cache runs .pytest_cache
