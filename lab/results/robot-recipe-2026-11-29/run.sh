#!/bin/bash
# Table III in simulation (docs/togcrf-robot.md) for the recipe's TOG of lab/results/fine-map-images-2026-11-29/
# (seed 0, 48,440 images, with and without grasp_fine_map), with the oracle and random bounds, on the paper's 160
# trials, 2 processes; then the same two checkpoints with 8 test-time views (togcrf.tta), and one table of all.
cd "$(dirname "$0")/../../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
CHECKPOINTS="runs/baseline-28epochs-seed0/tog/checkpoint.pt runs/fine-map-28epochs-seed0/tog/checkpoint.pt"
.venv/bin/togcrf robot-eval $CHECKPOINTS --config pipelines/recipe.toml --data data --workers 2 --no-pictures \
  --out runs/robot-recipe-views1
.venv/bin/togcrf robot-eval $CHECKPOINTS --config pipelines/recipe.toml --data data --workers 2 --no-pictures \
  --baselines '' --views 8 --out runs/robot-recipe-views8
.venv/bin/togcrf robot-table runs/robot-recipe-views1/trials.parquet runs/robot-recipe-views8/trials.parquet \
  --out runs/robot-recipe
