#!/bin/bash
# A/B fine-tune of the grasp matching (issue #15): same start, data, budget; one core each.
cd /work/main
COMMON="--data data --pipeline recipe --model tog --backbone resnet18 --image-size 192 --batch-size 4 --optimizer adamw --lr-schedule cosine --lr 2e-4 --warmup-steps 20 --scale-jitter 0.15 --val-samples 64 --time-budget 12 --epochs 50 --init runs/cpu-recipe-2cores/tog/checkpoint.pt --device cpu"
OPTS="--option fpn_min_stride=8 --option rpn_anchor_sizes=[16,32,64,128] --option fpn_channels=128 --option box_batch_per_image=64 --option box_head_size=256 --option grasp_channels=128 --option rpn_pre_nms_train=500 --option rpn_post_nms_train=250 --option grasp_anchor_size=12.0"
export OMP_NUM_THREADS=1
.venv/bin/togcrf train $COMMON $OPTS --out runs/ab/base > runs/ab/base.out 2>&1 &
.venv/bin/togcrf train $COMMON $OPTS --option grasp_positive_radius=1 --option grasp_ignore_radius=1 --out runs/ab/near > runs/ab/near.out 2>&1 &
wait
for r in base near; do
  .venv/bin/togcrf eval runs/ab/$r/checkpoint.pt --data data --pipeline recipe --out runs/ab/$r/eval.json --device cpu > runs/ab/$r.eval.out 2>&1 &
done
wait
