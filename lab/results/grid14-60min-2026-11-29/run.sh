#!/bin/bash
# Issue #15: the recipe (togcrf.reproduce.CPU_SCALE, with the top-1 ranking term at 0.2) with a finer grid of grasp
# candidates: 14 x 14 cells per RoI instead of 7 x 7 (`grasp_grid=14`), the anchors within a cell of an annotated
# grasp never mined as hard negatives (`grasp_ignore_radius=0.5`, in the finer cells). TOG, 60 minutes of training
# steps on both cores (2 threads, the time budget, bfloat16 on a CPU with AVX-512 BF16), seed 0, then scored on the
# 206 test samples (benchmarks/score_run.sh: both protocols, grasp_ranking.py). As run on 2026-11-29 from 17:12 UTC,
# nothing else running beside it, followed by lab/results/recipe-noterm-60min-2026-11-29/ (seed 0).
cd "$(dirname "$0")/../../.."
SEED=0 benchmarks/recipe_run.sh runs/grid14-60min-seed0 --option grasp_grid=14 --option grasp_ignore_radius=0.5
