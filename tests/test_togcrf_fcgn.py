"""The FCGN + Task baseline: anchors, training losses and the contract's eval output."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest
import torch

from osgd.contract.taxonomy import TASK_INDEX, TASKS
from togcrf.anchors import ANCHOR_ANGLES
from togcrf.fcgn import box_candidates, image_anchors
from togcrf.losses import LOSS_KEYS
from togcrf.model import MODEL_NAMES, GraspDetector, build_model


def _targets() -> list[dict[str, torch.Tensor]]:
    return [{
        "boxes": torch.tensor([[10.0, 10.0, 60.0, 40.0], [50.0, 50.0, 110.0, 100.0]]),
        "labels": torch.tensor([1, 2]),
        "grasps": torch.tensor([[30.0, 25.0, 20.0, 8.0, 0.3], [80.0, 75.0, 20.0, 8.0, -1.2]]),
        "grasp_objects": torch.tensor([0, 1]),
        "grasp_tasks": torch.tensor([TASK_INDEX["cut"], TASK_INDEX["hand over"]]),
    }]


def _image() -> torch.Tensor:
    image = torch.zeros(1, 128, 128)
    image[0, 10:40, 10:60] = 1.0
    image[0, 50:100, 50:110] = 0.5
    return image


def test_image_anchors_follow_the_grasp_head_order() -> None:
    anchors = image_anchors(3, 5, 8.0, 16.0)
    assert anchors.shape == (3 * 5 * 4, 5)
    row, column, angle = 2, 3, 1
    anchor = anchors[(row * 5 + column) * 4 + angle]
    assert anchor[:2].tolist() == [(column + 0.5) * 8, (row + 0.5) * 8]
    assert anchor[2:4].tolist() == [16.0, 16.0]
    assert anchor[4].item() == pytest.approx(ANCHOR_ANGLES[angle])


def test_build_model_returns_fcgn_task() -> None:
    assert "fcgn-task" in MODEL_NAMES
    model = build_model("fcgn-task", "resnet18", {"fcgn.level": 2, "box_head.detections_per_image": 7})
    assert isinstance(model, GraspDetector) and model.grasp_branch == "image"
    assert model.options.fcgn.level == 2
    assert model.grasp_stride == 16 and model.options.box_head.detections_per_image == 7
    assert model.crf is None
    with pytest.raises(ValueError, match="unknown model option no_such_option"):
        build_model("fcgn-task", "resnet18", {"no_such_option": 1})
    with pytest.raises(ValueError, match=r"fcgn\.level must be 0-3"):
        build_model("fcgn-task", "resnet18", {"fcgn.level": 4})


def test_fcgn_task_builds_only_its_own_grasp_head() -> None:
    """FCGN + Task builds its own grasp head only (no TOG head built and thrown away)."""
    model = build_model("fcgn-task", "resnet18", {"fcgn.channels": 32, "fcgn.blocks": 2})
    assert model.grasp_head.entry.out_channels == 32 and len(model.grasp_head.blocks) == 3  # 2 blocks + norm
    assert {name.split(".")[0] for name in model.state_dict()} == {"backbone", "rpn", "roi_heads", "grasp_head"}
    with pytest.raises(ValueError, match="unknown grasp branch"):
        GraspDetector("resnet18", grasp_branch="pixels")


def test_the_fcgn_module_does_not_import_the_model_module() -> None:
    """togcrf.model composes the branch of togcrf.fcgn: no import circle."""
    script = "import sys, togcrf.fcgn; print('togcrf.model' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "False"


def test_box_candidates_keep_the_most_stable_inside_each_box() -> None:
    rectangles = torch.tensor([[5.0, 5.0, 4.0, 2.0, 0.1], [6.0, 6.0, 4.0, 2.0, 0.2], [50.0, 50.0, 4.0, 2.0, 0.3]])
    stable = torch.tensor([0.2, 0.9, 0.5])
    task_probs = torch.eye(3, len(TASKS))
    boxes = torch.tensor([[0.0, 0.0, 10.0, 10.0], [40.0, 40.0, 60.0, 60.0]])
    grasps, stability, probs = box_candidates(rectangles, stable, task_probs, boxes, keep=5)
    assert grasps.shape == (2, 2, 5) and stability.shape == (2, 2) and probs.shape == (2, 2, len(TASKS))
    assert stability.tolist() == [pytest.approx([0.9, 0.2]), pytest.approx([0.5, 0.0])]
    assert grasps[0, 0].tolist() == rectangles[1].tolist() and grasps[1, 0].tolist() == rectangles[2].tolist()
    assert grasps[1, 1].tolist() == [50.0, 50.0, 0.0, 0.0, 0.0]  # padding: an empty rectangle at the centre
    assert torch.allclose(probs[1, 1], torch.full((len(TASKS),), 1 / len(TASKS)))
    assert box_candidates(rectangles, stable, task_probs, boxes, keep=1)[0].shape == (2, 1, 5)


def test_training_losses_fall_when_fitting_one_image() -> None:
    torch.manual_seed(0)
    model = build_model("fcgn-task", "resnet18", {"fcgn.channels": 32})
    model.train()
    losses = model([_image()], _targets())
    assert tuple(losses) == LOSS_KEYS
    assert all(torch.isfinite(value) and value.dim() == 0 for value in losses.values())
    # Each of the two grasps lies in one cell and within 22.5 degrees of at least one anchor angle.
    assert 2 <= model.last_training_stats["positive_candidates"] <= 4
    grasp_keys = ("grasp_stability", "grasp_regression", "grasp_task")
    first = sum(float(losses[key].detach()) for key in grasp_keys)
    # Fit the grasp part alone (the detector's part is torchvision's and tested there).
    for name, parameter in model.named_parameters():
        parameter.requires_grad_(name.startswith("grasp_head."))
    optimiser = torch.optim.Adam(model.grasp_head.parameters(), lr=1e-3)
    for _ in range(5):
        optimiser.zero_grad()
        losses = model([_image()], _targets())
        sum(losses[key] for key in grasp_keys).backward()
        optimiser.step()
    assert sum(float(losses[key].detach()) for key in grasp_keys) < 0.8 * first


def test_eval_output_follows_the_contract() -> None:
    torch.manual_seed(1)
    model = build_model("fcgn-task", "resnet18", {"fcgn.channels": 32, "fcgn.candidates_per_box": 20,
                                                  "box_head.score_threshold": 0.0, "box_head.detections_per_image": 6})
    model.eval()
    with torch.inference_mode():
        outputs = model([_image(), _image()[:, :96, :120]])
    assert len(outputs) == 2
    for output in outputs:
        count = len(output["boxes"])
        assert count > 0
        candidates = output["grasps"].shape[1]
        assert 0 < candidates <= 20
        assert output["grasps"].shape == (count, candidates, 5)
        assert output["grasp_stability"].shape == (count, candidates)
        assert output["grasp_task_probs"].shape == (count, candidates, len(TASKS))
        assert torch.all(output["scores"][:-1] >= output["scores"][1:])
        assert torch.allclose(output["grasp_task_probs"].sum(-1), torch.ones(count, candidates), atol=1e-5)
        real = output["grasp_stability"] > 0
        centres = output["grasps"][..., :2]
        boxes = output["boxes"][:, None]
        inside = ((centres >= boxes[..., :2]) & (centres <= boxes[..., 2:])).all(-1)
        assert torch.all(inside[real])  # every real candidate lies in its box
        assert torch.all(output["grasps"][..., 2][~real] == 0)  # padding is an empty rectangle
        assert torch.all(output["grasps"][..., 4].abs() <= math.pi / 2 + 1e-6)
