#!/bin/bash
# Score a training run's checkpoint every way docs/togcrf-evaluation.md quotes a 60-minute run (issue #15):
# togcrf eval under our protocol and the lab's, and benchmarks/grasp_ranking.py (where the top-1 grasp lands,
# the grasp and order oracles), on every test sample of a pipeline's data. The files go beside the checkpoint:
# eval.json, eval-lab.json, grasp-ranking.json and grasp-ranking.txt (each JSON holds its command).
#
#     benchmarks/score_run.sh runs/NAME/tog/checkpoint.pt [PIPELINE (recipe)] [DATA_DIR (data)]
set -euo pipefail
CHECKPOINT=${1:?usage: benchmarks/score_run.sh CHECKPOINT [PIPELINE] [DATA_DIR]}
PIPELINE=${2:-recipe}
DATA=${3:-data}
RUN_DIR=$(dirname "$CHECKPOINT")
BIN=$(dirname "$0")/../.venv/bin
"$BIN/togcrf" eval "$CHECKPOINT" --data "$DATA" --pipeline "$PIPELINE" --out "$RUN_DIR/eval.json" --device cpu
"$BIN/togcrf" eval "$CHECKPOINT" --data "$DATA" --pipeline "$PIPELINE" --protocol lab --out "$RUN_DIR/eval-lab.json" \
  --device cpu
"$BIN/python" "$(dirname "$0")/grasp_ranking.py" "$CHECKPOINT" --data "$DATA" --pipeline "$PIPELINE" \
  --max-samples 1000 --json "$RUN_DIR/grasp-ranking.json" > "$RUN_DIR/grasp-ranking.txt"
