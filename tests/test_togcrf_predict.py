"""`togcrf predict` on a sample, a 16-bit PNG and a .npy, with a picture and a task choice."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from helpers import write_synthetic_samples
from typer.testing import CliRunner

from osgd.contract.samples import iter_samples
from osgd.contract.taxonomy import CATEGORIES, TASK_INDEX, TASKS
from osgd.store import ShardStore
from togcrf.cli import app
from togcrf.metrics import Detections
from togcrf.predict import best_grasp_for_task, draw_prediction, load_depth
from togcrf.train import TrainConfig, train


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """Synthetic samples and a TOG checkpoint after one training step."""
    torch.manual_seed(0)
    root = tmp_path_factory.mktemp("predict")
    data_dir = root / "data"
    write_synthetic_samples(ShardStore(data_dir), 6)
    train(TrainConfig(data=str(data_dir), out=str(root / "run"), pipeline="synthetic", model="tog",
                      backbone="resnet18", epochs=1, batch_size=2, max_samples=2, augment=False, warmup_steps=1,
                      device="cpu", amp=False,
                      model_options={"box_head.detections_per_image": 4, "rpn.post_nms_test": 50,
                                     "box_head.score_threshold": 0.0}))
    return data_dir, root / "run" / "checkpoint.pt"


def test_predict_on_a_sample_writes_json_and_an_image(trained: tuple[Path, Path], tmp_path: Path) -> None:
    data_dir, checkpoint = trained
    out, image = tmp_path / "prediction.json", tmp_path / "prediction.png"
    result = CliRunner().invoke(app, ["predict", str(checkpoint), "synthetic_000003", "--data", str(data_dir),
                                      "--out", str(out), "--image", str(image), "--min-score", "0",
                                      "--grasps-per-object", "5"])
    assert result.exit_code == 0, result.output
    document = json.loads(out.read_text())
    assert document["sample_id"] == "synthetic_000003" and document["tasks"] == list(TASKS)
    assert (document["height"], document["width"]) == (128, 128)
    assert 1 <= len(document["objects"]) <= 4
    for obj in document["objects"]:
        assert obj["category"] in CATEGORIES and len(obj["box"]) == 4
        assert len(obj["grasps"]) == 5
        stabilities = [grasp["stability"] for grasp in obj["grasps"]]
        assert stabilities == sorted(stabilities, reverse=True)
        for grasp in obj["grasps"]:
            assert len(grasp["rectangle"]) == 5 and len(grasp["task_probs"]) == 12
            assert sum(grasp["task_probs"]) == pytest.approx(1.0, abs=1e-4)
            assert grasp["task"] == TASKS[int(np.argmax(grasp["task_probs"]))]
    picture = cv2.imread(str(image))
    assert picture is not None and picture.shape[0] > 100 and picture.std() > 1


def test_predict_reads_png_in_millimetres_and_npy_in_metres(trained: tuple[Path, Path], tmp_path: Path) -> None:
    data_dir, checkpoint = trained
    sample = next(iter_samples(data_dir, pipeline="synthetic"))
    png, npy = tmp_path / "depth.png", tmp_path / "depth.npy"
    cv2.imwrite(str(png), np.round(sample.depth * 1000).astype(np.uint16))
    np.save(npy, sample.depth)
    from_png, _ = load_depth(str(png))
    from_npy, _ = load_depth(str(npy))
    assert np.allclose(from_png, sample.depth, atol=0.0006) and np.array_equal(from_npy, sample.depth)
    outputs = []
    for source in (png, npy):
        result = CliRunner().invoke(app, ["predict", str(checkpoint), str(source), "--min-score", "0",
                                          "--grasps-per-object", "1"])
        assert result.exit_code == 0, result.output
        outputs.append(json.loads(result.output))
    # Millimetre rounding barely moves the detections.
    assert len(outputs[0]["objects"]) == len(outputs[1]["objects"])
    assert np.allclose(outputs[0]["objects"][0]["box"], outputs[1]["objects"][0]["box"], atol=2.0)
    # Test-time views keep the boxes and say how many views made the grasps.
    result = CliRunner().invoke(app, ["predict", str(checkpoint), str(npy), "--min-score", "0", "--views", "8"])
    assert result.exit_code == 0, result.output
    viewed = json.loads(result.output)
    assert viewed["test_time_views"] == 8 and outputs[1]["test_time_views"] == 1
    assert [item["box"] for item in viewed["objects"]] == [item["box"] for item in outputs[1]["objects"]]


def test_predict_errors(trained: tuple[Path, Path], tmp_path: Path) -> None:
    data_dir, checkpoint = trained
    eight_bit = tmp_path / "eight.png"
    cv2.imwrite(str(eight_bit), np.zeros((8, 8), dtype=np.uint8))
    tiny = tmp_path / "tiny.png"
    cv2.imwrite(str(tiny), np.full((1, 1), 700, dtype=np.uint16))
    objects = tmp_path / "objects.npy"
    np.save(objects, np.array([{"depth": 1}], dtype=object), allow_pickle=True)
    for source, expected in ((str(eight_bit), "16-bit"), ("no_such_sample", "no_such_sample"),
                             (str(tmp_path / "gone.npy"), "gone.npy"), (str(tiny), "tiny.png: a depth image of 1 x 1"),
                             (str(objects), "objects.npy: not a numpy array of depth")):
        result = CliRunner().invoke(app, ["predict", str(checkpoint), source, "--data", str(data_dir)])
        assert result.exit_code == 1 and expected in result.output and result.output.count("\n") == 1, result.output
    result = CliRunner().invoke(app, ["predict", str(checkpoint), "synthetic_000001", "--data", str(data_dir),
                                      "--task", "hand over", "--min-score", "0"])
    assert result.exit_code == 1 and "--category" in result.output


def test_predict_picks_a_grasp_for_a_task(trained: tuple[Path, Path], tmp_path: Path) -> None:
    data_dir, checkpoint = trained
    result = CliRunner().invoke(app, ["predict", str(checkpoint), "synthetic_000001", "--data", str(data_dir),
                                      "--task", "cut", "--min-score", "0", "--grasps-per-object", "0",
                                      "--image", str(tmp_path / "cut.png")])
    assert result.exit_code == 0, result.output
    chosen = json.loads(result.output)["chosen"]
    assert chosen["task"] == "cut" and chosen["category"] in CATEGORIES and len(chosen["rectangle"]) == 5
    assert (tmp_path / "cut.png").is_file()


def _detections() -> Detections:
    task_probs = np.full((2, 3, 12), 0.01)
    task_probs[0, :, TASK_INDEX["cut"]] = [0.2, 0.9, 0.5]
    task_probs[1, :, TASK_INDEX["cut"]] = [0.95, 0.1, 0.1]
    task_probs[1, :, TASK_INDEX["hand over"]] = [0.0, 0.8, 0.8]
    grasps = np.tile(np.array([40.0, 40.0, 20.0, 6.0, 0.2]), (2, 3, 1))
    grasps[1, :, 0] = [80.0, 90.0, 100.0]
    return Detections(boxes=np.array([[20.0, 20, 60, 60], [70, 30, 110, 50]]), categories=np.array([0, 1]),
                      scores=np.array([0.9, 0.8]), grasps=grasps,
                      grasp_stability=np.array([[0.9, 0.8, 0.7], [0.3, 0.9, 0.6]]), grasp_task_probs=task_probs)


def test_best_grasp_for_task_uses_stable_candidates_and_the_category() -> None:
    detections = _detections()
    # 0.95 'cut' on object 1 is unstable (0.3 < 0.5): the stable 0.9 on object 0 wins.
    chosen = best_grasp_for_task(detections, "cut")
    assert (chosen["object"], chosen["task_probability"]) == (0, pytest.approx(0.9))
    assert best_grasp_for_task(detections, "cut", min_stability=0.0)["object"] == 1
    chosen = best_grasp_for_task(detections, "hand over", category=CATEGORIES[1])
    assert chosen["category"] == CATEGORIES[1] and chosen["rectangle"][0] == 90.0
    with pytest.raises(ValueError, match="category"):
        best_grasp_for_task(detections, "no task")
    with pytest.raises(ValueError, match="unknown task"):
        best_grasp_for_task(detections, "juggle")
    with pytest.raises(ValueError, match="no pliers"):
        best_grasp_for_task(detections, "cut", category="pliers")


def test_draw_prediction_marks_grasps(tmp_path: Path) -> None:
    depth = np.full((128, 160), 0.8, dtype=np.float32)
    detections = _detections()
    draw_prediction(depth, detections, tmp_path / "a.png")
    draw_prediction(depth, Detections(detections.boxes[:0], detections.categories[:0], detections.scores[:0],
                                      detections.grasps[:0], detections.grasp_stability[:0],
                                      detections.grasp_task_probs[:0]), tmp_path / "b.png")
    with_grasps, empty = cv2.imread(str(tmp_path / "a.png")), cv2.imread(str(tmp_path / "b.png"))
    assert with_grasps.shape == empty.shape
    saturated = (with_grasps.max(axis=2).astype(int) - with_grasps.min(axis=2)) > 60
    assert saturated.sum() > (empty.max(axis=2).astype(int) - empty.min(axis=2) > 60).sum() + 100
