#!/bin/bash
# Issue #15: the top-1 ranking term with the candidates that match an annotated grasp as mAP-G judges them as its
# targets (--option grasp_ranking_matches=true), at the images of a 60-minute run (28 epochs, 48,440 images each, no
# time budget, the cosine over the steps): seeds 0 and 1 side by side on one thread each, then each run scored
# (benchmarks/recipe_run.sh with TOP1_CELLS=1). With 16 grasp RoIs per image, so that the baselines are the runs of
# the ranking term at 0.2 of lab/results/ranking-weight-2026-11-29 (run-28epochs.sh: the same command, seeds and
# epochs, without the option, before the recipe took 8 RoIs per image).
cd "$(dirname "$0")/../../.."
export MINUTES=0 THREADS=1 TOP1_CELLS=1
for SEED in 0 1; do
  SEED=$SEED benchmarks/recipe_run.sh "runs/ranking-matches-28epochs-seed$SEED" --epochs 28 \
    --option grasp_rois_per_image=16 --option grasp_ranking_matches=true &
done
wait
