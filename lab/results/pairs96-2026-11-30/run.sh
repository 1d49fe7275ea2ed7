#!/bin/bash
# Issue #15: TOG with the recipe as it is (bfloat16, the ranking term at 0.2, 8 grasp RoIs per image) on both cores,
# seed SEED (default 0), trained for 48 epochs of the 1,730 training samples (83,040 images, as many as the recipe's
# 60-minute runs of 2026-11-29 saw; MINUTES=0, so the cosine follows the steps and the run sees the same images on
# any machine) on the data of pipelines/TRAIN.toml: recipe-pairs96 (the default; the recipe's piles and images, 96
# sampled contact pairs per tool instead of 48) or recipe (the same-day baseline). Each checkpoint is scored on the
# 206 test samples with the recipe's ground truth by benchmarks/score_run.sh (both protocols, grasp_ranking.py;
# beside the checkpoint, OUT/tog) and with recipe-pairs96's (OUT/pairs96, through a link to the checkpoint); then
# lab/results/top1-filters-2026-11-30/filters.py against each pipeline's annotated grasps.
#
#     osgd --data-dir data --workers 2 run pipelines/recipe.toml
#     osgd --data-dir data --workers 2 run pipelines/recipe-pairs96.toml
#     lab/results/pairs96-2026-11-30/run.sh                 # trained on recipe-pairs96
#     TRAIN=recipe lab/results/pairs96-2026-11-30/run.sh    # trained on recipe
cd "$(dirname "$0")/../../.."
SEED=${SEED:-0}
TRAIN=${TRAIN:-recipe-pairs96}
OUT=runs/$TRAIN-48epochs-seed$SEED
RESULTS=lab/results/pairs96-2026-11-30
MINUTES=0 SEED=$SEED benchmarks/recipe_run.sh "$OUT" --pipeline "$TRAIN" --epochs 48 || exit 1
mkdir -p "$OUT/pairs96"
ln -sf ../tog/checkpoint.pt "$OUT/pairs96/checkpoint.pt"
benchmarks/score_run.sh "$OUT/pairs96/checkpoint.pt" recipe-pairs96 > "$OUT/score-pairs96.out" 2>&1
echo "$(date -u +%FT%TZ) scored on recipe-pairs96" >> "$OUT/dates.log"
export OMP_NUM_THREADS=2
for PIPELINE in recipe recipe-pairs96; do
  .venv/bin/python lab/results/top1-filters-2026-11-30/filters.py "$OUT/tog/checkpoint.pt" \
    "$RESULTS/filters-$TRAIN-seed$SEED-on-$PIPELINE.json" --pipeline "$PIPELINE" > /dev/null
done
echo "$(date -u +%FT%TZ) filters" >> "$OUT/dates.log"
