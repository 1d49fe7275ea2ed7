#!/bin/bash
# A/B of the recipe's learning rate at the 60-minute budget: TOG, seed 1, the recipe (lr 0.001) beside
# lr 0.002, side by side on one thread each (the two cores of a 2-core machine), then both evaluated on
# the recipe's test split under both protocols. Run from the repository root with the venv active.
# LRS picks the arms (run-lr0.0005.sh: the third arm alone).
set -e
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
OUT=${OUT:-runs/lr-ab-60min}
LRS=${LRS:-0.001 0.002}
mkdir -p $OUT
OPTS="--data data --pipeline recipe --model tog --backbone resnet18 --epochs 50 --image-size 192 --batch-size 4 --optimizer adamw --lr-schedule cosine --warmup-steps 200 --scale-jitter 0.15 --val-samples 64 --time-budget 60 --device cpu --seed 1 --option fpn_min_stride=8 --option rpn_anchor_sizes=[16,32,64,128] --option fpn_channels=128 --option box_batch_per_image=64 --option box_head_size=256 --option grasp_channels=128 --option rpn_pre_nms_train=500 --option rpn_post_nms_train=250 --option grasp_anchor_size=12.0"
date
for lr in $LRS; do
  togcrf train $OPTS --lr $lr --out $OUT/lr$lr > $OUT/lr$lr.train.log 2>&1 &
done
wait
date
for lr in $LRS; do
  for protocol in ours lab; do
    togcrf eval $OUT/lr$lr/checkpoint.pt --data data --pipeline recipe --split test --device cpu --speed-images 10 \
      --protocol $protocol --out $OUT/lr$lr/eval-$protocol.json >> $OUT/lr$lr.eval.log 2>&1
  done
done
date
echo done > $OUT/DONE-${LRS// /-}
