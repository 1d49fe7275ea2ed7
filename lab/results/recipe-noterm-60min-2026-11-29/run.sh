#!/bin/bash
# Issue #15: the same-day baseline of lab/results/recipe-ranking-60min-2026-11-29/ and
# lab/results/grid14-60min-2026-11-29/: the recipe without the top-1 ranking term (`--option grasp_ranking_weight=0`
# after the options of togcrf.reproduce.CPU_SCALE), otherwise the same command: TOG, 60 minutes of training steps on
# both cores (2 threads, the time budget, bfloat16 on a CPU with AVX-512 BF16), seed 0, then scored on the 206 test
# samples (benchmarks/score_run.sh: both protocols, grasp_ranking.py). As run on 2026-11-29 right after the grid run,
# nothing else running beside it.
cd "$(dirname "$0")/../../.."
SEED=0 benchmarks/recipe_run.sh runs/recipe-noterm-60min-seed0 --option grasp_ranking_weight=0
