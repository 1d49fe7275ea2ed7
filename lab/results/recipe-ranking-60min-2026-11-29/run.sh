#!/bin/bash
# Issue #15: the recipe as adopted on 2026-11-29 (togcrf.reproduce.CPU_SCALE, with grasp_ranking_weight=0.2) as the
# issue's goal asks for it: TOG, 60 minutes of training steps on both cores (2 threads, the time budget, bfloat16 on
# a CPU with AVX-512 BF16), seeds 0 and 1 one after the other, each then scored on the 206 test samples
# (benchmarks/score_run.sh: both protocols, grasp_ranking.py). As run on 2026-11-29, 14:06-16:27 UTC.
cd "$(dirname "$0")/../../.."
SEED=0 benchmarks/recipe_run.sh runs/recipe-ranking-60min-seed0
SEED=1 benchmarks/recipe_run.sh runs/recipe-ranking-60min-seed1
