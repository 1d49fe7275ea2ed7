#!/usr/bin/env bash
# The recipe's second seed: TOG-CRFs, `togcrf reproduce --scale cpu` (the 60-minute budget on 2 cores), seed 1,
# on recipe-pairs96; Table II on seen tools, novel procedural tools and the paper authors' models (both
# protocols), and Table III on piles of each (lab/experiments/2026-12-04-recipe-second-seed.md).
# The test sets are built after the training, so that the budget runs on quiet cores.
# Run from the repository root:
#   lab/results/recipe-seed1/run.sh [DATA] [RUN]
set -euo pipefail
DATA=${1:-/tmp/recipedata}
RUN=${2:-/tmp/reciperun-s1}
OUT=lab/results/recipe-seed1
export PYTHONHASHSEED=0
mkdir -p "$RUN"
build() { /usr/bin/time -f "%e s $1" .venv/bin/osgd --data-dir "$DATA" --workers 2 run "$1"; }
reproduce() {
    .venv/bin/togcrf reproduce --data "$DATA" --pipeline recipe-pairs96 --out "$RUN" --scale cpu --models tog-crfs \
        --seed 1 "$@"
}
build pipelines/recipe-pairs96.toml
reproduce > "$RUN/reproduce.log" 2>&1
build pipelines/recipe-novel.toml
build pipelines/recipe-authors.toml
reproduce --test-set seen=recipe-pairs96 --test-set novel=recipe-novel --test-set authors=recipe-authors \
    > "$RUN/reproduce-sets.log" 2>&1
cp "$RUN"/table2*.txt "$RUN"/table2*.json "$RUN"/tog-crfs/config.json "$OUT"/
grep -v " step " "$RUN/reproduce.log" > "$OUT/reproduce.log"
for tools in novel:pipelines/recipe-novel.toml authors:pipelines/recipe-authors.toml seen:pipelines/recipe-pairs96.toml; do
    .venv/bin/togcrf robot-eval "$RUN/tog-crfs/checkpoint.pt" --config "${tools#*:}" --data "$DATA" \
        --out "$RUN/robot-${tools%%:*}" --workers 2 --no-pictures | tail -25 > "$OUT/robot-${tools%%:*}.txt"
    cp "$RUN/robot-${tools%%:*}/table3.json" "$OUT/robot-${tools%%:*}.json"
    cp "$RUN/robot-${tools%%:*}/table3.md" "$OUT/robot-${tools%%:*}.md" 2>/dev/null || true
done
echo done
