#!/bin/bash
# Issue #15: grasp_fine_map against the recipe at the same number of images. Both runs train side by side on one
# thread each for EPOCHS (default 28) epochs without a time budget, so the cosine follows the steps and each sees
# the same 28 x 1,730 = 48,440 images whatever the machine's speed; then both protocols and top1_cells.py
# (benchmarks/recipe_run.sh). The 60-minute A/B of docs/results/fine-map-2026-11-29/ could not fix the images.
cd "$(dirname "$0")/../../.."
EPOCHS=${EPOCHS:-28}
SEED=${SEED:-0}
export SEED MINUTES=0 THREADS=1 TOP1_CELLS=1
benchmarks/recipe_run.sh "runs/fine-map-${EPOCHS}epochs-seed$SEED" --epochs "$EPOCHS" --option grasp_fine_map=true &
benchmarks/recipe_run.sh "runs/baseline-${EPOCHS}epochs-seed$SEED" --epochs "$EPOCHS" &
wait
