#!/bin/bash
# Table III in simulation (docs/togcrf-robot.md) for the recipe with the top-1 ranking term (since 2026-11-29): the
# two 60-minute runs on both cores (lab/results/recipe-ranking-60min-2026-11-29/, seeds 0 and 1) with 1 and 8
# test-time views, and the two 28-epoch runs of lab/results/ranking-weight-2026-11-29/ with 8 views (their 1-view
# trials are runs/robot-ranking-views1, lab/results/robot-ranking-2026-11-29/run.sh); the paper's 160 trials,
# 2 processes; then one table of all.
cd "$(dirname "$0")/../../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
RUN60="runs/recipe-ranking-60min-seed0/tog/checkpoint.pt runs/recipe-ranking-60min-seed1/tog/checkpoint.pt"
RUN28="runs/ranking-0.2-28epochs-seed0/tog/checkpoint.pt runs/ranking-0.2-28epochs-seed1/tog/checkpoint.pt"
ROBOT=(--config pipelines/recipe.toml --data data --workers 2 --no-pictures --baselines '')
.venv/bin/togcrf robot-eval $RUN60 "${ROBOT[@]}" --out runs/robot-ranking60-views1
.venv/bin/togcrf robot-eval $RUN60 $RUN28 "${ROBOT[@]}" --views 8 --out runs/robot-ranking-views8
.venv/bin/togcrf robot-table runs/robot-ranking-views1/trials.parquet runs/robot-ranking60-views1/trials.parquet \
  runs/robot-ranking-views8/trials.parquet --out runs/robot-ranking-60min
