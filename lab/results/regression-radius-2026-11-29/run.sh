#!/bin/bash
# Issue #15: the 60-minute CPU recipe with the regression of the candidates within RADIUS (default 1) cells of an
# annotated grasp trained onto it (--option grasp_regression_radius=$RADIUS), then both protocols and 8 test-time
# views (benchmarks/recipe_run.sh). Compare with lab/results/recipe-2cores-bf16-2026-11-28 (seed 0) and
# lab/results/recipe-2cores-bf16-seed1-2026-11-28 (seed 1): the same run without the option.
cd "$(dirname "$0")/../../.."
RADIUS=${RADIUS:-1}
SEED=${SEED:-0} VIEWS=8 exec benchmarks/recipe_run.sh "${OUT:-runs/regression-radius$RADIUS-seed${SEED:-0}}" \
  --option grasp_regression_radius="$RADIUS"
