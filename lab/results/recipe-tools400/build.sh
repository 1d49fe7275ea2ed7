#!/usr/bin/env bash
# Data of the experiment (lab/experiments/2026-12-04-more-training-tools.md): the training set with 400
# tools, then the novel procedural tools and the paper authors' models as test sets. Run from the repository root:
#   lab/results/recipe-tools400/build.sh [DATA]
set -euo pipefail
DATA=${1:-/tmp/recipedata}
export PYTHONHASHSEED=0
build() { /usr/bin/time -f "%e s $1" .venv/bin/osgd --data-dir "$DATA" --workers 2 run "$1"; }
build lab/results/recipe-tools400/pipeline.toml
build pipelines/recipe-novel.toml
build pipelines/recipe-authors.toml
echo built
