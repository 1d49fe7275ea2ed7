#!/bin/bash
# Score a training run's checkpoint every way an experiment quotes a 60-minute run: togcrf eval under our protocol
# and the lab's, and togcrf.diagnostics (where the top-1 grasp lands, the grasp and order oracles), on every test
# sample of a pipeline's data. The files go beside the checkpoint: eval.json, eval-lab.json, grasp-ranking.json and
# grasp-ranking.txt (each JSON holds its command).
#
#     lab/tools/score_run.sh runs/NAME/tog/checkpoint.pt [PIPELINE (recipe)] [DATA_DIR (data)]
set -euo pipefail
CHECKPOINT=${1:?usage: lab/tools/score_run.sh CHECKPOINT [PIPELINE] [DATA_DIR]}
PIPELINE=${2:-recipe}
DATA=${3:-data}
RUN_DIR=$(dirname "$CHECKPOINT")
BIN=$(dirname "$0")/../../.venv/bin
"$BIN/togcrf" eval "$CHECKPOINT" --data "$DATA" --pipeline "$PIPELINE" --out "$RUN_DIR/eval.json" --device cpu
"$BIN/togcrf" eval "$CHECKPOINT" --data "$DATA" --pipeline "$PIPELINE" --protocol lab --out "$RUN_DIR/eval-lab.json" \
  --device cpu
"$BIN/python" -m togcrf.diagnostics "$CHECKPOINT" --data "$DATA" --pipeline "$PIPELINE" \
  --max-samples 1000 --json "$RUN_DIR/grasp-ranking.json" > "$RUN_DIR/grasp-ranking.txt"
