"""Record or replay the fixed-seed training trace: 30 steps on the golden samples, per-step losses and evaluation.

``python tests/trace_training.py OUT.json`` trains each traced model for 30 steps (seed 0, one thread,
the portable CPU kernels set below) on the committed golden samples and writes every step's loss terms
and the evaluation document's figures of the checkpoint. ``tests/test_training_trace.py`` runs it in a
subprocess and compares the result with ``tests/traces/training-trace.json``, so that a change of the
code that should not change what is learned shows when it does.

Every kernel whose code path depends on the processor is pinned before torch loads, so that the trace is
the same on any x86-64 processor: ``ATEN_CPU_CAPABILITY=default`` (ATen's baseline vector kernels),
``MKL_CBWR=COMPATIBLE`` (MKL's matrix products in its processor-independent mode) and oneDNN switched off
(``torch.backends.mkldnn``: its convolutions choose kernels and blockings by processor), so convolutions
run as ATen's im2col and MKL's products. One thread: the order of every sum is fixed.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("ATEN_CPU_CAPABILITY", "default")
os.environ.setdefault("MKL_CBWR", "COMPATIBLE")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import pyarrow.parquet as pq
import torch

from osgd.store import ShardStore
from togcrf.config import TrainConfig
from togcrf.evaluate import evaluate_checkpoint
from togcrf.train import train

ROOT = Path(__file__).resolve().parents[1]

#: Steps of each traced run (2 steps per epoch: 4 samples, batch 2).
STEPS = 30

#: The CPU recipe's model options at a width that trains quickly.
RECIPE_OPTIONS = {"backbone": {"fpn_min_stride": 8, "fpn_max_stride": 16, "fpn_channels": 32},
                  "rpn": {"anchor_sizes": [27, 53, 107], "pre_nms_train": 200, "post_nms_train": 100,
                          "pre_nms_test": 100, "post_nms_test": 50},
                  "box_head": {"batch_per_image": 64, "size": 64, "detections_per_image": 10},
                  "grasp_head": {"channels": 32, "anchor_size": 10.0, "rois_per_image": 4},
                  "loss": {"ranking_weight": 0.2}}

#: The traced runs: name -> training options (on top of the common ones in :func:`trace_run`).
RUNS = {
    "tog-crfs-recipe": {"model": "tog-crfs", "optimizer": "adamw", "lr_schedule": "cosine", "lr": 0.001,
                        "scale_jitter": 0.15, "model_options": RECIPE_OPTIONS},
    "fcgn-task-sgd": {"model": "fcgn-task", "optimizer": "sgd", "lr": 0.01,
                      "model_options": {"box_head": {"size": 64}, "backbone": {"fpn_channels": 32},
                                        "rpn": {"pre_nms_train": 200, "post_nms_train": 100},
                                        "fcgn": {"channels": 32}}},
}

#: Evaluation figures compared (the speed columns are left out: they are timings).
EVAL_KEYS = ("mAP", "mAP-G", "Acc-T top1", "Acc-T top5", "Acc-T top10")


def golden_data(root: Path) -> Path:
    """A data dir holding the committed golden samples shards as pipeline "golden"."""
    store = ShardStore(root)
    manifest = json.loads((ROOT / "data" / "manifests" / "golden.json").read_text())
    records = [store.write("samples", shard["key"], shard["item"],
                           pq.read_table(ROOT / "data" / "golden" / "samples" / f"{shard['key']}.parquet"))
               for shard in manifest["stages"]["samples"]["shards"]]
    store.write_manifest("golden", {"stages": {"samples": {"shards": [record.as_dict() for record in records]}}})
    return root


def trace_run(data: Path, out: Path, options: dict) -> dict:
    """Train one traced run; its per-step losses and its evaluation figures."""
    steps: list[dict[str, float]] = []

    def record(event) -> None:
        if event.metrics is None:
            steps.append({key: float(value) for key, value in event.losses.items()})

    config = TrainConfig(data=str(data), out=str(out), pipeline="golden", backbone="resnet18",
                         epochs=STEPS // 2, batch_size=2, max_samples=4, image_size=128, warmup_steps=5,
                         device="cpu", seed=0, **options)
    train(config, record)
    document = evaluate_checkpoint(out / "checkpoint.pt", data, pipeline="golden", split="train",
                                   speed_images=0)
    return {"steps": steps, "eval": {key: document["row"][key] for key in EVAL_KEYS if key in document["row"]}}


def main(path: str) -> None:
    torch.set_num_threads(1)
    torch.backends.mkldnn.enabled = False
    with tempfile.TemporaryDirectory() as folder:
        data = golden_data(Path(folder) / "data")
        trace = {name: trace_run(data, Path(folder) / name, options) for name, options in RUNS.items()}
    Path(path).write_text(json.dumps(trace, indent=1) + "\n")


if __name__ == "__main__":
    main(sys.argv[1])
