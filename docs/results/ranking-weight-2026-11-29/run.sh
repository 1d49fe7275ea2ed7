#!/bin/bash
# Issue #15: the top-1 ranking term at a small weight (grasp_ranking_weight 0.2) from scratch against the recipe at
# the same number of images: both arms side by side on one thread each, EPOCHS (default 12) epochs without a time
# budget (the cosine follows the steps), seed 0; then both protocols and top1_cells.py (benchmarks/recipe_run.sh).
# The term was measured only at weight 1.0 before (docs/togcrf-evaluation.md, "A top-1 ranking term").
cd "$(dirname "$0")/../../.."
EPOCHS=${EPOCHS:-12}
SEED=${SEED:-0}
WEIGHT=${WEIGHT:-0.2}
export SEED MINUTES=0 THREADS=1 TOP1_CELLS=1
benchmarks/recipe_run.sh "runs/ranking-$WEIGHT-${EPOCHS}epochs-seed$SEED" --epochs "$EPOCHS" \
  --option "grasp_ranking_weight=$WEIGHT" &
benchmarks/recipe_run.sh "runs/baseline-${EPOCHS}epochs-seed$SEED" --epochs "$EPOCHS" &
wait
