#!/usr/bin/env bash
# Table II at the largest scale a GPU lease allows (issue #21), in steps that resume:
#
#   install     the dependencies, from an offline site-packages tarball where the machine has no network
#   data        pipelines/gpu.toml: the 100 procedural tools in 8,000 piles, one depth image each
#   throughput  the paper's configuration (ResNet-101, batch 2, SGD) beside the GPU recipe, 40 s each
#   train       TOG and TOG-CRFs side by side on the one GPU, the same time budget each
#               (togcrf reproduce --scale gpu: training, then evaluation under both protocols)
#   speed       frames per second at batch 1 and the CRF's share, one model at a time
#   report      both tables, learning curves, figure 5, a prediction picture, into RESULTS
#
# Each call does what is left and returns within DEADLINE seconds, so that it fits a command limit of ten
# minutes; call it again until it prints "table-gpu: done". Training runs on in the background between calls
# (setsid), and an interrupted training resumes from its last checkpoint.
#
#   make table-gpu            (or pipelines/table-gpu.sh)
#
# Variables: DATA (data), RUNS (runs/table-gpu), BUDGET (minutes of training per model, 11),
# DEADLINE (seconds, 570), RESULTS (the small result files, $RUNS/results; packed into $OUT/results.tar.gz
# when OUT is set), SITE (offline site-packages tarball, .gpu/site-py312.tar.xz), PYTHON (python3),
# WORKERS (dataset worker processes, one per core).
set -euo pipefail
cd "$(dirname "$0")/.."
started=$SECONDS
DEADLINE=${DEADLINE:-570}
DATA=${DATA:-data}
RUNS=${RUNS:-runs/table-gpu}
BUDGET=${BUDGET:-11}
RESULTS=${RESULTS:-$RUNS/results}
SITE=${SITE:-.gpu/site-py312.tar.xz}
PYTHON=${PYTHON:-python3}
WORKERS=${WORKERS:-$(nproc)}
MODELS=(tog tog-crfs)
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
    # a copy of the manifest under RUNS: a machine that syncs the working tree may remove the data dir's one
    [ -f "$DATA/manifests/gpu.json" ] || { [ -f "$RUNS/gpu.json" ] && mkdir -p "$DATA/manifests" \
        && cp "$RUNS/gpu.json" "$DATA/manifests/gpu.json"; } || true
    [ -f "$DATA/manifests/gpu.json" ] && return 0
    say "building pipelines/gpu.toml with $WORKERS workers"
    timeout "$(seconds_left)" $PYTHON -m osgd --data-dir "$DATA" --workers "$WORKERS" run pipelines/gpu.toml \
        2>&1 | tee "$RESULTS/dataset.txt"
    cp "$DATA/manifests/gpu.json" "$RUNS/gpu.json"
}

# images/s of a configuration, from its training's metrics.csv (40 s of steps, warm-up included)
measure() {
    local name=$1; shift
    [ -f "$RUNS/throughput/$name/tog/metrics.csv" ] && return 0
    say "throughput of $name"
    $PYTHON -m togcrf reproduce --data "$DATA" --pipeline gpu --models tog --out "$RUNS/throughput/$name" \
        --time-budget 0.67 --eval-max-samples 4 --speed-images 0 "$@" > "$RUNS/throughput/$name.out" 2>&1
}

throughput() {
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
train = sum(1 for path in sample_shards(data, "gpu") for split in pq.read_table(path, columns=["split"])["split"].to_pylist()
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

train() {
    for model in "${MODELS[@]}"; do
        [ -f "$RUNS/$model/eval-lab.json" ] && continue
        running "$model" && continue
        say "training and evaluating $model ($BUDGET minutes)"
        setsid nohup $PYTHON -m togcrf --log-level info reproduce --data "$DATA" --pipeline gpu --scale gpu \
            --models "$model" --out "$RUNS" --time-budget "$BUDGET" >> "$RUNS/$model.out" 2>&1 &
        echo $! > "$RUNS/$model.pid"
    done
    local last=0
    while running tog || running tog-crfs; do
        if [ "$(seconds_left)" -lt 15 ]; then say "still training; call again"; return 1; fi
        if [ $((SECONDS - last)) -ge 60 ]; then
            last=$SECONDS
            for model in "${MODELS[@]}"; do say "$model: $(tail -n 1 "$RUNS/$model/train.log" 2>/dev/null || true)"; done
        fi
        sleep 5
    done
    for model in "${MODELS[@]}"; do
        [ -f "$RUNS/$model/eval-lab.json" ] || { say "$model ended without its evaluation: see $RUNS/$model.out"; return 1; }
    done
}

# frames per second at batch 1, one model at a time (the evaluations above may have shared the GPU)
speed() {
    for model in "${MODELS[@]}"; do
        [ -f "$RESULTS/$model/speed.json" ] && continue
        mkdir -p "$RESULTS/$model"
        $PYTHON -m togcrf eval "$RUNS/$model/checkpoint.pt" --data "$DATA" --pipeline gpu --device cuda \
            --max-samples 40 --speed-images 40 --out "$RESULTS/$model/speed.json" > /dev/null
    done
}

report() {
    local run_dirs=() lab_files=()
    for model in "${MODELS[@]}"; do run_dirs+=("$RUNS/$model"); lab_files+=("$RUNS/$model/eval-lab.json"); done
    $PYTHON -m togcrf table "${run_dirs[@]}" --out "$RESULTS/table2.json" | tee "$RESULTS/table2.txt"
    $PYTHON -m togcrf table "${lab_files[@]}" --out "$RESULTS/table2-lab.json" | tee "$RESULTS/table2-lab.txt"
    $PYTHON -m togcrf curves "${run_dirs[@]}" --out "$RESULTS/curves.png"
    for model in "${MODELS[@]}"; do
        mkdir -p "$RESULTS/$model"
        cp "$RUNS/$model"/{eval.json,eval-lab.json,metrics.csv,config.json,train.log} "$RESULTS/$model/"
    done
    cp -r "$RUNS/figures" "$RESULTS/" 2>/dev/null || true
    cp "$RUNS/prediction.png" "$RESULTS/" 2>/dev/null || true
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
