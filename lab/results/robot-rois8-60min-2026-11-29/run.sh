#!/bin/bash
# Table III in simulation (docs/togcrf-robot.md) for the recipe with 8 grasp RoIs per image (since 2026-11-29 22:30
# UTC): the two 60-minute runs of lab/results/grasp-rois8-60min-2026-11-29/ (seeds 0 and 1), 1 view, on the paper's
# 160 trials, 2 processes; then one table beside the recipe's two 60-minute runs before it (16 RoIs per image,
# runs/robot-ranking60-views1, lab/results/robot-ranking-60min-2026-11-29/run.sh).
cd "$(dirname "$0")/../../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
RUNS="runs/grasp-rois8-60min-seed0/tog/checkpoint.pt runs/grasp-rois8-60min-seed1/tog/checkpoint.pt"
.venv/bin/togcrf robot-eval $RUNS --config pipelines/recipe.toml --data data --workers 2 --no-pictures --baselines '' \
  --out runs/robot-rois8-views1
.venv/bin/togcrf robot-table runs/robot-ranking60-views1/trials.parquet runs/robot-rois8-views1/trials.parquet \
  --out runs/robot-rois8-60min
