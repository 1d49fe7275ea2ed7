#!/usr/bin/env bash
# What the mean field does in the recipe's TOG-CRFs (seed 1, lab/results/recipe-seed1/run.sh): the checkpoint scored
# with its mean field switched off at test time against itself, and RoI by RoI by crowding, on the three test sets,
# with the crf-study's scripts (lab/experiments/2026-12-02-crf-study-screen.md). Run from the repository root:
#   lab/results/recipe-seed1/crf/run.sh [DATA] [RUN]
set -euo pipefail
DATA=${1:-/tmp/recipedata}
RUN=${2:-/tmp/reciperun-s1}
OUT=lab/results/recipe-seed1/crf
STUDY=lab/results/crf-study
SETS=(seen=recipe-pairs96 novel=recipe-novel authors=recipe-authors)
.venv/bin/python "$STUDY/crf_off.py" "$RUN/tog-crfs/checkpoint.pt" "$DATA" "$OUT/eval-unary.json" "${SETS[@]}"
cp "$RUN/tog-crfs/eval-sets.json" "$OUT/eval-crf.json"
.venv/bin/togcrf compare --baseline "$OUT/eval-unary.json" --candidate "$OUT/eval-crf.json" \
    --out "$OUT/compare-crf-at-test.json" > "$OUT/compare-crf-at-test.txt"
.venv/bin/python "$STUDY/crf_flips.py" "$OUT/flips.json" "$DATA" "$RUN/tog-crfs/checkpoint.pt" \
    --set seen=recipe-pairs96 --set novel=recipe-novel --set authors=recipe-authors > /dev/null
.venv/bin/python "$STUDY/crf_flips.py" --summarise "$OUT/flips-summary.json" "$OUT/flips.json" > "$OUT/flips.txt"
.venv/bin/togcrf figures "$RUN/tog-crfs/checkpoint.pt" --out "$OUT/figures"
echo done
