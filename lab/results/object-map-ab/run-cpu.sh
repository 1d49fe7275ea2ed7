#!/bin/bash
# Issue #15: the object map (--option grasp_object_map=true) against the recipe on the CPU, the protocol of
# lab/results/dense-training-grasps/run.sh (60min-ab/): TOG with the recipe's options, both arms side by side at one
# thread each on a 2-core AMD EPYC, 60 minutes of training steps each, seed 1 (the GPU A/B of run.sh was seed 0),
# evaluated on the recipe's 206 test samples (our protocol) and diagnosed with benchmarks/grasp_ranking.py.
set -e
cd "$(dirname "$0")/../../.."
.venv/bin/osgd --data-dir data --workers 2 run pipelines/recipe.toml
OPTS="--model tog --backbone resnet18 --epochs 50 --image-size 192 --batch-size 4 --optimizer adamw --lr 0.001
 --lr-schedule cosine --warmup-steps 200 --scale-jitter 0.15 --val-samples 64 --time-budget 60 --device cpu
 --option fpn_min_stride=8 --option rpn_anchor_sizes=[16,32,64,128] --option fpn_channels=128
 --option box_batch_per_image=64 --option box_head_size=256 --option grasp_channels=128
 --option rpn_pre_nms_train=500 --option rpn_post_nms_train=250 --option grasp_anchor_size=12.0 --seed 1"
mkdir -p runs/object-map-ab-cpu
declare -A EXTRA=([recipe]="" [object-map]="--option grasp_object_map=true")
for arm in recipe object-map; do
    # shellcheck disable=SC2086
    OMP_NUM_THREADS=1 .venv/bin/togcrf train --data data --pipeline recipe --out runs/object-map-ab-cpu/$arm \
        $OPTS ${EXTRA[$arm]} > runs/object-map-ab-cpu/$arm.out 2>&1 &
done
wait
for arm in recipe object-map; do
    (OMP_NUM_THREADS=1 .venv/bin/togcrf eval runs/object-map-ab-cpu/$arm/checkpoint.pt --data data --pipeline recipe \
        --split test --device cpu --speed-images 0 --out runs/object-map-ab-cpu/$arm/eval.json
     .venv/bin/python benchmarks/grasp_ranking.py runs/object-map-ab-cpu/$arm/checkpoint.pt --data data \
        --pipeline recipe --max-samples 60 --json runs/object-map-ab-cpu/$arm/landing.json) &
done
wait
for arm in recipe object-map; do
    mkdir -p lab/results/object-map-ab/cpu-seed1/$arm
    cp runs/object-map-ab-cpu/$arm/{eval.json,landing.json,metrics.csv,config.json} \
        lab/results/object-map-ab/cpu-seed1/$arm/
done
