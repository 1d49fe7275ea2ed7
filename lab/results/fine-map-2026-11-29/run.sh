#!/bin/bash
# Issue #15: the 60-minute CPU recipe with the grasp head also pooling ResNet C2 at stride 4
# (--option grasp_fine_map=true), then both protocols, 8 test-time views and top1_cells.py (benchmarks/recipe_run.sh).
# Its baseline is baseline.sh, run right after it on the same machine.
cd "$(dirname "$0")/../../.."
SEED=${SEED:-0} VIEWS=8 TOP1_CELLS=1 exec benchmarks/recipe_run.sh "${OUT:-runs/fine-map-seed${SEED:-0}}" \
  --option grasp_fine_map=true
