#!/bin/bash
# A/B of a lighter network at the 60-minute budget: TOG, seed 1, the recipe's 60-minute command ("recipe")
# beside the same with the ResNet stopped after C4 (fpn_max_stride 16, RPN anchors of 32, 64, 128 px on the three
# levels left) at 160 px with the anchors scaled with the image ("c4-160"); "c4" is the C4 network at 192 px,
# "c4-160-rank" the c4-160 arm with the top-1 ranking term in the stability loss (run-ranking.sh).
# The arms run side by side on one thread each (the two cores of a 2-core machine), then each is evaluated on
# the recipe's test split under both protocols. Run from the repository root with the venv active.
# ARMS picks the arms (default: recipe c4-160); MODEL the model (default tog; run-tog-crfs.sh: tog-crfs).
set -e
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
OUT=${OUT:-runs/c4-ab-60min}
ARMS=${ARMS:-recipe c4-160}
MODEL=${MODEL:-tog}
SUFFIX=${MODEL#tog}   # "" for tog, "-crfs" for tog-crfs
mkdir -p $OUT
OPTS="--data data --pipeline recipe --model $MODEL --backbone resnet18 --epochs 50 --batch-size 4 --optimizer adamw --lr-schedule cosine --warmup-steps 200 --lr 0.001 --scale-jitter 0.15 --val-samples 64 --time-budget 60 --device cpu --seed 1 --option fpn_min_stride=8 --option fpn_channels=128 --option box_batch_per_image=64 --option box_head_size=256 --option grasp_channels=128 --option rpn_pre_nms_train=500 --option rpn_post_nms_train=250"
declare -A ARM_OPTS=(
  [recipe]="--image-size 192 --option rpn_anchor_sizes=[16,32,64,128] --option grasp_anchor_size=12.0"
  [c4]="--image-size 192 --option fpn_max_stride=16 --option rpn_anchor_sizes=[32,64,128] --option grasp_anchor_size=12.0"
  [c4-160]="--image-size 160 --option fpn_max_stride=16 --option rpn_anchor_sizes=[27,53,107] --option grasp_anchor_size=10.0"
  [c4-160-rank]="--image-size 160 --option fpn_max_stride=16 --option rpn_anchor_sizes=[27,53,107] --option grasp_anchor_size=10.0 --option grasp_ranking_weight=1.0"
)
date
for arm in $ARMS; do
  togcrf train $OPTS ${ARM_OPTS[$arm]} --out $OUT/$arm$SUFFIX > $OUT/$arm$SUFFIX.train.log 2>&1 &
done
wait
date
for arm in $ARMS; do
  for protocol in ours lab; do
    togcrf eval $OUT/$arm$SUFFIX/checkpoint.pt --data data --pipeline recipe --split test --device cpu --speed-images 10 \
      --protocol $protocol --out $OUT/$arm$SUFFIX/eval-$protocol.json >> $OUT/$arm$SUFFIX.eval.log 2>&1
  done
done
date
echo done > $OUT/DONE-${ARMS// /-}$SUFFIX
