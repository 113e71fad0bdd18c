# Two entry points for a fresh clone (see README):
#   make demo   install into .venv, then build a procedural object, drop it, write an asset and an mp4
#   make test   install into .venv, then lint, format check and the test suite (CPU only)
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
DEMO_OUT ?= demo_out

.PHONY: install demo test lint bench clean

install: $(VENV)/.installed

# The CPU build of torch is pinned here, not in pyproject: an open `torch` requirement would pull a
# multi-GB CUDA build on a machine that has no torch yet.
$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q torch==2.13.0
	$(BIN)/python -m pip install -q -e '.[dev]'
	touch $@

demo: install
	$(BIN)/reconphys demo --out $(DEMO_OUT)

lint: install
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

test: lint
	$(BIN)/python -m pytest -q

bench: install
	$(BIN)/python benchmarks/bench_simulator.py
	$(BIN)/python benchmarks/bench_renderer.py

clean:
	rm -rf $(VENV) $(DEMO_OUT) .pytest_cache .ruff_cache
