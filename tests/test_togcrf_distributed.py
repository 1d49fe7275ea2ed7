"""Data-parallel training (togcrf.distributed): the sampler's shares, and torchrun with two gloo processes."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from helpers import write_synthetic_samples
from torch.utils.data import DataLoader

from osgd.store import ShardStore
from togcrf.data import SamplesDataset, ShardGroupedSampler, collate
from togcrf.model import build_model
from togcrf.train import TrainConfig, build_optimizer

ROOT = Path(__file__).resolve().parents[1]

#: A small TOG that keeps two processes quick on 2 cores (see tests/test_togcrf_train.py).
SMALL = {"grasp_head.channels": 32, "box_head.size": 128, "box_head.batch_per_image": 64, "rpn.pre_nms_train": 200,
         "rpn.post_nms_train": 100, "rpn.pre_nms_test": 100, "rpn.post_nms_test": 50, "grasp_head.rois_per_image": 4,
         "box_head.detections_per_image": 10}


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("distributed")
    write_synthetic_samples(ShardStore(root), 8, seed=11)
    return root


def test_ranks_take_their_share_of_each_global_batch(data_dir: Path) -> None:
    dataset = SamplesDataset(data_dir, pipeline="synthetic")
    single = ShardGroupedSampler(dataset, seed=3)
    single.set_epoch(2)
    order = list(single)
    shares = []
    for rank in range(3):
        sampler = ShardGroupedSampler(dataset, seed=3, rank=rank, world=3, batch_size=2)
        sampler.set_epoch(2)
        shares.append(list(sampler))
        assert len(shares[-1]) == len(sampler) == 2  # 8 items: one global batch of 6, the last 2 dropped
    # step k of rank r holds items [k * 6 + 2 r, k * 6 + 2 r + 2) of the single process's order
    assert [item for share in shares for item in share] == order[:6]


def _train_arguments(data_dir: Path, out: Path) -> list[str]:
    options = [item for name, value in SMALL.items() for item in ("--option", f"{name}={value}")]
    return ["train", "--data", str(data_dir), "--pipeline", "synthetic", "--out", str(out), "--model", "tog",
            "--backbone", "resnet18", "--epochs", "1", "--image-size", "64", "--max-samples", "2",
            "--batch-size", "1", "--lr", "0.01", "--warmup-steps", "0", "--clip-grad-norm", "0", "--device", "cpu",
            *options]


def _reference_step(data_dir: Path) -> dict[str, torch.Tensor]:
    """One SGD step on the mean of the two samples' gradients, each drawn as a rank draws it."""
    config = TrainConfig(data=str(data_dir), out="unused", pipeline="synthetic", model="tog", backbone="resnet18",
                         epochs=1, image_size=64, max_samples=2, batch_size=1, lr=0.01, warmup_steps=0,
                         clip_grad_norm=0.0, device="cpu", model_options=SMALL)
    dataset = SamplesDataset(data_dir, pipeline="synthetic", image_size=64, augment=True, seed=0, max_samples=2,
                             scale_jitter=config.scale_jitter)
    dataset.set_epoch(0)
    sampler = ShardGroupedSampler(dataset, seed=0)
    sampler.set_epoch(0)
    torch.manual_seed(0)
    model = build_model("tog", "resnet18", {**SMALL})
    model.train()
    gradients: dict[str, torch.Tensor] = {}
    for item in list(sampler)[:2]:
        model.zero_grad(set_to_none=True)
        torch.manual_seed(0)  # every rank seeds its epoch alike, then the loader draws its base seed
        for images, targets, _ in DataLoader(dataset, batch_size=1, sampler=[item], collate_fn=collate):
            sum(model(images, targets).values()).backward()
        for name, parameter in model.named_parameters():
            if parameter.grad is not None:
                gradients[name] = gradients.get(name, 0) + parameter.grad / 2
    optimizer = build_optimizer(model, config)
    for name, parameter in model.named_parameters():
        parameter.grad = gradients.get(name)
    optimizer.step()
    return {name: value.detach().clone() for name, value in model.state_dict().items()}


def test_two_processes_take_the_step_of_their_averaged_gradients(data_dir: Path, tmp_path: Path) -> None:
    """torchrun, 2 gloo processes at batch 1: one step equals the step on the mean of their gradients."""
    out = tmp_path / "two"
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2",
               "-m", "togcrf", *_train_arguments(data_dir, out)]
    result = subprocess.run(command, check=False, cwd=ROOT, capture_output=True, text=True, timeout=600,
                            env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert result.returncode == 0, result.stderr[-3000:]
    checkpoint = torch.load(out / "checkpoint.pt", weights_only=True)
    rows = (out / "metrics.csv").read_text().splitlines()
    assert len(rows) == 2 and rows[1].split(",")[1:3] == ["1", "1"]  # rank 0's one step of one sample
    assert (out / "train.log").read_text().count("epoch 1/1 done") == 1  # one process reported

    reference = _reference_step(data_dir)
    torch.manual_seed(0)
    initial = build_model("tog", "resnet18", {**SMALL}).state_dict()
    step = _distance(reference, initial)
    assert step > 1e-3
    assert _distance(reference, checkpoint["model"]) < 1e-4 * step


def _distance(first: dict[str, torch.Tensor], second: dict[str, torch.Tensor]) -> float:
    """Euclidean distance between two state dicts."""
    return sum(float((first[name].float() - second[name].float()).norm() ** 2) for name in first) ** 0.5
