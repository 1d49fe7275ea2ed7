#!/bin/bash
# Issue #15: grasp_fine_map against the recipe at the same number of images: both arms side by side on one thread
# each for EPOCHS (default 28) epochs without a time budget, 28 x 1,730 = 48,440 images each whatever the machine's
# speed; then both protocols and top1_cells.py (benchmarks/recipe_ab.sh). The 60-minute A/B of
# lab/results/fine-map-2026-11-29/ could not fix the images.
cd "$(dirname "$0")/../../.."
exec benchmarks/recipe_ab.sh fine-map "${EPOCHS:-28}" --option grasp_fine_map=true
