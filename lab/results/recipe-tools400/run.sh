#!/usr/bin/env bash
# The recipe trained on 400 distinct tools (lab/experiments/2026-12-04-more-training-tools.md): TOG-CRFs,
# `togcrf reproduce --scale cpu` (the 60-minute budget on 2 quiet cores), seed 1, the seed of the baseline
# run in lab/results/recipe-seed1/ on the same machine type; Table II on its own test piles (seen), the
# recipe's test piles (seen100: tools it trained on, piles of the recipe), novel procedural tools and the
# paper authors' models, both protocols; Table III on piles of the novel tools, the authors' models and its own.
# Run from the repository root after build.sh:
#   lab/results/recipe-tools400/run.sh [DATA] [RUN]
set -euo pipefail
DATA=${1:-/tmp/recipedata}
RUN=${2:-/tmp/tools400run-s1}
OUT=lab/results/recipe-tools400
export PYTHONHASHSEED=0
mkdir -p "$RUN"
reproduce() {
    .venv/bin/togcrf reproduce --data "$DATA" --pipeline recipe-tools400 --out "$RUN" --scale cpu --models tog-crfs \
        --seed 1 "$@"
}
reproduce > "$RUN/reproduce.log" 2>&1
reproduce --test-set seen=recipe-tools400 --test-set seen100=recipe-pairs96 --test-set novel=recipe-novel \
    --test-set authors=recipe-authors > "$RUN/reproduce-sets.log" 2>&1
cp "$RUN"/table2*.txt "$RUN"/table2*.json "$RUN"/tog-crfs/config.json "$OUT"/
grep -v " step " "$RUN/reproduce.log" > "$OUT/reproduce.log"
for tools in novel:pipelines/recipe-novel.toml authors:pipelines/recipe-authors.toml \
    seen:lab/results/recipe-tools400/pipeline.toml; do
    .venv/bin/togcrf robot-eval "$RUN/tog-crfs/checkpoint.pt" --config "${tools#*:}" --data "$DATA" \
        --out "$RUN/robot-${tools%%:*}" --workers 2 --no-pictures | tail -25 > "$OUT/robot-${tools%%:*}.txt"
    cp "$RUN/robot-${tools%%:*}/table3.json" "$OUT/robot-${tools%%:*}.json"
    cp "$RUN/robot-${tools%%:*}/table3.md" "$OUT/robot-${tools%%:*}.md" 2>/dev/null || true
done
echo done
