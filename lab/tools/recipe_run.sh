#!/bin/bash
# The 60-minute CPU recipe from scratch (TOG, bfloat16, 2 threads, as `togcrf reproduce --scale cpu --models tog
# --cpu-bf16`) with extra `togcrf train` arguments (a model option under test, or none for a same-day baseline), then
# lab/tools/score_run.sh (both protocols of togcrf eval, togcrf.diagnostics) on every test sample; with VIEWS=N also
# `togcrf eval --views N`, with TOP1_CELLS=1 also lab/results/regression-radius-2026-11-29/top1_cells.py. The run
# goes to OUT/tog, its output to OUT/train.out and OUT/score.out, the dates of its steps to OUT/dates.log. SEED
# (default 0) picks the seed. MINUTES (default 60) is the time budget; MINUTES=0 trains without one, for the --epochs
# given (the cosine then follows the steps, so the run sees the same images on any machine). THREADS (default 2) sets
# torch's threads: 1 for two runs side by side. Run from anywhere; paths are relative to the repository root.
#
#     lab/tools/recipe_run.sh OUT [TRAIN ARGUMENTS...]
#     VIEWS=8 TOP1_CELLS=1 lab/tools/recipe_run.sh runs/fine-map-seed0 --option grasp_fine_map=true
#     MINUTES=0 THREADS=1 lab/tools/recipe_run.sh runs/fine-map-12epochs --epochs 12 --option grasp_fine_map=true
OUT=${1:?usage: lab/tools/recipe_run.sh OUT [TRAIN ARGUMENTS...]}
shift
cd "$(dirname "$0")/../.."
mkdir -p "$OUT"
source lab/results/confidence-head-2026-11-28/recipe-options.sh
export OMP_NUM_THREADS=${THREADS:-2} MKL_NUM_THREADS=${THREADS:-2}
log "train start"
.venv/bin/togcrf train $COMMON $OPTS "$@" --lr 1e-3 --warmup-steps 200 --time-budget "${MINUTES:-60}" --out "$OUT/tog" \
  > "$OUT/train.out" 2>&1 || exit 1
log "train end"
lab/tools/score_run.sh "$OUT/tog/checkpoint.pt" > "$OUT/score.out" 2>&1
log "scored"
if [ -n "${VIEWS:-}" ]; then
  .venv/bin/togcrf eval "$OUT/tog/checkpoint.pt" --data data --pipeline recipe --device cpu --views "$VIEWS" \
    --out "$OUT/tog/eval-views$VIEWS.json" >> "$OUT/score.out" 2>&1
  log "evaluated"
fi
if [ -n "${TOP1_CELLS:-}" ]; then
  .venv/bin/python lab/results/regression-radius-2026-11-29/top1_cells.py "$OUT/tog/checkpoint.pt" \
    > "$OUT/top1-cells.txt" 2>&1
  log "top1 cells"
fi
