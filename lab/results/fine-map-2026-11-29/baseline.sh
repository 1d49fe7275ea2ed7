#!/bin/bash
# Issue #15: the baseline of run.sh on the same machine the same day: the 60-minute CPU recipe without
# grasp_fine_map, then both protocols and top1_cells.py (benchmarks/recipe_run.sh). This 2-core AMD EPYC ran
# 17.5 images/s on 2026-11-29 against 13.4-13.7 on 2026-11-28, so the runs of that day are no baseline for run.sh.
cd "$(dirname "$0")/../../.."
SEED=${SEED:-0} TOP1_CELLS=1 exec benchmarks/recipe_run.sh "${OUT:-runs/fine-map-baseline-seed${SEED:-0}}"
