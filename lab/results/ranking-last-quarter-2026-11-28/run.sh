#!/bin/bash
# Issue #15: the top-1 ranking term in the last quarter of the 60-minute budget, TOG, seed 0, bfloat16, 2 threads.
# Phase 1: the recipe (as `togcrf reproduce --scale cpu --models tog --cpu-bf16`) with a 45-minute budget.
# Phase 2, two arms one after the other from the phase-1 checkpoint, 15 minutes each (AdamW, cosine from lr 2e-4,
# 20 warm-up steps, as lab/results/ranking-finetune-2026-11-27): "rank" with grasp_ranking_weight 1.0, "plain"
# with the recipe's loss (the control). Each arm has had 60 minutes of training steps in all.
# Then both protocols of togcrf eval and grasp_ranking.py on the 206 test samples. Dates go to $OUT/dates.log.
cd "$(dirname "$0")/../../.."
OUT=${OUT:-runs/rank-last-quarter}
mkdir -p "$OUT"
export OMP_NUM_THREADS=2 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=2
COMMON="--data data --pipeline recipe --model tog --backbone resnet18 --image-size 160 --batch-size 4 --optimizer adamw --lr-schedule cosine --scale-jitter 0.15 --val-samples 64 --epochs 50 --seed 0 --device cpu --cpu-bf16"
OPTS="--option fpn_min_stride=8 --option fpn_max_stride=16 --option rpn_anchor_sizes=[27,53,107] --option fpn_channels=128 --option box_batch_per_image=64 --option box_head_size=256 --option grasp_channels=128 --option rpn_pre_nms_train=500 --option rpn_post_nms_train=250 --option grasp_anchor_size=10.0"
log() { echo "$(date -u +%FT%TZ) $*" >> "$OUT/dates.log"; }
if [ ! -f "$OUT/first45/checkpoint.pt" ]; then
  log "phase 1 start"
  .venv/bin/togcrf train $COMMON $OPTS --lr 1e-3 --warmup-steps 200 --time-budget 45 --out "$OUT/first45" \
    > "$OUT/first45.out" 2>&1 || exit 1
  log "phase 1 end"
fi
for arm in rank plain; do
  extra=""; [ "$arm" = rank ] && extra="--option grasp_ranking_weight=1.0"
  log "phase 2 $arm start"
  .venv/bin/togcrf train $COMMON $OPTS $extra --lr 2e-4 --warmup-steps 20 --time-budget 15 \
    --init "$OUT/first45/checkpoint.pt" --out "$OUT/$arm" > "$OUT/$arm.out" 2>&1 || exit 1
  log "phase 2 $arm end"
  .venv/bin/togcrf eval "$OUT/$arm/checkpoint.pt" --data data --pipeline recipe --out "$OUT/$arm/eval.json" \
    --device cpu > "$OUT/$arm.eval.out" 2>&1
  .venv/bin/togcrf eval "$OUT/$arm/checkpoint.pt" --data data --pipeline recipe --protocol lab \
    --out "$OUT/$arm/eval-lab.json" --device cpu > "$OUT/$arm.eval-lab.out" 2>&1
  .venv/bin/python benchmarks/grasp_ranking.py "$OUT/$arm/checkpoint.pt" --data data --pipeline recipe \
    --max-samples 1000 --json "$OUT/$arm/grasp-ranking.json" > "$OUT/$arm/grasp-ranking.txt" 2>&1
  log "phase 2 $arm evaluated"
done
