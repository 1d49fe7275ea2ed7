#!/bin/bash
# Issue #15: the recipe with half the grasp head's training RoIs (`--option grasp_rois_per_image=8` after the
# options of togcrf.reproduce.CPU_SCALE, which train the grasp head on up to 16 foreground RoIs per image), otherwise
# the recipe's command: TOG, 60 minutes of training steps on both cores (2 threads, the time budget, bfloat16 on a CPU
# with AVX-512 BF16), then scored on the 206 test samples (benchmarks/score_run.sh: both protocols,
# grasp_ranking.py). SEED picks the seed (default 0). Nothing else running beside it.
cd "$(dirname "$0")/../../.."
SEED=${SEED:-0}
SEED=$SEED benchmarks/recipe_run.sh "runs/grasp-rois8-60min-seed$SEED" --option grasp_rois_per_image=8
