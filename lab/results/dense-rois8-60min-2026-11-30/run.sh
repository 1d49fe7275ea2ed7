#!/bin/bash
# Issue #15: TOG with the recipe as it is (bfloat16, the ranking term at 0.2, 8 grasp RoIs per image), 60 minutes of
# training steps on both cores, seed 0, trained on pipelines/recipe-dense.toml (the recipe's piles and images with
# every stable, visible, collision-free grasp kept: nms_radius = 0) and scored on the recipe's test split (its
# suppressed ground truth) by benchmarks/score_run.sh (both protocols, grasp_ranking.py); then
# lab/results/label-ceiling-2026-11-30/top1_valid.py on it and on the recipe's TOG checkpoint of the same seed.
# Nothing else ran beside the training (2026-11-30 02:41:46 UTC on; the dates are in seed0/dates.log).
#
#     lab/results/dense-rois8-60min-2026-11-30/run.sh
cd "$(dirname "$0")/../../.."
.venv/bin/osgd --data-dir data --workers 2 run pipelines/recipe-dense.toml
SEED=0 benchmarks/recipe_run.sh runs/dense-rois8-60min-seed0 --pipeline recipe-dense
for RUN in dense-rois8-60min-seed0 grasp-rois8-60min-seed0; do
  .venv/bin/python lab/results/label-ceiling-2026-11-30/top1_valid.py runs/$RUN/tog/checkpoint.pt \
    lab/results/label-ceiling-2026-11-30/top1-valid-${RUN%-seed0}-seed0.json
done
