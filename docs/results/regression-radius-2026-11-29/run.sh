#!/bin/bash
# Issue #15: the 60-minute CPU recipe (TOG, bfloat16, 2 threads, as `togcrf reproduce --scale cpu --models tog
# --cpu-bf16`) with the regression of the candidates within one cell of an annotated grasp trained onto it
# (--option grasp_regression_radius=$RADIUS, default 1), then benchmarks/score_run.sh (both protocols of togcrf
# eval, grasp_ranking.py) and togcrf eval with 8 test-time views, on the 206 test samples. Compare with
# docs/results/recipe-2cores-bf16-2026-11-28 (seed 0) and docs/results/recipe-2cores-bf16-seed1-2026-11-28
# (seed 1): the same run without the option. Dates go to $OUT/dates.log.
HERE=$(cd "$(dirname "$0")" && pwd)
cd "$HERE/../../.."
SEED=${SEED:-0}
RADIUS=${RADIUS:-1}
OUT=${OUT:-runs/regression-radius$RADIUS-seed$SEED}
mkdir -p "$OUT"
source docs/results/confidence-head-2026-11-28/recipe-options.sh
log "train start"
.venv/bin/togcrf train $COMMON $OPTS --option grasp_regression_radius=$RADIUS --lr 1e-3 --warmup-steps 200 \
  --time-budget 60 --out "$OUT/tog" > "$OUT/train.out" 2>&1 || exit 1
log "train end"
benchmarks/score_run.sh "$OUT/tog/checkpoint.pt" > "$OUT/score.out" 2>&1
log "scored"
.venv/bin/togcrf eval "$OUT/tog/checkpoint.pt" --data data --pipeline recipe --device cpu --views 8 \
  --out "$OUT/tog/eval-views8.json" >> "$OUT/score.out" 2>&1
log "evaluated"
