#!/bin/bash
# Issue #15: the 60-minute CPU recipe with one pair of stability logits per category
# (--option grasp_stability_per_category=true), then both protocols and 8 test-time views
# (benchmarks/recipe_run.sh). Compare with lab/results/recipe-2cores-bf16-2026-11-28 (seed 0) and
# lab/results/recipe-2cores-bf16-seed1-2026-11-28 (seed 1): the same run without the option.
cd "$(dirname "$0")/../../.."
SEED=${SEED:-0} VIEWS=8 exec benchmarks/recipe_run.sh "${OUT:-runs/stability-per-category-seed${SEED:-0}}" \
  --option grasp_stability_per_category=true
