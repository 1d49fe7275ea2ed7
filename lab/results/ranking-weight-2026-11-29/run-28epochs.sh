#!/bin/bash
# Issue #15: the top-1 ranking term at the images of a 60-minute run (28 epochs, 48,440 images each, no time budget,
# the cosine over the steps), as run on 2026-11-29: two pairs of runs, one after the other, each pair side by side on
# one thread each, then each run scored (benchmarks/recipe_run.sh with TOP1_CELLS=1). The recipe's seed-0 run is
# lab/results/fine-map-images-2026-11-29/baseline-seed0 (the same command, seed and epochs, run beside another arm).
# The recipe has had the term at 0.2 since these runs, so its arm here turns it off (when run, it was the default 0).
cd "$(dirname "$0")/../../.."
export MINUTES=0 THREADS=1 TOP1_CELLS=1
SEED=0 benchmarks/recipe_run.sh runs/ranking-0.2-28epochs-seed0 --epochs 28 --option grasp_ranking_weight=0.2 &
SEED=1 benchmarks/recipe_run.sh runs/baseline-28epochs-seed1 --epochs 28 --option grasp_ranking_weight=0 &
wait
SEED=1 benchmarks/recipe_run.sh runs/ranking-0.2-28epochs-seed1 --epochs 28 --option grasp_ranking_weight=0.2 &
SEED=0 benchmarks/recipe_run.sh runs/ranking-0.3-28epochs-seed0 --epochs 28 --option grasp_ranking_weight=0.3 &
wait
