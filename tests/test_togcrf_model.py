"""The TOG / TOG-CRFs model: the API of the contract, losses, gradients and detections."""

from __future__ import annotations

import pytest
import torch
from helpers import write_synthetic_samples

from osgd.store import ShardStore
from togcrf import evaluate, reproduce
from togcrf.anchors import CANDIDATES_PER_ROI, roi_anchors
from togcrf.data import SamplesDataset, collate
from togcrf.losses import LOSS_KEYS
from togcrf.model import (
    MODEL_NAMES,
    MODELS,
    PAPER_NAMES,
    GraspDetector,
    build_model,
)
from togcrf.model.targets import padded_object_grasps

#: A small configuration that keeps CPU tests quick.
SMALL = {"grasp_head.channels": 32, "box_head.size": 128, "box_head.batch_per_image": 64, "rpn.pre_nms_train": 200,
         "rpn.post_nms_train": 100, "rpn.pre_nms_test": 100, "rpn.post_nms_test": 50, "grasp_head.rois_per_image": 4,
         "box_head.detections_per_image": 5}


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    root = tmp_path_factory.mktemp("model")
    write_synthetic_samples(ShardStore(root), 4, seed=5)
    dataset = SamplesDataset(root, pipeline="synthetic", split=None, image_size=96)
    return collate([dataset[0], dataset[1]])


def test_padded_object_grasps_groups_the_grasps_of_each_object():
    targets = [
        {"boxes": torch.zeros(2, 4), "grasps": torch.arange(15.0).reshape(3, 5),
         "grasp_objects": torch.tensor([1, 0, 1]), "grasp_tasks": torch.tensor([4, 5, 6])},
        {"boxes": torch.zeros(1, 4), "grasps": torch.full((1, 5), 9.0),
         "grasp_objects": torch.tensor([0]), "grasp_tasks": torch.tensor([7])},
    ]
    grasps, valid, tasks, first = padded_object_grasps(targets)
    assert first.tolist() == [0, 2]
    assert valid.tolist() == [[True, False], [True, True], [True, False]]
    assert grasps[0, 0].tolist() == targets[0]["grasps"][1].tolist()
    assert grasps[1].tolist() == targets[0]["grasps"][[0, 2]].tolist()
    assert tasks[1].tolist() == [4, 6] and tasks[2, 0].item() == 7
    assert grasps[2, 0].tolist() == [9.0] * 5


def test_the_registry_gives_table_two_its_rows_and_every_module_its_names():
    assert MODEL_NAMES == ("fcgn-task", "tog", "tog-crfs-omega", "tog-crfs-mu", "tog-crfs")
    assert list(PAPER_NAMES.values()) == ["FCGN + Task", "TOG", "TOG-CRFs omega", "TOG-CRFs mu", "TOG-CRFs"]
    assert [spec.grasp_branch for spec in MODELS.values()] == ["image", "roi", "roi", "roi", "roi"]
    assert reproduce.TABLE_MODELS is MODEL_NAMES and evaluate.PAPER_NAMES is PAPER_NAMES
    # The losses, in the order of the columns of metrics.csv.
    assert LOSS_KEYS == ("rpn_objectness", "rpn_box", "rcnn_class", "rcnn_box", "grasp_stability",
                         "grasp_regression", "grasp_task")


#: Checkpoint layout of each model with the default options: state-dict entries, parameter and buffer elements
#: and top-level modules. Checkpoints of earlier versions load only while these stay the same.
CHECKPOINT_LAYOUT = {
    "fcgn-task": (114, 28741586, {"backbone", "rpn", "roi_heads", "grasp_head"}),
    "tog": (124, 32043090, {"backbone", "rpn", "roi_heads", "grasp_head"}),
    "tog-crfs-omega": (125, 32043234, {"backbone", "rpn", "roi_heads", "grasp_head", "crf"}),
    "tog-crfs-mu": (125, 32043234, {"backbone", "rpn", "roi_heads", "grasp_head", "crf"}),
    "tog-crfs": (126, 32043378, {"backbone", "rpn", "roi_heads", "grasp_head", "crf"}),
}


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_the_checkpoint_layout_of_every_model_stays(name):
    state = build_model(name, "resnet18").state_dict()
    layout = (len(state), sum(value.numel() for value in state.values()), {key.split(".")[0] for key in state})
    assert layout == CHECKPOINT_LAYOUT[name]


def test_build_model_names_and_variants():
    assert build_model("tog", "resnet18", {**SMALL}).crf is None
    omega_only = build_model("tog-crfs-omega", "resnet18", {**SMALL})
    assert omega_only.crf.omega.shape == (12, 12) and omega_only.crf.mu is None
    mu_only = build_model("tog-crfs-mu", "resnet18", {**SMALL})
    assert mu_only.crf.omega is None and mu_only.crf.mu.shape == (12, 12)
    with pytest.raises(ValueError, match="unknown model"):
        build_model("tog-xyz")
    with pytest.raises(ValueError, match="unknown backbone"):
        build_model("tog", "vgg16")
    with pytest.raises(ValueError, match="unknown model option no_such_option"):
        build_model("tog", "resnet18", {"no_such_option": 1})


