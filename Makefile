# Two commands do everything on a fresh machine: `make demo` and `make test`; `make docs` builds the manual.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DOCS_STAMP := $(VENV)/.docs-installed

.PHONY: demo test bench docs install clean render-venv

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[all,test]"
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/mutloc demo

test: $(STAMP)
	$(BIN)/python -m pytest -n 2 -q

# Blender (the bpy wheel) for bench/make_blender_set.py, in a venv of its own: bpy 5.0 pins numpy<2.
# Then: MUTLOC_BLENDER_PYTHON=.venv-render/bin/python .venv/bin/python bench/make_blender_set.py
.venv-render/.installed:
	$(PYTHON) -m venv .venv-render
	.venv-render/bin/python -m pip install --quiet "bpy>=5.0"
	touch $@

render-venv: .venv-render/.installed

# The manual, into site/ (open site/index.html); --strict fails on a broken link or API reference.
$(DOCS_STAMP): $(STAMP)
	$(BIN)/python -m pip install --quiet -e ".[all,test,docs]"
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -e ".[all,test,bench]"  # GTSAM, the peer of bench_team.py
	$(BIN)/python bench/bench_solvers.py
	$(BIN)/python bench/bench_detectors.py
	$(BIN)/python bench/bench_cli.py
	$(BIN)/python bench/bench_tags.py
	$(BIN)/python bench/bench_filter.py
	$(BIN)/python bench/bench_unsync.py
	$(BIN)/python bench/bench_team.py
	env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE OPENBLAS_NUM_THREADS=1 $(BIN)/python bench/bench_team_filter.py
	$(BIN)/python bench/bench_calibrate.py
	@echo "figures written to bench/results/"

clean:
	rm -rf $(VENV) build site src/*.egg-info
