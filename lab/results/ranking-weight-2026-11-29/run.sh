#!/bin/bash
# Issue #15: the top-1 ranking term at a small weight (grasp_ranking_weight WEIGHT, default 0.2) from scratch against
# the recipe at the same number of images: both arms side by side on one thread each, EPOCHS (default 12) epochs
# without a time budget, seed SEED (default 0); then both protocols and top1_cells.py (benchmarks/recipe_ab.sh).
# The term was measured only at weight 1.0 before (docs/togcrf-evaluation.md, "A top-1 ranking term").
cd "$(dirname "$0")/../../.."
WEIGHT=${WEIGHT:-0.2}
exec benchmarks/recipe_ab.sh "ranking-$WEIGHT" "${EPOCHS:-12}" --option "grasp_ranking_weight=$WEIGHT"
