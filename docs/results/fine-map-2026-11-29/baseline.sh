#!/bin/bash
# Issue #15: the baseline of run.sh on the same machine the same day: the 60-minute CPU recipe (TOG, bfloat16,
# 2 threads) without grasp_fine_map, then benchmarks/score_run.sh and top1_cells.py. This 2-core AMD EPYC ran
# 17.5 images/s on 2026-11-29 against 13.4-13.7 on 2026-11-28, so the runs of that day are no baseline for run.sh.
# Dates go to $OUT/dates.log.
HERE=$(cd "$(dirname "$0")" && pwd)
cd "$HERE/../../.."
SEED=${SEED:-0}
OUT=${OUT:-runs/fine-map-baseline-seed$SEED}
mkdir -p "$OUT"
source docs/results/confidence-head-2026-11-28/recipe-options.sh
log "train start"
.venv/bin/togcrf train $COMMON $OPTS --lr 1e-3 --warmup-steps 200 --time-budget 60 --out "$OUT/tog" \
  > "$OUT/train.out" 2>&1 || exit 1
log "train end"
benchmarks/score_run.sh "$OUT/tog/checkpoint.pt" > "$OUT/score.out" 2>&1
log "scored"
.venv/bin/python docs/results/regression-radius-2026-11-29/top1_cells.py "$OUT/tog/checkpoint.pt" \
  > "$OUT/top1-cells.txt" 2>&1
log "top1 cells"