def test_backbone_takes_depth_and_has_trainable_normalisation():
    model = build_model("tog", "resnet18", {**SMALL})
    assert model.backbone.body.conv1.in_channels == 1
    norms = [module for module in model.backbone.modules() if isinstance(module, torch.nn.GroupNorm)]
    assert norms and all(module.weight.requires_grad for module in norms)
    batch_norm = build_model("tog", "resnet18", {"backbone.norm": "batch", **SMALL})
    assert any(isinstance(module, torch.nn.BatchNorm2d) for module in batch_norm.backbone.modules())


def test_fpn_max_stride_16_stops_the_resnet_after_c4_and_still_trains(batch):
    full = build_model("tog", "resnet18", {"backbone.fpn_min_stride": 8, "rpn.anchor_sizes": (16, 32, 64, 128),
                                           **SMALL})
    short = build_model("tog", "resnet18", {"backbone.fpn_min_stride": 8, "backbone.fpn_max_stride": 16,
                                            "rpn.anchor_sizes": (16, 32, 64), **SMALL})
    assert hasattr(full.backbone.body, "layer4") and not hasattr(short.backbone.body, "layer4")
    assert short.roi_heads.box_roi_pool.scales == [1 / 8, 1 / 16]
    images, targets, _ = batch
    with torch.no_grad():
        maps = short.backbone(torch.stack(images))
    assert list(maps) == ["0", "1", "pool"]
    assert [maps[name].shape[-1] for name in maps] == [96 // 8, 96 // 16, 96 // 32]
    short.train()
    losses = short(images, targets)
    assert all(torch.isfinite(value) for value in losses.values())
    with pytest.raises(ValueError, match="expected 3 sizes"):
        build_model("tog", "resnet18", {"backbone.fpn_min_stride": 8, "backbone.fpn_max_stride": 16,
                                        "rpn.anchor_sizes": (16, 32, 64, 128)})
    with pytest.raises(ValueError, match="fpn_max_stride 8"):
        build_model("tog", "resnet18", {"backbone.fpn_max_stride": 8})


def test_training_returns_the_losses_and_gradients_reach_the_crf(batch):
    torch.manual_seed(0)
    images, targets, _ = batch
    model = build_model("tog-crfs", "resnet18", {**SMALL})
    model.train()
    losses = model(images, targets)
    assert tuple(losses) == LOSS_KEYS
    assert all(value.dim() == 0 and torch.isfinite(value) for value in losses.values())
    assert losses["grasp_task"] > 0 and model.last_training_stats["positive_candidates"] > 0
    sum(losses.values()).backward()
    for parameter in (model.crf.omega, model.crf.mu, model.backbone.body.conv1.weight,
                      model.grasp_head.task.weight, model.grasp_head.stability.weight):
        assert parameter.grad is not None and float(parameter.grad.abs().sum()) > 0
    with pytest.raises(ValueError, match="targets"):
        model(images)


def test_detections_follow_the_contract(batch):
    torch.manual_seed(0)
    images, _, _ = batch
    model: GraspDetector = build_model("tog-crfs", "resnet18", {"box_head.score_threshold": 0.0, **SMALL})
    with torch.no_grad():
        # zero regression: every candidate is its anchor, so the rectangles must be the RoI anchors
        model.grasp_head.regression.weight.zero_()
        model.grasp_head.regression.bias.zero_()
    model.eval()
    with torch.no_grad():
        outputs = model(images)
    assert len(outputs) == len(images)
    for output in outputs:
        count = len(output["boxes"])
        assert count > 0
        assert output["boxes"].dtype == torch.float32 and output["labels"].dtype == torch.int64
        assert output["grasps"].shape == (count, CANDIDATES_PER_ROI, 5)
        assert output["grasp_stability"].shape == (count, CANDIDATES_PER_ROI)
        assert output["grasp_task_probs"].shape == (count, CANDIDATES_PER_ROI, 12)
        assert torch.allclose(output["grasp_task_probs"].sum(-1), torch.ones(count, CANDIDATES_PER_ROI), atol=1e-5)
        assert ((output["grasp_stability"] >= 0) & (output["grasp_stability"] <= 1)).all()
        assert (output["scores"][:-1] >= output["scores"][1:]).all()
        assert ((output["labels"] >= 1) & (output["labels"] <= 10)).all()
        expected = roi_anchors(output["boxes"], model.options.grasp_head.anchor_size)
        assert torch.allclose(output["grasps"], expected, atol=1e-4)


def test_every_model_is_the_one_detector_with_its_grasp_branch():
    for name, spec in MODELS.items():
        model = build_model(name, "resnet18", {**SMALL})
        assert type(model) is GraspDetector and model.grasp_branch == spec.grasp_branch
        assert (model.crf is None) == (spec.crf_terms is None)


def test_images_without_objects_train_with_zero_grasp_losses():
    model = build_model("tog-crfs", "resnet18", {**SMALL})
    model.train()
    empty = {"boxes": torch.zeros(0, 4), "labels": torch.zeros(0, dtype=torch.int64), "grasps": torch.zeros(0, 5),
             "grasp_objects": torch.zeros(0, dtype=torch.int64), "grasp_tasks": torch.zeros(0, dtype=torch.int64)}
    losses = model([torch.zeros(1, 64, 64), torch.zeros(1, 48, 64)], [empty, dict(empty)])
    assert all(torch.isfinite(value) for value in losses.values())
    assert losses["grasp_task"].item() == 0 and losses["rcnn_class"].item() > 0
    sum(losses.values()).backward()

