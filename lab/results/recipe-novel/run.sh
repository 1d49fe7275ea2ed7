#!/usr/bin/env bash
# TOG-CRFs with the CPU recipe (recipe-pairs96, the recipe's 60-minute budget) scored on seen tools and on the
# 40 novel procedural tools of pipelines/recipe-novel.toml: Table II per test set (both protocols) and Table III
# on piles of the novel tools, then of the seen ones (lab/experiments/2026-12-03-recipe-novel-tools.md).
# Run from the repository root:
#   lab/results/recipe-novel/run.sh [DATA] [RUN]
set -euo pipefail
DATA=${1:-/tmp/recipedata}
RUN=${2:-/tmp/reciperun}
OUT=lab/results/recipe-novel
export PYTHONHASHSEED=0
mkdir -p "$RUN"
for config in pipelines/recipe-pairs96.toml pipelines/recipe-novel.toml; do
    /usr/bin/time -f "%e s $config" .venv/bin/osgd --data-dir "$DATA" --workers 2 run "$config"
done
.venv/bin/togcrf reproduce --data "$DATA" --pipeline recipe-pairs96 --out "$RUN" --scale cpu --models tog-crfs \
    --test-set seen=recipe-pairs96 --test-set novel=recipe-novel > "$RUN/reproduce.log" 2>&1
cp "$RUN"/table2*.txt "$RUN"/table2*.json "$OUT"/ 2>/dev/null || true
for tools in novel:pipelines/recipe-novel.toml seen:pipelines/recipe-pairs96.toml; do
    .venv/bin/togcrf robot-eval "$RUN/tog-crfs/checkpoint.pt" --config "${tools#*:}" --data "$DATA" \
        --out "$RUN/robot-${tools%%:*}" --workers 2 --no-pictures | tail -25 > "$OUT/robot-${tools%%:*}.txt"
    cp "$RUN/robot-${tools%%:*}/table3.json" "$OUT/robot-${tools%%:*}.json"
done
