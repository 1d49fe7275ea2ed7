#!/usr/bin/env bash
# The grasp head's object map (ModelOptions.grasp_object_map, issue #15) against the recipe: TOG with the
# CPU recipe (togcrf.reproduce.CPU_SCALE's options, as lab/results/recipe-ablation/run.sh spells them) and
# the same with --option grasp_object_map=true, trained side by side on one GPU from the same seed for the
# same minutes of steps, then evaluated on the recipe's 206 test samples (our protocol), and the
# grasp-landing diagnosis (benchmarks/grasp_ranking.py) of each on 60 test samples.
#
# On the device machine (pipelines/table-gpu.sh's offline kit in .gpu/, carried):
#   DEADLINE=560 WORKERS=16 lab/results/object-map-ab/run.sh
# Writes into RESULTS (RUNS/results; packed into $OUT/results.tar.gz when OUT is set): dataset.txt,
# ARM/{eval.json,metrics.csv,config.json,train.log,landing.json}, ab.log.
set -euo pipefail
cd "$(dirname "$0")/../../.."
started=$SECONDS
DEADLINE=${DEADLINE:-560}
WORKERS=${WORKERS:-$(nproc)}
DATA=${DATA:-/tmp/osgd-recipe-data}
RUNS=${RUNS:-/tmp/object-map-ab}
RESULTS=${RESULTS:-$RUNS/results}
SITE=${SITE:-.gpu/site-py312.tar.xz}
SEED=${SEED:-0}
ARMS=(recipe object-map)
mkdir -p "$RUNS" "$RESULTS"
collect() {
    for arm in "${ARMS[@]}"; do
        mkdir -p "$RESULTS/$arm"
        cp "$RUNS/$arm"/{eval.json,metrics.csv,config.json,train.log,landing.json} "$RUNS/$arm".*out \
            "$RESULTS/$arm/" 2>/dev/null || true
    done
    [ -n "${OUT:-}" ] && tar -czf "$OUT/results.tar.gz" -C "$RESULTS" . || true
}
trap collect EXIT
say() { echo "object-map A/B [$(date +%H:%M:%S), $((SECONDS - started)) s]: $*" | tee -a "$RESULTS/ab.log"; }

source pipelines/gpu-kit.sh "$SITE"
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader | tee -a "$RESULTS/ab.log" || true

say "building pipelines/recipe.toml with $WORKERS workers"
python3 -m osgd --data-dir "$DATA" --workers "$WORKERS" run pipelines/recipe.toml > "$RESULTS/dataset.txt" 2>&1
say "data built"

declare -A OPTIONS=([recipe]="" [object-map]="--option grasp_object_map=true")
RECIPE=(--data "$DATA" --pipeline recipe --model tog --backbone resnet18 --epochs 50 --image-size 192
        --batch-size 4 --optimizer adamw --lr 0.001 --lr-schedule cosine --warmup-steps 200 --scale-jitter 0.15
        --val-samples 64 --device cuda --workers 2 --seed "$SEED" --option fpn_min_stride=8
        --option 'rpn_anchor_sizes=[16,32,64,128]' --option fpn_channels=128 --option box_batch_per_image=64
        --option box_head_size=256 --option grasp_channels=128 --option rpn_pre_nms_train=500
        --option rpn_post_nms_train=250 --option grasp_anchor_size=12.0)
# minutes of training steps: what is left after the data, less start-up, per-epoch validation and evaluation
minutes=$(python3 -c "print(round(max(0.5, ($DEADLINE - $((SECONDS - started)) - 110) / 60 * 0.85), 2))")
say "training ${ARMS[*]} side by side for $minutes minutes of steps each"
for arm in "${ARMS[@]}"; do
    # shellcheck disable=SC2086
    OMP_NUM_THREADS=4 python3 -m togcrf --log-level info train "${RECIPE[@]}" ${OPTIONS[$arm]} \
        --time-budget "$minutes" --out "$RUNS/$arm" > "$RUNS/$arm.out" 2>&1 &
done
wait
say "trained; evaluating"
for arm in "${ARMS[@]}"; do
    (OMP_NUM_THREADS=4 python3 -m togcrf eval "$RUNS/$arm/checkpoint.pt" --data "$DATA" --pipeline recipe \
        --split test --device cuda --speed-images 0 --out "$RUNS/$arm/eval.json" > "$RUNS/$arm.eval.out" 2>&1
     OMP_NUM_THREADS=4 python3 benchmarks/grasp_ranking.py "$RUNS/$arm/checkpoint.pt" --data "$DATA" \
        --pipeline recipe --max-samples 60 --json "$RUNS/$arm/landing.json" > "$RUNS/$arm.landing.out" 2>&1) &
done
wait
say "done"
