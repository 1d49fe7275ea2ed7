#!/bin/bash
# An A/B of the CPU recipe at the same number of images: the recipe with extra `togcrf train` arguments (arm NAME)
# and the recipe as it is, trained at once, side by side on one thread each, for EPOCHS epochs without a time budget
# (the cosine follows the steps, so both arms see the same images whatever the machine's speed), each then scored by
# lab/tools/recipe_run.sh with TOP1_CELLS=1. The arm goes to runs/NAME-EPOCHSepochs-seedSEED, the baseline to
# runs/baseline-EPOCHSepochs-seedSEED; SEED (default 0) picks the seed of both.
#
#     lab/tools/recipe_ab.sh NAME EPOCHS [TRAIN ARGUMENTS...]
#     lab/tools/recipe_ab.sh fine-map 28 --option grasp_fine_map=true
NAME=${1:?usage: lab/tools/recipe_ab.sh NAME EPOCHS [TRAIN ARGUMENTS...]}
EPOCHS=${2:?usage: lab/tools/recipe_ab.sh NAME EPOCHS [TRAIN ARGUMENTS...]}
shift 2
cd "$(dirname "$0")/../.."
export SEED=${SEED:-0} MINUTES=0 THREADS=1 TOP1_CELLS=1
lab/tools/recipe_run.sh "runs/$NAME-${EPOCHS}epochs-seed$SEED" --epochs "$EPOCHS" "$@" &
lab/tools/recipe_run.sh "runs/baseline-${EPOCHS}epochs-seed$SEED" --epochs "$EPOCHS" &
wait
