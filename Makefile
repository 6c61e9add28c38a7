# Two commands do everything on a fresh machine: `make demo` and `make test`.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test bench install clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/mutloc demo

test: $(STAMP)
	$(BIN)/python -m pytest -n 2 -q

bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -e ".[test,bench]"  # GTSAM, the peer of bench_team.py
	$(BIN)/python bench/bench_solvers.py
	$(BIN)/python bench/bench_detectors.py
	$(BIN)/python bench/bench_cli.py
	$(BIN)/python bench/bench_tags.py
	$(BIN)/python bench/bench_filter.py
	$(BIN)/python bench/bench_team.py
	$(BIN)/python bench/bench_calibrate.py
	@echo "figures written to bench/results/"

clean:
	rm -rf $(VENV) build src/*.egg-info
