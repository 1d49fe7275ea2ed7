#!/bin/bash
# Issue #15: the robot experiment in simulation (Table III, 1 view, the paper's 160 trials, 2 processes, no
# baselines) on the TOG checkpoint that run.sh trained on pipelines/TRAIN.toml with seed SEED. Every checkpoint meets
# the same piles and the same judge: the piles follow pipelines/recipe.toml whatever the training data, as in every
# robot run of docs/togcrf-robot.md; the robot's piles are fresh scenes, never in either pipeline's splits.
#
#     SEED=0 lab/results/pairs96-2026-11-30/robot.sh                 # trained on recipe-pairs96
#     SEED=0 TRAIN=recipe lab/results/pairs96-2026-11-30/robot.sh    # trained on recipe
#     .venv/bin/togcrf robot-table runs/robot-recipe-48epochs-seed{0,1}/trials.parquet \
#         runs/robot-recipe-pairs96-48epochs-seed{0,1}/trials.parquet --out runs/robot-pairs96-ab
#
# Three times the paper's trials (30 per tool task, 90 for "no task" and for "hand over"; the first 10 and 30 are the
# trials above), the four checkpoints in one run (2026-11-30 14:50:28-14:55:25 UTC, alone on the machine):
#
#     OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 .venv/bin/togcrf robot-eval \
#         runs/recipe-48epochs-seed{0,1}/tog/checkpoint.pt runs/recipe-pairs96-48epochs-seed{0,1}/tog/checkpoint.pt \
#         --config pipelines/recipe.toml --data data --workers 2 --no-pictures --baselines '' \
#         --tool-trials 30 --named-trials 90 --out runs/robot-pairs96-ab-x3
cd "$(dirname "$0")/../../.."
SEED=${SEED:-0}
TRAIN=${TRAIN:-recipe-pairs96}
RUN=runs/$TRAIN-48epochs-seed$SEED
echo "$(date -u +%FT%TZ) robot start" >> "$RUN/dates.log"
OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 .venv/bin/togcrf robot-eval "$RUN/tog/checkpoint.pt" \
  --config pipelines/recipe.toml --data data --workers 2 --no-pictures --baselines '' \
  --out "runs/robot-$TRAIN-48epochs-seed$SEED" || exit 1
echo "$(date -u +%FT%TZ) robot end" >> "$RUN/dates.log"
