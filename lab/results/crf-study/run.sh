#!/usr/bin/env bash
# The CRF study at screen scale (lab/experiments/2026-12-02-crf-study-screen.md): TOG and TOG-CRFs, the CPU preset,
# EPOCHS epochs each (the same training images for every run), seeds 0..SEEDS-1, trained on the default dataset in
# DATA (built as in lab/results/gap-screen/run.sh) and scored on its seen-tool test split and on the novel
# procedural tools; then the paired differences with their 95 % intervals. Run from the repository root:
#   lab/results/crf-study/run.sh [DATA] [RUN] [EPOCHS] [SEEDS]
set -euo pipefail
DATA=${1:-/tmp/gapdata2}
RUN=${2:-/tmp/crfstudy}
EPOCHS=${3:-10}
SEEDS=${4:-4}
OUT=lab/results/crf-study
export PYTHONHASHSEED=0
mkdir -p "$RUN"
for seed in $(seq 0 $((SEEDS - 1))); do
    for model in tog tog-crfs; do
        run="$RUN/$model-s$seed"
        if [ ! -f "$OUT/eval-$model-s$seed.json" ]; then
            .venv/bin/togcrf train --data "$DATA" --pipeline default --out "$run" --model "$model" --preset cpu \
                --epochs "$EPOCHS" --time-budget 0 --seed "$seed" > "$RUN/train-$model-s$seed.log" 2>&1
            .venv/bin/togcrf eval "$run/checkpoint.pt" --data "$DATA" --test-set seen=default \
                --test-set novel=gap-novel --out "$OUT/eval-$model-s$seed.json" > "$OUT/eval-$model-s$seed.txt"
            cp "$run/metrics.csv" "$OUT/metrics-$model-s$seed.csv"
        fi
    done
done
