# The recipe's training options (as `togcrf reproduce --scale cpu --models tog --cpu-bf16`), sourced by frozen.sh and
# scratch.sh (and benchmarks/recipe_run.sh): $COMMON (data, optimiser, schedule, precision; $SEED, default 0), $OPTS
# (the model options; since 2026-11-29 with grasp_ranking_weight=0.2, which the runs of this folder did not have;
# `--option grasp_ranking_weight=0` after $OPTS repeats them) and log.
export OMP_NUM_THREADS=2 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=2
COMMON="--data data --pipeline recipe --model tog --backbone resnet18 --image-size 160 --batch-size 4 --optimizer adamw --lr-schedule cosine --scale-jitter 0.15 --val-samples 64 --epochs 50 --seed ${SEED:-0} --device cpu --cpu-bf16"
OPTS="--option fpn_min_stride=8 --option fpn_max_stride=16 --option rpn_anchor_sizes=[27,53,107] --option fpn_channels=128 --option box_batch_per_image=64 --option box_head_size=256 --option grasp_channels=128 --option rpn_pre_nms_train=500 --option rpn_post_nms_train=250 --option grasp_anchor_size=10.0 --option grasp_ranking_weight=0.2"
log() { echo "$(date -u +%FT%TZ) $*" >> "$OUT/dates.log"; }
