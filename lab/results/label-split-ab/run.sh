#!/bin/bash
# Issue #16's split along the tool, seen by the detector (issue #15): TOG with the recipe's options trained on the
# recipe's samples labelled with the split (this commit) against the same samples labelled by the parts alone (the
# labels before the split: commit 3709887's data/manifests/recipe.json). The piles, images, boxes and grasp
# rectangles are the same; only the grasps' task labels differ. Side by side, one thread each, 40 minutes of training
# steps each, seed 0, on a 2-core AMD EPYC (2026-11-26); the protocol of lab/results/table-removal-ab/. Each arm is
# evaluated on its own labels of the same 206 test samples. SEED=1 lab/results/label-split-ab/run.sh for the second
# seed (runs/label-ab/seed1). Seed 0 ran before the SEED variable, into runs/label-ab/{split,parts}, as its eval.json
# commands say; the same training otherwise (togcrf train seeds 0 by default).
#
# The "parts" arm needs the samples shards of the labels before the split in the data dir: any data dir that built
# pipelines/recipe.toml before this change has them (shards are kept by key); otherwise build them from a worktree:
#     git worktree add /tmp/before 3709887 && (cd /tmp/before && .venv/bin/osgd --data-dir "$PWD/data" run pipelines/recipe.toml)
set -e
SEED=${SEED:-0}
cd "$(dirname "$0")/../../.."
.venv/bin/osgd --data-dir data --workers 2 run pipelines/recipe.toml
PARTS_DATA=runs/label-ab/parts-data
mkdir -p $PARTS_DATA/manifests
ln -sfn "$PWD/data/samples" $PARTS_DATA/samples
git show 3709887:data/manifests/recipe.json > $PARTS_DATA/manifests/recipe.json
OPTS="--model tog --backbone resnet18 --epochs 50 --image-size 192 --batch-size 4 --optimizer adamw --lr 0.001
 --lr-schedule cosine --warmup-steps 200 --scale-jitter 0.15 --val-samples 64 --time-budget 40 --device cpu
 --option fpn_min_stride=8 --option rpn_anchor_sizes=[16,32,64,128] --option fpn_channels=128
 --option box_batch_per_image=64 --option box_head_size=256 --option grasp_channels=128
 --option rpn_pre_nms_train=500 --option rpn_post_nms_train=250 --option grasp_anchor_size=12.0"
declare -A DATA=([split]=data [parts]=$PARTS_DATA)
OUT=runs/label-ab/seed$SEED
mkdir -p $OUT
for arm in split parts; do
    OMP_NUM_THREADS=1 .venv/bin/togcrf train --data ${DATA[$arm]} --pipeline recipe --out $OUT/$arm --seed $SEED \
        $OPTS > $OUT/$arm.log 2>&1 &
done
wait
for arm in split parts; do
    .venv/bin/togcrf eval $OUT/$arm/checkpoint.pt --data ${DATA[$arm]} --pipeline recipe --split test \
        --device cpu --speed-images 0 --out $OUT/$arm/eval.json
done
