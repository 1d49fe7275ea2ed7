#!/bin/bash
# Issue #15: TOG with the recipe as it is (bfloat16, the ranking term at 0.2, 8 grasp RoIs per image) plus one cell
# of context around each RoI for the grasp head (--option grasp_context_cells=1), 60 minutes of training steps on both
# cores, seed SEED (default 0), scored on the recipe's 206 test samples by benchmarks/score_run.sh (both protocols,
# grasp_ranking.py); then which ground-truth filter leaves its top-1 without a valid grasp
# (lab/results/top1-filters-2026-11-30/filters.py, as for the recipe's checkpoints there).
# Seed 0: 2026-11-30 07:05:15 UTC on, nothing else ran beside the training (the dates are in seed0/dates.log).
#
#     lab/results/context-cells-2026-11-30/run.sh          # seed 0
#     SEED=1 lab/results/context-cells-2026-11-30/run.sh   # seed 1
cd "$(dirname "$0")/../../.."
SEED=${SEED:-0}
SEED=$SEED benchmarks/recipe_run.sh runs/context1-60min-seed$SEED --option grasp_context_cells=1
OMP_NUM_THREADS=2 .venv/bin/python lab/results/top1-filters-2026-11-30/filters.py \
  runs/context1-60min-seed$SEED/tog/checkpoint.pt lab/results/context-cells-2026-11-30/filters-seed$SEED.json
