#!/bin/bash
# Issue #15: a first look at grasp_regression_radius by fine-tuning the seed-0 bfloat16 recipe checkpoint
# (runs/recipe-2cores-bf16-2026-11-28/tog, lab/results/recipe-2cores-bf16-2026-11-28) with radius 1 and, as the
# control, 0 (the recipe's loss), the two arms side by side at one thread each:
#   PART=conv: only the regression convolution trains (grasp_head.regression), 7 minutes, lr 1e-3;
#   PART=head: the whole grasp head trains (grasp_head), 12 minutes, lr 3e-4.
# RADII (default "1 0") lists the arms. Then togcrf eval of each arm and top1_cells.py. Outputs:
# runs/regrad-ft/{r0,r1,head-r0,head-r1} (and head-r0.5 with PART=head RADII=0.5).
HERE=$(cd "$(dirname "$0")" && pwd)
cd "$HERE/../../.."
PART=${PART:-head}
OUT=runs/regrad-ft
mkdir -p $OUT
source lab/results/confidence-head-2026-11-28/recipe-options.sh
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
if [ "$PART" = conv ]; then PREFIX=grasp_head.regression LR=1e-3 MINUTES=7 NAME=r; else PREFIX=grasp_head LR=3e-4 MINUTES=12 NAME=head-r; fi
for R in ${RADII:-1 0}; do
  .venv/bin/togcrf train $COMMON $OPTS --option grasp_regression_radius=$R \
    --init runs/recipe-2cores-bf16-2026-11-28/tog/checkpoint.pt --train-only $PREFIX --lr $LR --warmup-steps 20 \
    --time-budget $MINUTES --out $OUT/$NAME$R > $OUT/$NAME$R.out 2>&1 &
done
wait
for R in ${RADII:-1 0}; do
  .venv/bin/togcrf eval $OUT/$NAME$R/checkpoint.pt --data data --pipeline recipe --device cpu --out $OUT/$NAME$R/eval.json
  .venv/bin/python "$HERE/top1_cells.py" $OUT/$NAME$R/checkpoint.pt > $OUT/$NAME$R/top1-cells.txt
done
