#!/bin/bash
# Table III in simulation (docs/togcrf-robot.md) for the recipe's TOG with and without the top-1 ranking term at 0.2
# (lab/results/ranking-weight-2026-11-29/, seeds 0 and 1, 48,440 images each), the paper's 160 trials, 1 view,
# 2 processes; then one table of the four checkpoints.
cd "$(dirname "$0")/../../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
.venv/bin/togcrf robot-eval runs/baseline-28epochs-seed0/tog/checkpoint.pt runs/baseline-28epochs-seed1/tog/checkpoint.pt \
  --config pipelines/recipe.toml --data data --workers 2 --no-pictures --baselines '' --out runs/robot-baseline-views1
.venv/bin/togcrf robot-eval runs/ranking-0.2-28epochs-seed0/tog/checkpoint.pt \
  runs/ranking-0.2-28epochs-seed1/tog/checkpoint.pt --config pipelines/recipe.toml --data data --workers 2 \
  --no-pictures --baselines '' --out runs/robot-ranking-views1
.venv/bin/togcrf robot-table runs/robot-baseline-views1/trials.parquet runs/robot-ranking-views1/trials.parquet \
  --out runs/robot-ranking
