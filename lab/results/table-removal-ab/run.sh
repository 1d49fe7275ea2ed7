#!/bin/bash
# Issue #15: the recipe's table-plane removal alone. TOG with the recipe's options on the recipe's data, the input
# measured from the fitted table plane (--depth-reference table, the recipe) against the image's median depth
# (--depth-reference median, before the recipe: the 2-3 cm camera-tilt ramp stays in the image). Side by side, one
# thread each, 40 minutes of training steps each, seed 0, on a 2-core AMD EPYC (2026-11-25); the table arm is the
# same command as lab/results/dense-training-grasps/'s recipe arm, so it also shows how much a rerun moves.
set -e
cd "$(dirname "$0")/../../.."
.venv/bin/osgd --data-dir data --workers 2 run pipelines/recipe.toml
mkdir -p runs/table-ab
OPTS="--model tog --backbone resnet18 --epochs 50 --image-size 192 --batch-size 4 --optimizer adamw --lr 0.001
 --lr-schedule cosine --warmup-steps 200 --scale-jitter 0.15 --val-samples 64 --time-budget 40 --device cpu
 --option fpn_min_stride=8 --option rpn_anchor_sizes=[16,32,64,128] --option fpn_channels=128
 --option box_batch_per_image=64 --option box_head_size=256 --option grasp_channels=128
 --option rpn_pre_nms_train=500 --option rpn_post_nms_train=250 --option grasp_anchor_size=12.0"
for reference in table median; do
    OMP_NUM_THREADS=1 .venv/bin/togcrf train --data data --pipeline recipe --out runs/table-ab/$reference \
        --depth-reference $reference $OPTS > runs/table-ab/$reference.log 2>&1 &
done
wait
for reference in table median; do
    .venv/bin/togcrf eval runs/table-ab/$reference/checkpoint.pt --data data --pipeline recipe --split test \
        --device cpu --speed-images 0 --out runs/table-ab/$reference/eval.json
done
