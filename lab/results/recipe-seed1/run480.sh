#!/usr/bin/env bash
# Table III of the seed-1 checkpoint on piles of the novel procedural tools at three times the paper's trials
# (480), for a tighter GSR-T than the 160 trials of run.sh. Run after run.sh, from the repository root:
#   lab/results/recipe-seed1/run480.sh [DATA] [RUN]
set -euo pipefail
DATA=${1:-/tmp/recipedata}
RUN=${2:-/tmp/reciperun-s1}
OUT=lab/results/recipe-seed1
export PYTHONHASHSEED=0
.venv/bin/togcrf robot-eval "$RUN/tog-crfs/checkpoint.pt" --config pipelines/recipe-novel.toml --data "$DATA" \
    --out "$RUN/robot-novel-480" --workers 2 --no-pictures --tool-trials 30 --named-trials 90 \
    | tail -30 > "$OUT/robot-novel-480.txt"
cp "$RUN/robot-novel-480/table3.json" "$OUT/robot-novel-480.json"
cp "$RUN/robot-novel-480/table3.md" "$OUT/robot-novel-480.md"
echo done
