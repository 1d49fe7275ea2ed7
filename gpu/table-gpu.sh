#!/usr/bin/env bash
# Table II on a GPU lease, in steps that resume:
#
#   install     the dependencies, from an offline site-packages tarball where the machine has no network
#   data        the pipeline's dataset (PIPELINE, a config in pipelines/: gpu, 8,000 piles; or recipe-pairs96,
#               the CPU recipe's)
#   throughput  the paper's configuration (ResNet-101, batch 2, SGD) beside the GPU recipe, 40 s each
#   train       every job (a seed and a model) side by side on the one GPU, each
#               `togcrf reproduce --scale SCALE TRAIN_OPTIONS` in its own process group (training, then
#               evaluation under both protocols)
#   speed       frames per second at batch 1 and the CRF's share, one model at a time (seed 0)
#   report      the tables (with several seeds, each model's mean over them too), learning curves, figure 5,
#               a prediction picture, into RESULTS
#
# Each call does what is left and returns within DEADLINE seconds, so that it fits a command limit of ten
# minutes; call it again until it prints "table-gpu: done". Training runs on in the background between calls
# (setsid), and an interrupted training resumes from its last checkpoint.
#
#   make table-gpu            (or gpu/table-gpu.sh): TOG and TOG-CRFs on pipelines/gpu.toml, 11 minutes each
#   PIPELINE=recipe-pairs96 SCALE=cpu THROUGHPUT=0 TRAIN_OPTIONS="--epochs 6 --time-budget 0 --workers 1" WORKERS=16 \
#   JOBS="0:fcgn-task 0:tog 0:tog-crfs-omega 0:tog-crfs-mu 0:tog-crfs 1:tog 1:tog-crfs" gpu/table-gpu.sh
#               the CPU recipe's Table II, all five rows and a second seed, at an epoch budget instead of minutes
#
# Variables: DATA (data), PIPELINE (gpu: pipelines/PIPELINE.toml), SCALE (gpu), JOBS (seed:model pairs,
# "0:tog 0:tog-crfs"), RUNS (runs/table-gpu; a job's run dir is RUNS/seedS/MODEL), BUDGET (minutes of training per
# model, 11), TRAIN_OPTIONS (more `togcrf reproduce` options; default --time-budget BUDGET), THROUGHPUT (1: measure
# the paper's configuration and the GPU recipe first), DEADLINE (seconds, 570), RESULTS (the small result files,
# $RUNS/results; packed into $OUT/results.tar.gz when OUT is set), SITE (offline site-packages tarball,
# .gpu/site-py312.tar.xz, made by gpu/gpu-offline-kit.sh), PYTHON (python3), WORKERS (dataset worker processes,
# one per core).
set -euo pipefail
cd "$(dirname "$0")/.."
started=$SECONDS
DEADLINE=${DEADLINE:-570}
DATA=${DATA:-data}
RUNS=${RUNS:-runs/table-gpu}
PIPELINE=${PIPELINE:-gpu}
SCALE=${SCALE:-gpu}
BUDGET=${BUDGET:-11}
TRAIN_OPTIONS=${TRAIN_OPTIONS:---time-budget $BUDGET}
THROUGHPUT=${THROUGHPUT:-1}
read -r -a JOBS <<< "${JOBS:-0:tog 0:tog-crfs}"
RESULTS=${RESULTS:-$RUNS/results}
SITE=${SITE:-.gpu/site-py312.tar.xz}
PYTHON=${PYTHON:-python3}
WORKERS=${WORKERS:-$(nproc)}
mkdir -p "$RUNS" "$RESULTS"

say() { echo "table-gpu [$(date +%H:%M:%S), $((SECONDS - started)) s]: $*" | tee -a "$RUNS/table-gpu.log"; }
seconds_left() { echo $((DEADLINE - (SECONDS - started))); }

