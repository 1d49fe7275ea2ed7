"""`togcrf reproduce`: its scales are the presets, and a tiny end-to-end run writes both protocols' tables."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest
import torch
from helpers import write_synthetic_samples

from osgd.store import ShardStore
from togcrf.checkpoint import load_checkpoint
from togcrf.config import CPU, GPU, SMALL
from togcrf.reproduce import model_config, reproduce, resolve_scale


def test_scales_are_the_presets_and_the_cpu_recipe():
    assert resolve_scale("cpu") == CPU and resolve_scale("small") == SMALL
    assert resolve_scale("cpu") is not CPU  # a copy: changing it leaves the preset alone
    assert resolve_scale("auto") == (resolve_scale("paper") if torch.cuda.is_available() else CPU)
    with pytest.raises(ValueError, match="expected auto, paper, gpu, cpu, small"):
        resolve_scale("huge")
    config = model_config(CPU, "data", "runs/x", "tog", pipeline="recipe-pairs96", device="cpu", seed=3,
                          resume=False)
    config.validate()
    assert (config.data, config.out, config.model, config.seed) == ("data", "runs/x", "tog", 3)
    assert config.optimizer == "adamw" and config.lr_schedule == "cosine" and config.time_budget_minutes == 60
    # bfloat16 where the CPU has it (togcrf.engine falls back to float32 elsewhere)
    assert config.cpu_bf16 and not replace(CPU, cpu_bf16=False).cpu_bf16
    # the grasp anchors scale with the image from ROI-GD's 12 px at 192 px
    assert config.model_options.grasp_head.anchor_size == pytest.approx(12.0 * config.image_size / 192, abs=0.1)


def test_the_gpu_scale_is_the_cpu_recipe_at_native_size():
    gpu = resolve_scale("gpu")
    assert gpu == GPU and gpu.image_size == 320 and gpu.workers > 0
    config = model_config(gpu, "data", "runs/x", "tog-crfs", pipeline="gpu", device="cuda", seed=0, resume=False)
    config.validate()
    assert (config.optimizer, config.lr_schedule, config.workers) == ("adamw", "cosine", gpu.workers)
    assert config.model_options.grasp_head.anchor_size == pytest.approx(12.0 * 320 / 192)


def test_reproduce_writes_both_protocols_tables(tmp_path):
    data_dir = tmp_path / "data"
    write_synthetic_samples(ShardStore(data_dir), 10, test_every=5)
    write_synthetic_samples(ShardStore(data_dir), 10, seed=2, test_every=5, pipeline="novel")
    tiny = replace(SMALL, epochs=1, image_size=64, max_samples=2, eval_max_samples=2, warmup_steps=1,
                   model_options={"grasp_head.channels": 32, "box_head.size": 128,
                                  "box_head.detections_per_image": 5})
    result = reproduce(data_dir, tmp_path / "out", tiny, pipeline="synthetic", models=("tog",), device="cpu",
                       speed_images=1, test_sets={"seen": "synthetic", "novel": "novel"})
    assert [name for name, _ in result["rows"]] == ["TOG"]
    # the table per test set: a row per set and protocol, the novel set's tools all unseen
    sets = (tmp_path / "out" / "table2-sets.txt").read_text()
    assert all(f"TOG / {name} [{protocol}]" in sets for name in ("seen", "novel") for protocol in ("ours", "lab"))
    novel = json.loads((tmp_path / "out" / "table2-sets.json").read_text())["runs"]["TOG"]["test_sets"]["novel"]
    assert novel["images"] == 2 and novel["tools"] >= 1 and novel["novel_tools"] == novel["tools"]
    for suffix, protocol in (("", "ours"), ("-lab", "lab")):
        assert (tmp_path / "out" / f"table2{suffix}.txt").read_text().startswith(f"Algorithm [protocol: {protocol}]")
        table = json.loads((tmp_path / "out" / f"table2{suffix}.json").read_text())
        assert table["protocol"] == protocol and table["rows"][0]["name"] == "TOG"
        assert table["scale"]["model_options"]["grasp_head"]["channels"] == 32 and "data" not in table["scale"]
        evaluation = json.loads((tmp_path / "out" / "tog" / f"eval{suffix}.json").read_text())
        assert evaluation["protocol"] == protocol and evaluation["metrics"]["images"] == 2
    _, config = load_checkpoint(tmp_path / "out" / "tog" / "checkpoint.pt")
    assert config["model_options"]["grasp_head"]["channels"] == 32
