#!/bin/bash
# Issue #15: the "is my top-1 grasp right" head (ModelOptions.grasp_confidence) trained alone, 12 minutes, on the
# frozen seed-0 bfloat16 recipe checkpoint (the rest of the model is unchanged: its inputs are detached), then
# benchmarks/score_run.sh (both protocols of togcrf eval, grasp_ranking.py) on the 206 test samples. A quick measure of what the head can
# learn; it is not a 60-minute recipe run (it adds 12 minutes to the checkpoint's 60). Dates go to $OUT/dates.log.
HERE=$(cd "$(dirname "$0")" && pwd)
cd "$HERE/../../.."
OUT=${OUT:-runs/confidence-frozen}
INIT=${INIT:-runs/recipe-2cores-bf16-2026-11-28/tog/checkpoint.pt}
mkdir -p "$OUT"
source "$HERE/recipe-options.sh"
log "head start"
.venv/bin/togcrf train $COMMON $OPTS --option grasp_confidence=true --init "$INIT" \
  --train-only grasp_head.confidence --lr 1e-3 --warmup-steps 20 --time-budget 12 --out "$OUT/head" \
  > "$OUT/head.out" 2>&1 || exit 1
log "head end"
benchmarks/score_run.sh "$OUT/head/checkpoint.pt" > "$OUT/head.score.out" 2>&1
log "head evaluated"