install() {
    if { [ -f "$SITE" ] || [ -f /tmp/osgd-site/.unpacked ]; } \
            && ! $PYTHON -c "import pybullet, trimesh, coacd, embreex, pydantic" 2>/dev/null; then
        mkdir -p /tmp/osgd-site
        [ -f /tmp/osgd-site/.unpacked ] || { tar -xJf "$SITE" -C /tmp/osgd-site && touch /tmp/osgd-site/.unpacked; }
        export PYTHONPATH=/tmp/osgd-site:${PYTHONPATH:-}
        # pydantic-core needs typing_extensions >= 4.14 (Sentinel); the tarball carries one in _extra
        $PYTHON -c "from typing_extensions import Sentinel" 2>/dev/null || export PYTHONPATH=/tmp/osgd-site/_extra:$PYTHONPATH
    fi
    if ! $PYTHON -c "import pybullet, trimesh, coacd, embreex, pydantic, torch, torchvision" 2>/dev/null; then
        say "installing"
        $PYTHON -m pip install -q -e .
    fi
    export PYTHONPATH=$PWD:${PYTHONPATH:-}
    $PYTHON -c "import torch; assert torch.cuda.is_available(), 'no CUDA device'; print(torch.cuda.get_device_name())" \
        > "$RESULTS/device.txt"
    nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv >> "$RESULTS/device.txt" 2>/dev/null || true
    echo "cpus: $(nproc); torch: $($PYTHON -c 'import torch; print(torch.__version__)')" >> "$RESULTS/device.txt"
}

build_data() {
    local manifest="$DATA/manifests/$PIPELINE.json"
    # the build's manifest is kept under RUNS: a machine that syncs the working tree may remove or replace the
    # data dir's one (data/manifests/ is tracked)
    if [ -f "$RUNS/$PIPELINE.json" ]; then
        mkdir -p "$DATA/manifests" && cp "$RUNS/$PIPELINE.json" "$manifest"
        return 0
    fi
    say "building pipelines/$PIPELINE.toml with $WORKERS workers"
    # a manifest tracked in git (data/manifests/) is moved aside, so that the build's own manifest is the one
    # compared with it
    [ -f "$manifest" ] && mv "$manifest" "$RESULTS/$PIPELINE-tracked.json"
    timeout "$(seconds_left)" $PYTHON -m osgd --data-dir "$DATA" --workers "$WORKERS" run "pipelines/$PIPELINE.toml" \
        2>&1 | tee "$RESULTS/dataset.txt"
    cp "$manifest" "$RUNS/$PIPELINE.json"
    if [ -f "$RESULTS/$PIPELINE-tracked.json" ]; then
        cmp -s "$manifest" "$RESULTS/$PIPELINE-tracked.json" && say "the manifest equals the tracked one" \
            || say "the manifest differs from the tracked one ($RESULTS/$PIPELINE-tracked.json)"
    fi
}

# images/s of a configuration, from its training's metrics.csv (40 s of steps, warm-up included)
measure() {
    local name=$1; shift
    [ -f "$RUNS/throughput/$name/tog/metrics.csv" ] && return 0
    say "throughput of $name"
    $PYTHON -m togcrf reproduce --data "$DATA" --pipeline "$PIPELINE" --models tog --out "$RUNS/throughput/$name" \
        --time-budget 0.67 --eval-max-samples 4 --speed-images 0 "$@" > "$RUNS/throughput/$name.out" 2>&1
}

throughput() {
    [ "$THROUGHPUT" = 1 ] || return 0
    [ -f "$RESULTS/throughput.json" ] && return 0
    mkdir -p "$RUNS/throughput"
    measure paper --scale paper
    measure gpu --scale gpu
    $PYTHON - "$RUNS/throughput" "$RESULTS/throughput.json" "$DATA" <<'EOF'
import csv, json, sys
from pathlib import Path
from osgd.contract.samples import sample_shards
import pyarrow.parquet as pq
folder, out, data = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
train = sum(1 for path in sample_shards(data, "$PIPELINE") for split in pq.read_table(path, columns=["split"])["split"].to_pylist()
            if split == "train")
result = {"train_samples": train, "configurations": {}}
for name in ("paper", "gpu"):
    rows = list(csv.DictReader((folder / name / "tog" / "metrics.csv").open()))
    config = json.loads((folder / name / "tog" / "config.json").read_text())
    speed = float(rows[-1]["images_per_second"])
    result["configurations"][name] = {
        "backbone": config["backbone"], "batch_size": config["batch_size"], "image_size": config["image_size"],
        "optimizer": config["optimizer"], "images_per_second": speed,
        "minutes_for_10_epochs_one_model": round(10 * train / speed / 60, 1)}
out.write_text(json.dumps(result, indent=2) + "\n")
print(json.dumps(result, indent=2))
EOF
}

running() { [ -f "$RUNS/$1.pid" ] && kill -0 "$(cat "$RUNS/$1.pid")" 2>/dev/null; }
seed_of() { echo "${1%%:*}"; }
model_of() { echo "${1#*:}"; }
job_dir() { echo "$RUNS/seed$(seed_of "$1")/$(model_of "$1")"; }
job_name() { echo "seed$(seed_of "$1")-$(model_of "$1")"; }

