#!/bin/bash
# Seed 1 of TOG and TOG-CRFs, the 60-minute recipe, side by side, one thread each.
cd /work/main && source .venv/bin/activate
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
OUT=runs/cpu-recipe-60min-c/seed1
mkdir -p $OUT
OPTS="--data data --pipeline recipe --backbone resnet18 --epochs 50 --image-size 192 --batch-size 4 --optimizer adamw --lr 0.001 --lr-schedule cosine --warmup-steps 200 --scale-jitter 0.15 --val-samples 64 --time-budget 60 --device cpu --seed 1 --option fpn_min_stride=8 --option rpn_anchor_sizes=[16,32,64,128] --option fpn_channels=128 --option box_batch_per_image=64 --option box_head_size=256 --option grasp_channels=128 --option rpn_pre_nms_train=500 --option rpn_post_nms_train=250 --option grasp_anchor_size=12.0"
date
for m in tog tog-crfs; do
  togcrf train $OPTS --model $m --out $OUT/$m > $OUT/$m.train.log 2>&1 &
done
wait
date
for m in tog tog-crfs; do
  togcrf eval $OUT/$m/checkpoint.pt --data data --pipeline recipe --split test --device cpu --speed-images 10 --out $OUT/$m/eval.json > $OUT/$m.eval.log 2>&1
  togcrf eval $OUT/$m/checkpoint.pt --data data --pipeline recipe --split test --device cpu --speed-images 10 --protocol lab --out $OUT/$m/eval-lab.json >> $OUT/$m.eval.log 2>&1
done
date
echo done > $OUT/DONE
