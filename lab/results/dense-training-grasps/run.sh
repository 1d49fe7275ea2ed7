#!/bin/bash
# Issue #15: TOG trained on the recipe's grasps (the paper's suppression, 3.9 grasps per object) against the same
# piles and images with every usable grasp (pipelines/recipe-dense.toml, 18 per object); both evaluated on the
# recipe's test split (the recipe's ground truth, eval.json) and on the same images with every usable grasp
# (eval-on-dense.json). Side by side, one thread each, 40 minutes of training steps each, seed 0, on a 2-core
# AMD EPYC (2026-11-25; about 2.3 images/s each, 3.4 epochs). The run of 2026-11-25 named the dense data
# "recipe-nms0" (`osgd run pipelines/recipe.toml --set pipeline.name=recipe-nms0 --set samples.nms_radius=0`):
# the same shards as recipe-dense (the manifests differ only in the name).
set -e
cd "$(dirname "$0")/../../.."
.venv/bin/osgd --data-dir data --workers 2 run pipelines/recipe.toml
.venv/bin/osgd --data-dir data --workers 2 run pipelines/recipe-dense.toml
OPTS="--model tog --backbone resnet18 --epochs 50 --image-size 192 --batch-size 4 --optimizer adamw --lr 0.001
 --lr-schedule cosine --warmup-steps 200 --scale-jitter 0.15 --val-samples 64 --time-budget 40 --device cpu
 --option fpn_min_stride=8 --option rpn_anchor_sizes=[16,32,64,128] --option fpn_channels=128
 --option box_batch_per_image=64 --option box_head_size=256 --option grasp_channels=128
 --option rpn_pre_nms_train=500 --option rpn_post_nms_train=250 --option grasp_anchor_size=12.0"
for arm in recipe recipe-dense; do
    OMP_NUM_THREADS=1 .venv/bin/togcrf train --data data --pipeline $arm --out runs/dense-ab/$arm $OPTS &
done
wait
for arm in recipe recipe-dense; do
    .venv/bin/togcrf eval runs/dense-ab/$arm/checkpoint.pt --data data --pipeline recipe --split test \
        --device cpu --speed-images 0 --out runs/dense-ab/$arm/eval.json
    .venv/bin/togcrf eval runs/dense-ab/$arm/checkpoint.pt --data data --pipeline recipe-dense --split test \
        --device cpu --speed-images 0 --out runs/dense-ab/$arm/eval-on-dense.json
done

# seed1/: the same A/B with --seed 1, side by side at one thread each (2026-11-26, the same kind of 2-core AMD EPYC;
# 2.2 images/s each, 5,450 and 5,490 images; a test run and step timings shared the machine for a few minutes)
for arm in recipe recipe-dense; do
    OMP_NUM_THREADS=1 .venv/bin/togcrf train --data data --pipeline $arm --out runs/dense-ab-seed1/$arm $OPTS --seed 1 &
done
wait
for arm in recipe recipe-dense; do
    .venv/bin/togcrf eval runs/dense-ab-seed1/$arm/checkpoint.pt --data data --pipeline recipe --split test \
        --device cpu --speed-images 0 --out runs/dense-ab-seed1/$arm/eval.json
    .venv/bin/togcrf eval runs/dense-ab-seed1/$arm/checkpoint.pt --data data --pipeline recipe-dense --split test \
        --device cpu --speed-images 0 --out runs/dense-ab-seed1/$arm/eval-on-dense.json
    mkdir -p lab/results/dense-training-grasps/seed1/$arm
    cp runs/dense-ab-seed1/$arm/{eval.json,eval-on-dense.json,metrics.csv,config.json} \
        lab/results/dense-training-grasps/seed1/$arm/
done

# 60min/: TOG on recipe-dense alone on both cores (2 threads) for the recipe's 60-minute budget, the command of
# lab/results/cpu-recipe-60min-epyc/ with --pipeline recipe-dense; evaluated on recipe's test split, both protocols.
.venv/bin/togcrf train --data data --pipeline recipe-dense --out runs/dense-60min/tog ${OPTS/--time-budget 40/--time-budget 60}
.venv/bin/togcrf eval runs/dense-60min/tog/checkpoint.pt --data data --pipeline recipe --split test --device cpu \
    --speed-images 10 --out runs/dense-60min/tog/eval.json
.venv/bin/togcrf eval runs/dense-60min/tog/checkpoint.pt --data data --pipeline recipe --split test --device cpu \
    --speed-images 0 --protocol lab --out runs/dense-60min/tog/eval-lab.json

# 60min-ab/: the same A/B for 60 minutes of training steps each (side by side, one thread each, seed 0; 2026-11-26,
# the 2-core AMD EPYC of seed1/, AdamW fused; 2.3 images/s each: 8,520 and 8,360 images, 4.9 epochs)
for arm in recipe recipe-dense; do
    OMP_NUM_THREADS=1 .venv/bin/togcrf train --data data --pipeline $arm --out runs/dense-ab-60/$arm \
        ${OPTS/--time-budget 40/--time-budget 60} --seed 0 &
done
wait
for arm in recipe recipe-dense; do
    .venv/bin/togcrf eval runs/dense-ab-60/$arm/checkpoint.pt --data data --pipeline recipe --split test \
        --device cpu --speed-images 0 --out runs/dense-ab-60/$arm/eval.json
    .venv/bin/togcrf eval runs/dense-ab-60/$arm/checkpoint.pt --data data --pipeline recipe-dense --split test \
        --device cpu --speed-images 0 --out runs/dense-ab-60/$arm/eval-on-dense.json
    mkdir -p lab/results/dense-training-grasps/60min-ab/$arm
    cp runs/dense-ab-60/$arm/{eval.json,eval-on-dense.json,metrics.csv,config.json} \
        lab/results/dense-training-grasps/60min-ab/$arm/
done
