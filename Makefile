# osgd: two commands do all set-up on a fresh machine:
#   make test      create .venv if missing, install, run the test suite
#   make dataset   create .venv if missing, install, build the default dataset
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DATA_DIR ?= data
PIPELINE ?= pipelines/default.toml
WORKERS ?=

.PHONY: help install system-deps test test-slow test-all lint dataset kitchen golden golden-update bench clean-data table table-gpu

help:
	@echo "make test       install into .venv and run the tests (the CI entry point)"
	@echo "make dataset    install and build the default dataset into $(DATA_DIR)/"
	@echo "make kitchen    the kitchen example taxonomy (docs/taxonomy.md): its meshes, then its dataset in $(DATA_DIR)/"
	@echo "make golden     rebuild the golden pipeline and compare with data/manifests/"
	@echo "make bench      run every stage benchmark"
	@echo "make table      train and evaluate the five models of Table II (the CPU recipe: 1 h per model)"
	@echo "make table-gpu  TOG and TOG-CRFs on 8,000 piles on a GPU machine, in steps of <= 10 min (rerun to go on)"
	@echo "make lint       ruff"

# EGL (Mesa software rendering) for pybullet's renderer; optional, installed when missing.
system-deps:
	@if ! ldconfig -p 2>/dev/null | grep -q libEGL_mesa; then \
		if command -v apt-get >/dev/null && [ "$$(id -u)" = 0 ]; then \
			echo "installing Mesa EGL"; \
			(apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libegl1 libegl-mesa0 libgl1-mesa-dri >/dev/null) \
				|| echo "warning: Mesa EGL not installed; the renderer falls back to embree"; \
		else echo "note: Mesa EGL not found; the renderer falls back to embree"; fi; \
	fi

$(STAMP): pyproject.toml
	@test -d $(VENV) || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev]'
	@touch $(STAMP)

install: system-deps $(STAMP)

test: install
	$(BIN)/python -m pytest -q

test-slow: install
	$(BIN)/python -m pytest -q -m slow

test-all: install
	$(BIN)/python -m pytest -q -m ''

lint: install
	$(BIN)/ruff check osgd togcrf tests benchmarks

dataset: install
	$(BIN)/osgd --data-dir $(DATA_DIR) $(if $(WORKERS),--workers $(WORKERS)) run $(PIPELINE)

# The kitchen example (docs/taxonomy.md): a taxonomy of Table I plus a mug, scissors and a whisk, its meshes written
# by a script into $(DATA_DIR)/kitchen-tools, then its dataset.
kitchen: install
	$(BIN)/python pipelines/kitchen/make_tools.py $(DATA_DIR)/kitchen-tools
	OSGD_KITCHEN_TOOLS=$(abspath $(DATA_DIR))/kitchen-tools $(BIN)/osgd --data-dir $(DATA_DIR) \
		$(if $(WORKERS),--workers $(WORKERS)) run pipelines/kitchen.toml

golden: install
	$(BIN)/python -m pytest -q -m '' tests/test_golden.py

# Rebuild the golden pipeline and rewrite its committed record (after an intended change):
# the manifest, and the shards that tests/test_golden.py compares content with.
golden-update: install
	rm -rf .golden-build data/golden
	PYTHONHASHSEED=0 $(BIN)/osgd --data-dir .golden-build --workers 2 run pipelines/golden.toml
	cp .golden-build/manifests/golden.json data/manifests/golden.json
	for table in models grasps checks scenes samples; do \
		mkdir -p data/golden/$$table && cp .golden-build/$$table/*.parquet data/golden/$$table/; done
	rm -rf .golden-build

# Every benchmarks/bench_*.py with its defaults (benchmarks/ holds these and their helper time_stage_items.py).
bench: install
	@for script in benchmarks/bench_*.py; do echo "== $$script"; $(BIN)/python $$script || exit 1; done

# Table II: on a CPU the recipe's data (the pipeline RECIPE names) and one hour of training per model (five hours);
# on a GPU the paper's scale. Also per test set: the recipe's test piles (seen tools), piles of novel procedural
# tools (pipelines/recipe-novel.toml) and, where OSGD_MODELS_DIR (default ../shared/osgd-models) exists, of the
# paper authors' models (pipelines/recipe-authors.toml).
RECIPE := recipe-pairs96
OSGD_MODELS_DIR ?= ../shared/osgd-models
TEST_SETS = seen=$(RECIPE) novel=recipe-novel $(if $(wildcard $(OSGD_MODELS_DIR)),authors=recipe-authors)
# Absolute, so that make's test above and the pipelines (which read it relative to their own folder) mean one folder.
table: export OSGD_MODELS_DIR := $(abspath $(OSGD_MODELS_DIR))
table: install
	for pipeline in $(foreach set,$(TEST_SETS),$(lastword $(subst =, ,$(set)))); do \
		$(BIN)/osgd --data-dir $(DATA_DIR) $(if $(WORKERS),--workers $(WORKERS)) run pipelines/$$pipeline.toml || exit 1; done
	$(BIN)/togcrf reproduce --data $(DATA_DIR) --pipeline $(RECIPE) --out runs/table2 $(foreach set,$(TEST_SETS),--test-set $(set))

# Table II on a GPU machine: gpu/table-gpu.sh installs, builds pipelines/gpu.toml, measures,
# trains and evaluates, each call within DEADLINE seconds; call it again until it prints "table-gpu: done".
table-gpu:
	gpu/table-gpu.sh

clean-data:
	rm -rf $(DATA_DIR)/models $(DATA_DIR)/grasps $(DATA_DIR)/checks $(DATA_DIR)/scenes $(DATA_DIR)/samples $(DATA_DIR)/cache
