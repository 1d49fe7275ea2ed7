#!/usr/bin/env bash
# The generalisation gap screen (lab/experiments/2026-12-02-gap-screen.md): the default dataset and a test set of
# 40 novel procedural tools (lab/pipelines/gap-novel.toml) built into DATA, TOG-CRFs trained with the CPU preset on
# the default dataset within BUDGET minutes, scored on the seen-tool test split and the novel tools (Table II, both
# protocols), and Table III in simulation on piles of each. Run from the repository root:
#   lab/results/gap-screen/run.sh [DATA] [RUN] [BUDGET]
set -euo pipefail
DATA=${1:-/tmp/gapdata2}
RUN=${2:-/tmp/gaprun}
BUDGET=${3:-40}
OUT=lab/results/gap-screen
export PYTHONHASHSEED=0
for config in pipelines/default.toml lab/pipelines/gap-novel.toml; do
    .venv/bin/osgd --data-dir "$DATA" --workers 2 run "$config"
done
.venv/bin/togcrf train --data "$DATA" --pipeline default --out "$RUN/tog-crfs" --model tog-crfs --preset cpu \
    --time-budget "$BUDGET" > "$RUN/train.log" 2>&1
.venv/bin/togcrf eval "$RUN/tog-crfs/checkpoint.pt" --data "$DATA" --test-set seen=default \
    --test-set novel=gap-novel --out "$OUT/eval-sets.json" | tee "$OUT/eval-sets.txt"
for tools in default:pipelines/default.toml novel:lab/pipelines/gap-novel.toml; do
    .venv/bin/togcrf robot-eval "$RUN/tog-crfs/checkpoint.pt" --config "${tools#*:}" --data "$DATA" \
        --out "$RUN/robot-${tools%%:*}" --workers 2 --no-pictures | tail -25 > "$OUT/robot-${tools%%:*}.txt"
    cp "$RUN/robot-${tools%%:*}/table3.json" "$OUT/robot-${tools%%:*}.json"
done
