"""Training from samples shards: run dir, checkpoints, resume, the CLI, and fitting synthetic samples."""

from __future__ import annotations

import csv
import json

import pytest
import torch
from helpers import write_synthetic_samples
from torchvision.ops import box_iou
from typer.testing import CliRunner

from osgd.store import ShardStore
from togcrf.cli import app
from togcrf.data import SamplesDataset, collate
from togcrf.train import LOSS_TERMS, TrainConfig, load_checkpoint, train

#: A small model that keeps CPU runs quick (see tests/test_togcrf_model.py).
SMALL = {"grasp_channels": 32, "box_head_size": 128, "box_batch_per_image": 64, "rpn_pre_nms_train": 200,
         "rpn_post_nms_train": 100, "rpn_pre_nms_test": 100, "rpn_post_nms_test": 50, "grasp_rois_per_image": 4,
         "detections_per_image": 10}


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("train")
    write_synthetic_samples(ShardStore(root), 12, seed=11)
    return root


def quick_config(data_dir, out, **changes) -> TrainConfig:
    values = {"data": str(data_dir), "out": str(out), "pipeline": "synthetic", "model": "tog-crfs",
              "backbone": "resnet18", "epochs": 1, "batch_size": 2, "max_samples": 2, "image_size": 64,
              "warmup_steps": 1, "device": "cpu", "model_options": SMALL}
    values.update(changes)
    return TrainConfig(**values)


def test_run_dir_checkpoint_and_resume_match_an_uninterrupted_run(data_dir, tmp_path):
    straight = quick_config(data_dir, tmp_path / "straight", epochs=2)
    train(straight)
    first = quick_config(data_dir, tmp_path / "resumed", epochs=1)
    train(first)
    with pytest.raises(ValueError, match="--resume"):
        train(first)
    train(quick_config(data_dir, tmp_path / "resumed", epochs=2, resume=True))

    run_dir = tmp_path / "resumed"
    checkpoint = torch.load(run_dir / "checkpoint.pt", weights_only=False)
    assert set(checkpoint) >= {"model", "optimizer", "scheduler", "epoch", "config", "data"}
    assert checkpoint["epoch"] == 1
    assert checkpoint["config"]["model"] == "tog-crfs" and checkpoint["config"]["image_size"] == 64
    assert checkpoint["config"]["model_options"]["grasp_channels"] == 32
    assert checkpoint["data"]["pipeline"] == "synthetic" and len(checkpoint["data"]["shards"]) == 2
    rows = list(csv.DictReader((run_dir / "metrics.csv").open()))
    assert [row["epoch"] for row in rows] == ["0", "1"]
    assert set(LOSS_TERMS) <= set(rows[0]) and "train_acc_t_top1" in rows[0]
    assert json.loads((run_dir / "config.json").read_text())["backbone"] == "resnet18"

    # same seed, same data order and augmentation: resuming gives the uninterrupted run's weights
    reference = torch.load(tmp_path / "straight" / "checkpoint.pt", weights_only=False)["model"]
    for name, value in checkpoint["model"].items():
        assert torch.allclose(value.float(), reference[name].float(), atol=1e-5), name

    model, config = load_checkpoint(run_dir / "checkpoint.pt")
    assert not model.training and config["epoch"] == 1
    assert torch.equal(model.crf.omega.detach(), checkpoint["model"]["crf.omega"])
    with pytest.raises(ValueError, match="cannot resume"):
        train(quick_config(data_dir, run_dir, epochs=3, resume=True, backbone="resnet34"))


def test_cli_trains_and_refuses_to_overwrite(data_dir, tmp_path):
    runner = CliRunner()
    arguments = ["train", "--data", str(data_dir), "--pipeline", "synthetic", "--out", str(tmp_path / "run"),
                 "--model", "tog", "--backbone", "resnet18", "--epochs", "1", "--batch-size", "2",
                 "--max-samples", "2", "--image-size", "64", "--device", "cpu"]
    arguments += [item for name, value in SMALL.items() for item in ("--option", f"{name}={value}")]
    result = runner.invoke(app, arguments)
    assert result.exit_code == 0, result.output
    assert (tmp_path / "run" / "checkpoint.pt").exists()
    assert "epoch 1/1" in result.output
    again = runner.invoke(app, arguments)
    assert again.exit_code == 1 and "--resume" in again.output
    bad = runner.invoke(app, [*arguments[:-2], "--device", "cpu", "--model", "nope"])
    assert bad.exit_code == 1 and "nope" in bad.output


def fit(data_dir, out, epochs: int, samples: int, model: str = "tog-crfs") -> list[dict[str, str]]:
    torch.manual_seed(0)
    train(quick_config(data_dir, out, model=model, epochs=epochs, max_samples=samples, image_size=128,
                       augment=False, lr=0.02, warmup_steps=5))
    return list(csv.DictReader((out / "metrics.csv").open()))


def detections_found(data_dir, run_dir, samples: int) -> float:
    """Fraction of training objects with a detection of the right class at IoU >= 0.5."""
    model, config = load_checkpoint(run_dir / "checkpoint.pt")
    dataset = SamplesDataset(data_dir, pipeline="synthetic", image_size=config["image_size"], max_samples=samples)
    images, targets, _ = collate([dataset[index] for index in range(len(dataset))])
    with torch.no_grad():
        outputs = model(images)
    found = total = 0
    for output, target in zip(outputs, targets, strict=True):
        overlap = box_iou(target["boxes"], output["boxes"])
        same_class = target["labels"][:, None] == output["labels"][None, :]
        found += int(((overlap >= 0.5) & same_class).any(dim=1).sum())
        total += len(target["boxes"])
    return found / total


def test_short_training_lowers_every_loss_term(data_dir, tmp_path):
    rows = fit(data_dir, tmp_path / "run", epochs=6, samples=2)
    first, last = rows[0], rows[-1]
    for term in ("loss", "rpn_objectness", "rcnn_class", "grasp_stability", "grasp_regression", "grasp_task"):
        assert float(last[term]) < 0.8 * float(first[term]), (term, first[term], last[term])


@pytest.mark.slow
def test_longer_training_on_synthetic_samples(data_dir, tmp_path):
    """120 SGD steps on 4 samples from scratch (about 10 minutes on 2 busy cores).

    Every loss term comes clearly down except ``rcnn_box``, which grows while
    the proposals become positives, and ``grasp_stability``, which only nears
    the 1:3 hard-mining prior (0.56) this early. The model does not fit the
    samples yet at this length: about 60 % of the objects are detected and
    the on-the-fly train Acc-T top-1 is about 0.4 (see docs/togcrf.md).
    """
    rows = fit(data_dir, tmp_path / "run", epochs=60, samples=4)
    first, last = rows[0], rows[-1]
    for term in ("loss", "rpn_objectness", "rcnn_class", "grasp_regression", "grasp_task"):
        assert float(last[term]) < 0.5 * float(first[term]), (term, first[term], last[term])
    assert float(last["grasp_stability"]) < 0.6 * float(first["grasp_stability"])
    # rpn_box starts near zero and peaks as the RPN finds objects: it must come clearly down from the peak
    peak = max(float(row["rpn_box"]) for row in rows)
    assert float(last["rpn_box"]) < 0.5 * peak
    assert float(last["train_acc_t_top1"]) > float(first["train_acc_t_top1"])
    assert detections_found(data_dir, tmp_path / "run", 4) >= 0.5
