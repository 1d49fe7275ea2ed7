#!/bin/bash
# Issue #15: the 60-minute CPU recipe (TOG, bfloat16, 2 threads, as `togcrf reproduce --scale cpu --models tog
# --cpu-bf16`) with the grasp head also pooling ResNet C2 at stride 4 (--option grasp_fine_map=true), then
# benchmarks/score_run.sh (both protocols of togcrf eval, grasp_ranking.py), togcrf eval with 8 test-time views, and
# top1_cells.py (where the top-1 candidates lie), on the 206 test samples. Compare with
# docs/results/recipe-2cores-bf16-2026-11-28 (seed 0) and docs/results/recipe-2cores-bf16-seed1-2026-11-28
# (seed 1): the same run without the option. Dates go to $OUT/dates.log.
HERE=$(cd "$(dirname "$0")" && pwd)
cd "$HERE/../../.."
SEED=${SEED:-0}
OUT=${OUT:-runs/fine-map-seed$SEED}
mkdir -p "$OUT"
source docs/results/confidence-head-2026-11-28/recipe-options.sh
log "train start"
.venv/bin/togcrf train $COMMON $OPTS --option grasp_fine_map=true --lr 1e-3 --warmup-steps 200 \
  --time-budget 60 --out "$OUT/tog" > "$OUT/train.out" 2>&1 || exit 1
log "train end"
benchmarks/score_run.sh "$OUT/tog/checkpoint.pt" > "$OUT/score.out" 2>&1
log "scored"
.venv/bin/togcrf eval "$OUT/tog/checkpoint.pt" --data data --pipeline recipe --device cpu --views 8 \
  --out "$OUT/tog/eval-views8.json" >> "$OUT/score.out" 2>&1
log "evaluated"
.venv/bin/python docs/results/regression-radius-2026-11-29/top1_cells.py "$OUT/tog/checkpoint.pt" \
  > "$OUT/top1-cells.txt" 2>&1
log "top1 cells"
