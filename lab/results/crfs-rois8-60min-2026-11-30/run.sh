#!/bin/bash
# Issue #15, Table II's TOG-CRFs row with the recipe as it is since 2026-11-29 22:30 UTC (togcrf.reproduce.CPU_SCALE:
# bfloat16, the top-1 ranking term at 0.2, 8 grasp RoIs per image): 60 minutes of training steps on both cores,
# seed SEED (default 0), evaluated by `togcrf reproduce` under both protocols; then where the top-1 grasp lands
# (benchmarks/grasp_ranking.py) and the robot experiment in simulation (Table III, 1 view, the paper's 160 trials,
# 2 processes), alone and beside the recipe's two TOG checkpoints (runs/robot-rois8-views1 of
# lab/results/robot-rois8-60min-2026-11-29/run.sh).
#
# Seed 0 (2026-11-30 01:19:48-02:32:16 UTC): nothing else ran beside the training; the session ran these steps from
# /tmp/s/crfs.sh and /tmp/s/chain4.sh (which went on with lab/results/top1-categories-2026-11-30/,
# lab/results/label-ceiling-2026-11-30/ and `make test`). A first seed 1 was started at 02:40:52 UTC and stopped a
# minute later, to give the machine to lab/results/dense-rois8-60min-2026-11-30/.
# Seed 1 (2026-11-30 04:11:33-05:23:42 UTC, from /tmp/s/crfs1.sh, the same steps; robot-table run afterwards): the
# diagnostics of lab/results/top1-filters-2026-11-30/ ran beside its first 8 minutes (three runs of about 30 s and
# short tests of the script); its epochs 1, 2 and 4 ran at 11.2, 10.6 and 15.0 images/s instead of 18.4-19.6, about
# 160 s of its 3,600 (4.5 %); its results are in seed1-perturbed/ and robot-seed1-perturbed/. Seed 1 was run again
# alone (2026-11-30 08:23:15-09:35:58 UTC, this script itself, after the session had renamed the first run's
# folders under runs/ with the suffix -perturbed): seed1/ and robot-seed1/. The dates are in seedN/dates.log.
#
#     lab/results/crfs-rois8-60min-2026-11-30/run.sh          # seed 0
#     SEED=1 lab/results/crfs-rois8-60min-2026-11-30/run.sh   # seed 1
cd "$(dirname "$0")/../../.."
SEED=${SEED:-0}
OUT=runs/crfs-rois8-60min-seed$SEED
mkdir -p $OUT
OMP_NUM_THREADS=2 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=2 .venv/bin/togcrf reproduce --data data --pipeline recipe \
  --out $OUT --scale cpu --models tog-crfs --seed $SEED --device cpu > $OUT/reproduce.out 2>&1
OMP_NUM_THREADS=2 .venv/bin/python benchmarks/grasp_ranking.py $OUT/tog-crfs/checkpoint.pt --data data \
  --pipeline recipe --max-samples 1000 --json $OUT/tog-crfs/grasp-ranking.json > $OUT/tog-crfs/grasp-ranking.txt
OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 .venv/bin/togcrf robot-eval $OUT/tog-crfs/checkpoint.pt \
  --config pipelines/recipe.toml --data data --workers 2 --no-pictures --baselines '' --out runs/robot-crfs-rois8-seed$SEED
.venv/bin/togcrf robot-table runs/robot-rois8-views1/trials.parquet runs/robot-crfs-rois8-seed$SEED/trials.parquet \
  --out runs/robot-crfs-rois8-seed$SEED-beside-tog      # seed 0: --out runs/robot-crfs-rois8
