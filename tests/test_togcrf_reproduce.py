"""`togcrf reproduce`: the scales, and a tiny end-to-end run writing both protocols' tables."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest
import torch
from helpers import write_synthetic_samples

from osgd.store import ShardStore
from togcrf.checkpoint import load_checkpoint
from togcrf.reproduce import CPU_SCALE, GPU_SCALE, SMALL_SCALE, reproduce, resolve_scale


def test_scales_and_the_cpu_recipe():
    assert resolve_scale("cpu") is CPU_SCALE and resolve_scale("small") is SMALL_SCALE
    assert resolve_scale("auto") is (resolve_scale("paper") if torch.cuda.is_available() else CPU_SCALE)
    with pytest.raises(ValueError, match="expected auto, paper, gpu, cpu, small"):
        resolve_scale("huge")
    # the recipe's options build a model, and its config is a valid training config
    config = CPU_SCALE.train_config("data", "runs/x", "tog", pipeline="recipe", device="cpu", seed=0, resume=False)
    config.validate()
    assert config.optimizer == "adamw" and config.lr_schedule == "cosine" and config.time_budget_minutes == 60
    # bfloat16 where the CPU has it (togcrf.train falls back to float32 elsewhere); --no-cpu-bf16 overrides it
    assert config.cpu_bf16 and not replace(CPU_SCALE, cpu_bf16=False).train_config(
        "data", "runs/x", "tog", pipeline="recipe", device="cpu", seed=0, resume=False).cpu_bf16
    # the grasp anchors scale with the image from ROI-GD's 12 px at 192 px
    assert config.model_options["grasp_anchor_size"] == pytest.approx(12.0 * config.image_size / 192, abs=0.1)


def test_the_gpu_scale_is_the_cpu_recipe_at_native_size():
    gpu = resolve_scale("gpu")
    assert gpu is GPU_SCALE and gpu.image_size == 320 and gpu.workers > 0
    config = gpu.train_config("data", "runs/x", "tog-crfs", pipeline="gpu", device="cuda", seed=0, resume=False)
    config.validate()
    assert (config.optimizer, config.lr_schedule, config.workers) == ("adamw", "cosine", gpu.workers)
    # the grasp anchors grow with the image: 12 px at 192 px
    assert config.model_options["grasp_anchor_size"] == pytest.approx(12.0 * 320 / 192)


def test_reproduce_writes_both_protocols_tables(tmp_path):
    data_dir = tmp_path / "data"
    write_synthetic_samples(ShardStore(data_dir), 10, test_every=5)
    tiny = replace(SMALL_SCALE, epochs=1, image_size=64, max_samples=2, eval_max_samples=2, warmup_steps=1,
                   model_options=(("grasp_channels", 32), ("box_head_size", 128), ("detections_per_image", 5)))
    result = reproduce(data_dir, tmp_path / "out", tiny, pipeline="synthetic", models=("tog",), device="cpu",
                       speed_images=1)
    assert [name for name, _ in result["rows"]] == ["TOG"]
    for suffix, protocol in (("", "ours"), ("-lab", "lab")):
        assert (tmp_path / "out" / f"table2{suffix}.txt").read_text().startswith(f"Algorithm [protocol: {protocol}]")
        table = json.loads((tmp_path / "out" / f"table2{suffix}.json").read_text())
        assert table["protocol"] == protocol and table["rows"][0]["name"] == "TOG"
        evaluation = json.loads((tmp_path / "out" / "tog" / f"eval{suffix}.json").read_text())
        assert evaluation["protocol"] == protocol and evaluation["metrics"]["images"] == 2
    _, config = load_checkpoint(tmp_path / "out" / "tog" / "checkpoint.pt")
    assert config["model_options"]["grasp_channels"] == 32
