#!/bin/bash
# Issue #15: the 60-minute CPU recipe (TOG, bfloat16, 2 threads, as `togcrf reproduce --scale cpu --models tog
# --cpu-bf16`) with the "is my top-1 grasp right" head (--option grasp_confidence=true) trained from scratch end to
# end (grasp_confidence_trains_features=true: its loss reaches the trunk and the backbone), then
# benchmarks/score_run.sh (both protocols of togcrf eval, grasp_ranking.py) and confidence_auc.py on the 206 test samples. Compare with
# lab/results/recipe-2cores-bf16-2026-11-28 (the same run without the head). Dates go to $OUT/dates.log.
HERE=$(cd "$(dirname "$0")" && pwd)
cd "$HERE/../../.."
SEED=${SEED:-0}
OUT=${OUT:-runs/confidence-scratch-seed$SEED}
mkdir -p "$OUT"
source "$HERE/recipe-options.sh"
log "train start"
.venv/bin/togcrf train $COMMON $OPTS --option grasp_confidence=true --option grasp_confidence_trains_features=true --lr 1e-3 --warmup-steps 200 --time-budget 60 \
  --out "$OUT/tog" > "$OUT/train.out" 2>&1 || exit 1
log "train end"
benchmarks/score_run.sh "$OUT/tog/checkpoint.pt" > "$OUT/score.out" 2>&1
.venv/bin/python lab/results/confidence-head-2026-11-28/confidence_auc.py "$OUT/tog/checkpoint.pt" --data data \
  --pipeline recipe > "$OUT/tog/confidence-auc.txt" 2>&1
log "evaluated"
