#!/usr/bin/env bash
# The CPU recipe's changes one at a time (issue #15, item 1: "every change measured against the plain
# recipe on the same data"): TOG with the recipe, and with each change of the recipe undone, trained side
# by side on one GPU from the same seed and for the same time, then evaluated on the recipe's 206 test
# samples. A short budget (what a ten-minute device call leaves after building the data): this compares
# how fast each arm starts to learn, not where it ends.
#
#   arm        what differs from the recipe (togcrf.reproduce.CPU_SCALE)
#   recipe     nothing
#   no-norm    no GroupNorm in the FPN and on the grasp trunk (fpn_norm=false, grasp_trunk_norm=false)
#   anchor16   16 px grasp anchors instead of 12 px (the anchor before the recipe)
#   sgd        SGD with momentum 0.9 at lr 0.01 (the optimiser before the recipe; warm-up, cosine and the
#              clip at 10 kept)
#
# On the device machine (pipelines/table-gpu.sh's offline kit in .gpu/):
#   DEADLINE=480 WORKERS=16 lab/results/recipe-ablation/run.sh
# Writes into RESULTS (RUNS/results; packed into $OUT/results.tar.gz when OUT is set): dataset.txt,
# manifest.json, ARM/{eval.json,metrics.csv,config.json,train.log}, ablation.log. Run on 2026-11-25 with
# DEADLINE=400 on an H100 with 16 cores: the data took 3 min 18 s, each arm 1.44 minutes of steps (about
# 2,900 images, 1.7 epochs); the results are beside this script.
set -euo pipefail
cd "$(dirname "$0")/../../.."
started=$SECONDS
DEADLINE=${DEADLINE:-480}
WORKERS=${WORKERS:-$(nproc)}
DATA=${DATA:-/tmp/osgd-recipe-data}
RUNS=${RUNS:-/tmp/recipe-ablation}
RESULTS=${RESULTS:-$RUNS/results}
SITE=${SITE:-.gpu/site-py312.tar.xz}
SEED=${SEED:-0}
mkdir -p "$RUNS" "$RESULTS"
collect() {
    for arm in recipe no-norm anchor16 sgd; do
        mkdir -p "$RESULTS/$arm"
        cp "$RUNS/$arm"/{eval.json,metrics.csv,config.json,train.log} "$RUNS/$arm".*out "$RESULTS/$arm/" 2>/dev/null || true
    done
    # the device tool returns at most 8 files: one tarball
    [ -n "${OUT:-}" ] && tar -czf "$OUT/results.tar.gz" -C "$RESULTS" . || true
}
trap collect EXIT
say() { echo "ablation [$(date +%H:%M:%S), $((SECONDS - started)) s]: $*" | tee -a "$RESULTS/ablation.log"; }

source pipelines/gpu-kit.sh "$SITE"

say "building pipelines/recipe.toml with $WORKERS workers"
python3 -m osgd --data-dir "$DATA" --workers "$WORKERS" run pipelines/recipe.toml > "$RESULTS/dataset.txt" 2>&1
cp "$DATA/manifests/recipe.json" "$RESULTS/manifest.json"
cmp -s "$DATA/manifests/recipe.json" data/manifests/recipe.json && say "the manifest equals the tracked one" \
    || say "the manifest differs from the tracked one"

declare -A ARMS=(
    [recipe]=""
    [no-norm]="--option fpn_norm=false --option grasp_trunk_norm=false"
    [anchor16]="--option grasp_anchor_size=16.0"
    [sgd]="--optimizer sgd --lr 0.01"
)
RECIPE=(--data "$DATA" --pipeline recipe --model tog --backbone resnet18 --epochs 50 --image-size 192
        --batch-size 4 --optimizer adamw --lr 0.001 --lr-schedule cosine --warmup-steps 200 --scale-jitter 0.15
        --val-samples 64 --device cuda --workers 1 --seed "$SEED" --option fpn_min_stride=8
        --option 'rpn_anchor_sizes=[16,32,64,128]' --option fpn_channels=128 --option box_batch_per_image=64
        --option box_head_size=256 --option grasp_channels=128 --option rpn_pre_nms_train=500
        --option rpn_post_nms_train=250 --option grasp_anchor_size=12.0)
# minutes of training steps: what is left after the data, less start-up, per-epoch validation and evaluation
minutes=$(python3 -c "print(round(max(0.5, ($DEADLINE - $((SECONDS - started)) - 100) / 60 * 0.85), 2))")
say "training ${!ARMS[*]} side by side for $minutes minutes of steps each"
for arm in "${!ARMS[@]}"; do
    # shellcheck disable=SC2086
    OMP_NUM_THREADS=3 python3 -m togcrf --log-level info train "${RECIPE[@]}" ${ARMS[$arm]} \
        --time-budget "$minutes" --out "$RUNS/$arm" > "$RUNS/$arm.out" 2>&1 &
done
wait
for arm in "${!ARMS[@]}"; do
    OMP_NUM_THREADS=3 python3 -m togcrf eval "$RUNS/$arm/checkpoint.pt" --data "$DATA" --pipeline recipe \
        --split test --device cuda --speed-images 0 --out "$RUNS/$arm/eval.json" > "$RUNS/$arm.eval.out" 2>&1 &
done
wait
say "done"
