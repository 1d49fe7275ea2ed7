#!/bin/bash
# Issue #15: TOG-CRFs with the recipe as it is (bfloat16, the ranking term at 0.2, 8 grasp RoIs per image), 60 minutes
# of training steps on both cores, seed 0, trained on pipelines/recipe-dense.toml (the recipe's piles and images with
# every stable, visible, collision-free grasp kept) and scored on the recipe's test split by benchmarks/score_run.sh
# (both protocols, grasp_ranking.py); then lab/results/top1-filters-2026-11-30/filters.py and
# lab/results/label-ceiling-2026-11-30/top1_valid.py on it. The run goes to runs/crfs-dense-rois8-60min-seed0/tog
# (recipe_run.sh's folder name; the model is tog-crfs, as config.json says). Nothing else ran beside the training
# (2026-11-30 05:26:03-06:36:47 UTC, scored by 06:37:56; the session ran it from /tmp/s/chain.sh).
#
#     lab/results/crfs-dense-rois8-60min-2026-11-30/run.sh
cd "$(dirname "$0")/../../.."
.venv/bin/osgd --data-dir data --workers 2 run pipelines/recipe-dense.toml
SEED=0 benchmarks/recipe_run.sh runs/crfs-dense-rois8-60min-seed0 --pipeline recipe-dense --model tog-crfs
.venv/bin/python lab/results/top1-filters-2026-11-30/filters.py runs/crfs-dense-rois8-60min-seed0/tog/checkpoint.pt \
  lab/results/top1-filters-2026-11-30/dense-crfs-seed0.json
.venv/bin/python lab/results/label-ceiling-2026-11-30/top1_valid.py runs/crfs-dense-rois8-60min-seed0/tog/checkpoint.pt \
  lab/results/crfs-dense-rois8-60min-2026-11-30/top1-valid.json