train() {
    local job
    for job in "${JOBS[@]}"; do
        [ -f "$(job_dir "$job")/eval-lab.json" ] && continue
        running "$(job_name "$job")" && continue
        say "training and evaluating $(job_name "$job") ($TRAIN_OPTIONS)"
        # shellcheck disable=SC2086
        setsid nohup $PYTHON -m togcrf --log-level info reproduce --data "$DATA" --pipeline "$PIPELINE" \
            --scale "$SCALE" --models "$(model_of "$job")" --seed "$(seed_of "$job")" \
            --out "$RUNS/seed$(seed_of "$job")" $TRAIN_OPTIONS >> "$RUNS/$(job_name "$job").out" 2>&1 &
        echo $! > "$RUNS/$(job_name "$job").pid"
    done
    local last=0 busy=1
    while [ "$busy" = 1 ]; do
        busy=0
        for job in "${JOBS[@]}"; do running "$(job_name "$job")" && busy=1; done
        [ "$busy" = 1 ] || break
        if [ "$(seconds_left)" -lt 15 ]; then say "still training; call again"; return 1; fi
        if [ $((SECONDS - last)) -ge 60 ]; then
            last=$SECONDS
            for job in "${JOBS[@]}"; do
                say "$(job_name "$job"): $(tail -n 1 "$(job_dir "$job")/train.log" 2>/dev/null || true)"
            done
        fi
        sleep 5
    done
    for job in "${JOBS[@]}"; do
        [ -f "$(job_dir "$job")/eval-lab.json" ] \
            || { say "$(job_name "$job") ended without its evaluation: see $RUNS/$(job_name "$job").out"; return 1; }
    done
}

# frames per second at batch 1, one model at a time (the evaluations above may have shared the GPU)
speed() {
    local job
    for job in "${JOBS[@]}"; do
        [ "$(seed_of "$job")" = 0 ] || continue
        local out="$RESULTS/seed0/$(model_of "$job")/speed.json"
        [ -f "$out" ] && continue
        mkdir -p "$(dirname "$out")"
        $PYTHON -m togcrf eval "$(job_dir "$job")/checkpoint.pt" --data "$DATA" --pipeline "$PIPELINE" \
            --device cuda --max-samples 40 --speed-images 40 --out "$out" > /dev/null
    done
}

report() {
    local job run_dirs=() lab_files=()
    for job in "${JOBS[@]}"; do run_dirs+=("$(job_dir "$job")"); lab_files+=("$(job_dir "$job")/eval-lab.json"); done
    $PYTHON -m togcrf table "${run_dirs[@]}" --out "$RESULTS/table2.json" | tee "$RESULTS/table2.txt"
    $PYTHON -m togcrf table "${lab_files[@]}" --out "$RESULTS/table2-lab.json" | tee "$RESULTS/table2-lab.txt"
    if [ "$(printf '%s\n' "${JOBS[@]}" | cut -d: -f1 | sort -u | wc -l)" -gt 1 ]; then
        # several seeds: each model's mean and standard deviation over its seeds
        $PYTHON -m togcrf table "${run_dirs[@]}" --mean --out "$RESULTS/means.json" | tee "$RESULTS/means.txt"
        $PYTHON -m togcrf table "${lab_files[@]}" --mean --out "$RESULTS/means-lab.json" | tee "$RESULTS/means-lab.txt"
    fi
    $PYTHON -m togcrf curves "${run_dirs[@]}" --out "$RESULTS/curves.png"
    for job in "${JOBS[@]}"; do
        local into="$RESULTS/seed$(seed_of "$job")/$(model_of "$job")"
        mkdir -p "$into"
        cp "$(job_dir "$job")"/{eval.json,eval-lab.json,metrics.csv,config.json,train.log} "$into/"
    done
    cp -r "$RUNS/seed0/figures" "$RESULTS/" 2>/dev/null || true
    cp "$RUNS/seed0/prediction.png" "$RESULTS/" 2>/dev/null || true
}

pack() {
    [ -n "${OUT:-}" ] && tar -czf "$OUT/results.tar.gz" -C "$RUNS" results table-gpu.log \
        $(cd "$RUNS" && ls ./*.out 2>/dev/null) $(cd "$RUNS" && ls throughput/*.out 2>/dev/null) || true
}
trap pack EXIT

install
build_data
throughput
train
speed
report
say "done"
echo "table-gpu: done"
