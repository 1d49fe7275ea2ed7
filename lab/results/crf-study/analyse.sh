#!/usr/bin/env bash
# The CRF study's answers from the runs of run.sh (lab/experiments/2026-12-02-crf-study-screen.md): TOG-CRFs minus
# TOG over the seeds (togcrf compare, paired by seed), the same TOG-CRFs checkpoints with the mean field switched off
# at test time (crf_off.py) against themselves, and figure 5 of seed 0. Run from the repository root:
#   lab/results/crf-study/analyse.sh [DATA] [RUN] [SEEDS]
set -euo pipefail
DATA=${1:-/tmp/gapdata2}
RUN=${2:-/tmp/crfstudy}
SEEDS=${3:-4}
OUT=lab/results/crf-study
seeds=$(seq 0 $((SEEDS - 1)))
arguments=()
for seed in $seeds; do
    arguments+=(--baseline "$OUT/eval-tog-s$seed.json" --candidate "$OUT/eval-tog-crfs-s$seed.json")
done
.venv/bin/togcrf compare "${arguments[@]}" --out "$OUT/compare.json" > "$OUT/compare.txt"
arguments=()
for seed in $seeds; do
    if [ ! -f "$OUT/eval-tog-crfs-s$seed-unary.json" ]; then
        .venv/bin/python "$OUT/crf_off.py" "$RUN/tog-crfs-s$seed/checkpoint.pt" "$DATA" \
            "$OUT/eval-tog-crfs-s$seed-unary.json" seen=default novel=gap-novel
    fi
    arguments+=(--baseline "$OUT/eval-tog-crfs-s$seed-unary.json" --candidate "$OUT/eval-tog-crfs-s$seed.json")
done
.venv/bin/togcrf compare "${arguments[@]}" --out "$OUT/compare-crf-at-test.json" > "$OUT/compare-crf-at-test.txt"
.venv/bin/togcrf figures "$RUN/tog-crfs-s0/checkpoint.pt" --out "$OUT/figures-s0"
parts=()
for seed in $seeds; do
    if [ ! -f "$OUT/flips-s$seed.json" ]; then
        .venv/bin/python "$OUT/crf_flips.py" "$OUT/flips-s$seed.json" "$DATA" "$RUN/tog-crfs-s$seed/checkpoint.pt" \
            --set seen=default --set novel=gap-novel > /dev/null
    fi
    parts+=("$OUT/flips-s$seed.json")
done
.venv/bin/python "$OUT/crf_flips.py" --summarise "$OUT/flips.json" "${parts[@]}" > "$OUT/flips.txt"
