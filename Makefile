# pipenav: `make demo` and `make test` each create .venv if missing, install, and run.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.pipenav-installed
PYTEST_ARGS ?=
JOBS ?= auto

.PHONY: install demo test test-scenarios test-slow test-all lint bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

# torch first, pinned: a bare "torch" requirement would pull a multi-GB CUDA build.
$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install -q torch==2.13.0
	$(BIN)/python -m pip install -q -e ".[test,zoo,bench]"
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/pipenav demo --out results/demo

# The default suite: everything but the slow tests and the scenario suite.
test: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow and not scenarios" $(PYTEST_ARGS)

# The packaged autonomy scenarios as tests, one per scenario and seed, on all cores.
test-scenarios: $(STAMP)
	$(BIN)/python -m pytest -q -m scenarios -n $(JOBS) $(PYTEST_ARGS)

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m "slow and not scenarios" -n $(JOBS) $(PYTEST_ARGS)

test-all: $(STAMP)
	$(BIN)/python -m pytest -q $(PYTEST_ARGS)

# ruff's rules and format on everything; mypy on the four packages (pyproject.toml [tool.mypy]).
lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_world.py

clean:
	rm -rf $(VENV) results .pytest_cache .ruff_cache .mypy_cache .hypothesis
