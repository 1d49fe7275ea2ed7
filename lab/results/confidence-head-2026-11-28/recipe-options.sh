# The recipe's training options (as `togcrf reproduce --scale cpu --models tog --cpu-bf16`), sourced by frozen.sh and
# scratch.sh (and benchmarks/recipe_run.sh): $COMMON (data, optimiser, schedule, precision; $SEED, default 0), $OPTS
# (the model options, read from togcrf.reproduce.CPU_MODEL_OPTIONS; since 2026-11-29 with grasp_ranking_weight=0.2,
# which the runs of this folder did not have; `--option grasp_ranking_weight=0` after $OPTS repeats them; since
# 22:30 UTC that day with grasp_rois_per_image=8: `--option grasp_rois_per_image=16` repeats the runs before) and log.
export OMP_NUM_THREADS=2 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=2
COMMON="--data data --pipeline recipe --model tog --backbone resnet18 --image-size 160 --batch-size 4 --optimizer adamw --lr-schedule cosine --scale-jitter 0.15 --val-samples 64 --epochs 50 --seed ${SEED:-0} --device cpu --cpu-bf16"
OPTS=$(.venv/bin/python - <<'PY'
import json
from togcrf.reproduce import CPU_MODEL_OPTIONS
print(" ".join(f"--option {name}={json.dumps(value, separators=(',', ':'))}" for name, value in CPU_MODEL_OPTIONS))
PY
)
log() { echo "$(date -u +%FT%TZ) $*" >> "$OUT/dates.log"; }
