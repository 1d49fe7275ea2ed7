#!/bin/bash
# Diagnostic (issue #15): can the top-1 grasp ranking be learned from a trained detector's features?
# Both arms fine-tune the 2-core recipe checkpoint of seed 0 (runs/recipe-2cores-2026-11-27/tog) for 15 minutes of
# training steps at lr 2e-4 (AdamW, cosine, 20 warm-up steps), one thread each, side by side: "continue" with the
# recipe's loss, "rank" with the top-1 ranking term (grasp_ranking_weight 1.0) added. Then both protocols of
# togcrf eval and grasp_ranking.py on the 206 test samples. Not the 60-minute recipe: 75 minutes of training in all.
cd "$(dirname "$0")/../../.."
OUT=${OUT:-runs/rank-ft}
mkdir -p "$OUT"
COMMON="--data data --pipeline recipe --model tog --backbone resnet18 --image-size 160 --batch-size 4 --optimizer adamw --lr-schedule cosine --lr 2e-4 --warmup-steps 20 --scale-jitter 0.15 --val-samples 64 --time-budget 15 --epochs 50 --seed 0 --init runs/recipe-2cores-2026-11-27/tog/checkpoint.pt --device cpu"
OPTS="--option fpn_min_stride=8 --option fpn_max_stride=16 --option rpn_anchor_sizes=[27,53,107] --option fpn_channels=128 --option box_batch_per_image=64 --option box_head_size=256 --option grasp_channels=128 --option rpn_pre_nms_train=500 --option rpn_post_nms_train=250 --option grasp_anchor_size=10.0"
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1
.venv/bin/togcrf train $COMMON $OPTS --out "$OUT/continue" > "$OUT/continue.out" 2>&1 &
.venv/bin/togcrf train $COMMON $OPTS --option grasp_ranking_weight=1.0 --out "$OUT/rank" > "$OUT/rank.out" 2>&1 &
wait
for arm in continue rank; do
  ( .venv/bin/togcrf eval "$OUT/$arm/checkpoint.pt" --data data --pipeline recipe --out "$OUT/$arm/eval.json" --device cpu \
      > "$OUT/$arm.eval.out" 2>&1
    .venv/bin/togcrf eval "$OUT/$arm/checkpoint.pt" --data data --pipeline recipe --protocol lab \
      --out "$OUT/$arm/eval-lab.json" --device cpu > "$OUT/$arm.eval-lab.out" 2>&1
    .venv/bin/python benchmarks/grasp_ranking.py "$OUT/$arm/checkpoint.pt" --data data --pipeline recipe \
      --max-samples 1000 --json "$OUT/$arm/grasp-ranking.json" > "$OUT/$arm/grasp-ranking.txt" 2>&1 ) &
done
wait
