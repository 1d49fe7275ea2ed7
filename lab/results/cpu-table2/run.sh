#!/bin/bash
# CPU Table II (issue #15): all five models at one per-model budget, one epoch of the recipe's
# training data (1,730 images, 433 steps of batch 4) on 2 threads, then TOG and TOG-CRFs again with a
# second seed. One epoch, not the recipe's 60 minutes: on this 2-core machine a model trains at
# 3.7-4 images/s, and 7 x 60 minutes does not fit a session. An epoch budget, not a time budget, so
# that every row sees the same images whatever the load.
set -e
cd "$(dirname "$0")/../../.."
COMMON="--data data --pipeline recipe --scale cpu --epochs 1 --time-budget 0"
.venv/bin/togcrf reproduce $COMMON --seed 0 --out runs/table2-cpu1-seed0
.venv/bin/togcrf reproduce $COMMON --seed 1 --models tog,tog-crfs --out runs/table2-cpu1-seed1
# The two seeds side by side, and each model's mean and standard deviation over them, from the evaluations
# committed beside this script (seedS/MODEL/eval.json, eval-lab.json, config.json):
cd lab/results/cpu-table2
for suffix in "" -lab; do
    ../../../.venv/bin/togcrf table seed{0,1}/tog/eval$suffix.json seed{0,1}/tog-crfs/eval$suffix.json \
        --out seeds$suffix.json > seeds$suffix.txt
    ../../../.venv/bin/togcrf table seed{0,1}/tog/eval$suffix.json seed{0,1}/tog-crfs/eval$suffix.json --mean \
        --out means$suffix.json > means$suffix.txt
done
