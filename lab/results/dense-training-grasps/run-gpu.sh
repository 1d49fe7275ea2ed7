#!/usr/bin/env bash
# Issue #15: the dense-grasp A/B of run.sh (TOG trained on the recipe's suppressed grasps against every usable
# grasp, pipelines/recipe-dense.toml), two seeds per arm, at an epoch budget towards the image count of the
# 60-minute recipe on a 2-core AMD EPYC (16,800 images): EPOCHS (default 7: 12,110 images) of the 1,730 training
# images, the cosine over those steps, the four jobs side by side on one GPU. Each evaluated on the recipe's test
# split (the recipe's ground truth) under both protocols, and with every usable grasp (eval-on-dense.json).
#
# On the device machine, with the offline kit (.gpu/, pipelines/gpu-offline-kit.sh) and the recipe's models,
# grasps, checks and scenes shards built on the 2-core machine carried (same keys and bytes); the samples are
# rendered there:
#   DEADLINE=540 WORKERS=16 lab/results/dense-training-grasps/run-gpu.sh
# Writes into RESULTS (RUNS/results; packed into $OUT/results.tar.gz when OUT is set): dataset-*.txt, ab.log,
# seedS/ARM/{eval.json,eval-lab.json,eval-on-dense.json,metrics.csv,config.json,train.log}.
set -euo pipefail
cd "$(dirname "$0")/../../.."
started=$SECONDS
DEADLINE=${DEADLINE:-540}
WORKERS=${WORKERS:-$(nproc)}
EPOCHS=${EPOCHS:-7}
DATA=${DATA:-data}
RUNS=${RUNS:-/tmp/dense-ab-gpu}
RESULTS=${RESULTS:-$RUNS/results}
SITE=${SITE:-.gpu/site-py312.tar.xz}
ARMS=(recipe recipe-dense)
SEEDS=(0 1)
mkdir -p "$RUNS" "$RESULTS"
collect() {
    for seed in "${SEEDS[@]}"; do
        for arm in "${ARMS[@]}"; do
            local run="$RUNS/seed$seed/$arm"
            mkdir -p "$RESULTS/seed$seed/$arm"
            cp "$run"/{eval.json,eval-lab.json,eval-on-dense.json,metrics.csv,config.json,train.log} \
                "$RESULTS/seed$seed/$arm/" 2>/dev/null || true
        done
    done
    [ -n "${OUT:-}" ] && tar -czf "$OUT/results.tar.gz" -C "$RESULTS" . || true
}
trap collect EXIT
say() { echo "dense A/B [$(date +%H:%M:%S), $((SECONDS - started)) s]: $*" | tee -a "$RESULTS/ab.log"; }

source pipelines/gpu-kit.sh "$SITE"
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader | tee -a "$RESULTS/ab.log" || true

for arm in "${ARMS[@]}"; do
    say "building pipelines/$arm.toml with $WORKERS workers"
    python3 -m osgd --data-dir "$DATA" --workers "$WORKERS" run "pipelines/$arm.toml" > "$RESULTS/dataset-$arm.txt" 2>&1
done
say "data built"

RECIPE=(--data "$DATA" --model tog --backbone resnet18 --epochs "$EPOCHS" --image-size 192
        --batch-size 4 --optimizer adamw --lr 0.001 --lr-schedule cosine --warmup-steps 200 --scale-jitter 0.15
        --val-samples 64 --device cuda --workers 1 --option fpn_min_stride=8
        --option 'rpn_anchor_sizes=[16,32,64,128]' --option fpn_channels=128 --option box_batch_per_image=64
        --option box_head_size=256 --option grasp_channels=128 --option rpn_pre_nms_train=500
        --option rpn_post_nms_train=250 --option grasp_anchor_size=12.0)
# the training stops, with its last epoch's checkpoint, where the evaluations would no longer fit
seconds=$((DEADLINE - (SECONDS - started) - 75))
say "training ${ARMS[*]} x seeds ${SEEDS[*]} side by side, $EPOCHS epochs each, at most $seconds s"
for seed in "${SEEDS[@]}"; do
    for arm in "${ARMS[@]}"; do
        mkdir -p "$RUNS/seed$seed/$arm"
        OMP_NUM_THREADS=4 timeout "$seconds" python3 -m togcrf --log-level info train "${RECIPE[@]}" \
            --pipeline "$arm" --seed "$seed" --out "$RUNS/seed$seed/$arm" > "$RUNS/seed$seed/$arm/train.log" 2>&1 &
    done
done
wait || true
say "trained; evaluating"
left=$((DEADLINE + 40 - (SECONDS - started)))
for seed in "${SEEDS[@]}"; do
    for arm in "${ARMS[@]}"; do
        run="$RUNS/seed$seed/$arm"
        for protocol in ours lab; do
            suffix=""; [ "$protocol" = lab ] && suffix="-lab"
            OMP_NUM_THREADS=2 timeout "$left" python3 -m togcrf eval "$run/checkpoint.pt" --data "$DATA" --pipeline recipe \
                --split test --device cuda --speed-images 0 --protocol "$protocol" \
                --out "$run/eval$suffix.json" > "$run/eval$suffix.out" 2>&1 &
        done
        OMP_NUM_THREADS=2 timeout "$left" python3 -m togcrf eval "$run/checkpoint.pt" --data "$DATA" --pipeline recipe-dense \
            --split test --device cuda --speed-images 0 --out "$run/eval-on-dense.json" > "$run/eval-on-dense.out" 2>&1 &
    done
done
wait || true
say "done"
