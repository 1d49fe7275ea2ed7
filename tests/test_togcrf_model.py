"""The TOG / TOG-CRFs model: the API of the contract, losses, gradients and detections."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch
from helpers import write_synthetic_samples

from osgd.contract.taxonomy import CATEGORIES
from osgd.store import ShardStore
from togcrf import evaluate, reproduce, train
from togcrf.anchors import CANDIDATES_PER_ROI, decode, roi_anchors
from togcrf.data import SamplesDataset, collate
from togcrf.losses import LOSS_KEYS
from togcrf.metrics import grasp_match_matrix
from togcrf.model import (
    C2_CHANNELS,
    FINE_MAP,
    MODEL_NAMES,
    MODELS,
    PAPER_NAMES,
    GraspDetector,
    GraspHead,
    GraspOutputs,
    build_model,
    matching_candidates,
    object_map_targets,
    padded_object_grasps,
    pyramid,
    rescored,
    top_grasp_right,
    widened_boxes,
)

#: A small configuration that keeps CPU tests quick.
SMALL = {"grasp_channels": 32, "box_head_size": 128, "box_batch_per_image": 64, "rpn_pre_nms_train": 200,
         "rpn_post_nms_train": 100, "rpn_pre_nms_test": 100, "rpn_post_nms_test": 50, "grasp_rois_per_image": 4,
         "detections_per_image": 5}


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    root = tmp_path_factory.mktemp("model")
    write_synthetic_samples(ShardStore(root), 4, seed=5)
    dataset = SamplesDataset(root, pipeline="synthetic", split=None, image_size=96, instance_masks=True)
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
                         "grasp_regression", "grasp_task", "grasp_object_map", "grasp_confidence")
    assert train.LOSS_TERMS is LOSS_KEYS


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
    assert build_model("tog", **SMALL).crf is None
    omega_only = build_model("tog-crfs-omega", **SMALL)
    assert omega_only.crf.omega.shape == (12, 12) and omega_only.crf.mu is None
    mu_only = build_model("tog-crfs-mu", **SMALL)
    assert mu_only.crf.omega is None and mu_only.crf.mu.shape == (12, 12)
    with pytest.raises(ValueError, match="unknown model"):
        build_model("tog-xyz")
    with pytest.raises(ValueError, match="unknown backbone"):
        build_model("tog", "vgg16")
    with pytest.raises(TypeError, match="unknown model options"):
        build_model("tog", no_such_option=1)


def test_backbone_takes_depth_and_has_trainable_normalisation():
    model = build_model("tog", "resnet18", **SMALL)
    assert model.backbone.body.conv1.in_channels == 1
    norms = [module for module in model.backbone.modules() if isinstance(module, torch.nn.GroupNorm)]
    assert norms and all(module.weight.requires_grad for module in norms)
    batch_norm = build_model("tog", "resnet18", norm="batch", **SMALL)
    assert any(isinstance(module, torch.nn.BatchNorm2d) for module in batch_norm.backbone.modules())


def test_fpn_max_stride_16_stops_the_resnet_after_c4_and_still_trains(batch):
    full = build_model("tog", "resnet18", fpn_min_stride=8, rpn_anchor_sizes=(16, 32, 64, 128), **SMALL)
    short = build_model("tog", "resnet18", fpn_min_stride=8, fpn_max_stride=16, rpn_anchor_sizes=(16, 32, 64),
                        **SMALL)
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
        build_model("tog", fpn_min_stride=8, fpn_max_stride=16, rpn_anchor_sizes=(16, 32, 64, 128))
    with pytest.raises(ValueError, match="fpn_max_stride 8"):
        build_model("tog", fpn_max_stride=8)


def test_training_returns_the_losses_and_gradients_reach_the_crf(batch):
    torch.manual_seed(0)
    images, targets, _ = batch
    model = build_model("tog-crfs", "resnet18", **SMALL)
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
    model: GraspDetector = build_model("tog-crfs", "resnet18", box_score_threshold=0.0, **SMALL)
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
        expected = roi_anchors(output["boxes"], model.options.grasp_anchor_size)
        assert torch.allclose(output["grasps"], expected, atol=1e-4)


def test_every_model_is_the_one_detector_with_its_grasp_branch():
    for name, spec in MODELS.items():
        model = build_model(name, "resnet18", **SMALL)
        assert type(model) is GraspDetector and model.grasp_branch == spec.grasp_branch
        assert (model.crf is None) == (spec.crf_terms is None)


@pytest.mark.parametrize("object_map", [False, True])
def test_images_without_objects_train_with_zero_grasp_losses(object_map):
    model = build_model("tog-crfs", "resnet18", grasp_object_map=object_map, **SMALL)
    model.train()
    empty = {"boxes": torch.zeros(0, 4), "labels": torch.zeros(0, dtype=torch.int64), "grasps": torch.zeros(0, 5),
             "grasp_objects": torch.zeros(0, dtype=torch.int64), "grasp_tasks": torch.zeros(0, dtype=torch.int64),
             "mask_values": torch.zeros(0, dtype=torch.int64)}
    targets = [empty | {"instance_mask": torch.zeros(64, 64, dtype=torch.uint8)},
               empty | {"instance_mask": torch.zeros(48, 64, dtype=torch.uint8)}]
    losses = model([torch.zeros(1, 64, 64), torch.zeros(1, 48, 64)], targets)
    assert all(torch.isfinite(value) for value in losses.values())
    assert losses["grasp_task"].item() == 0 and losses["rcnn_class"].item() > 0
    assert losses["grasp_object_map"].item() == 0
    sum(losses.values()).backward()


def test_object_map_targets_are_the_share_of_each_cell_on_the_rois_own_object():
    left_right = torch.zeros(40, 40, dtype=torch.uint8)
    left_right[:, :20], left_right[:, 20:] = 1, 2
    top = torch.zeros(32, 48, dtype=torch.uint8)
    top[:16] = 5
    targets = [{"instance_mask": left_right, "mask_values": torch.tensor([1, 2])},
               {"instance_mask": top, "mask_values": torch.tensor([5])}]
    # RoI 0: object 0 (left half) seen through a box that reaches 8 px into object 1; RoI 1: the same box
    # for object 1; RoI 2: image 1's object (object 2 of the batch), a box over the whole image.
    rois = torch.tensor([[0.0, 0.0, 28.0, 28.0], [0.0, 0.0, 28.0, 28.0], [0.0, 0.0, 48.0, 32.0]])
    shares = object_map_targets(targets, rois, torch.tensor([0, 1, 2])).reshape(3, 7, 7)
    assert shares.shape == (3, 7, 7) and ((shares >= 0) & (shares <= 1)).all()
    # cells are 4 px wide: columns 0-4 lie left of x = 20, columns 5-6 right of it (row by row, as the head)
    assert torch.allclose(shares[0, :, :5], torch.ones(7, 5)) and torch.allclose(shares[0, :, 5:], torch.zeros(7, 2))
    assert torch.allclose(shares[1], 1 - shares[0])
    assert torch.allclose(shares[2, :3], torch.ones(3, 7)) and torch.allclose(shares[2, 4:], torch.zeros(3, 7))
    with pytest.raises(ValueError, match="instance masks"):
        object_map_targets([{"boxes": torch.zeros(1, 4)}], rois[:1], torch.tensor([0]))


def test_the_object_map_trains_and_weighs_the_stability_of_each_cell(batch):
    torch.manual_seed(0)
    images, targets, _ = batch
    assert all("instance_mask" in target and "mask_values" in target for target in targets)
    plain = build_model("tog", "resnet18", **SMALL)
    plain.train()
    assert plain.grasp_head.object_map is None and plain(images, targets)["grasp_object_map"].item() == 0
    model = build_model("tog", "resnet18", grasp_object_map=True, box_score_threshold=0.0, **SMALL)
    model.train()
    losses = model(images, targets)
    assert torch.isfinite(losses["grasp_object_map"]) and losses["grasp_object_map"] > 0
    sum(losses.values()).backward()
    assert float(model.grasp_head.object_map.weight.grad.abs().sum()) > 0
    model.eval()
    stabilities = {}
    for bias in (-20.0, 20.0):
        with torch.no_grad():
            model.grasp_head.object_map.bias.fill_(bias)
            stabilities[bias] = torch.cat([output["grasp_stability"] for output in model(images)])
    assert len(stabilities[20.0]) > 0
    assert stabilities[-20.0].max() < 1e-6 < stabilities[20.0].min()
    with pytest.raises(ValueError, match="roi"):
        build_model("fcgn-task", "resnet18", grasp_object_map=True, **SMALL)


def one_candidate_outputs(top_candidates: list[int]) -> GraspOutputs:
    """GraspOutputs of RoIs of 196 candidates, zero deltas, anchors of 10 x 10 px at angle 0 centred on
    (candidate, 0), each RoI's most stable candidate the one of ``top_candidates``."""
    rois = len(top_candidates)
    anchors = torch.zeros(rois, CANDIDATES_PER_ROI, 5)
    anchors[..., 0] = torch.arange(CANDIDATES_PER_ROI, dtype=torch.float32) * 20
    anchors[..., 2:4] = 10.0
    stability = torch.zeros(rois, CANDIDATES_PER_ROI, 2)
    stability[torch.arange(rois), torch.tensor(top_candidates, dtype=torch.long), 1] = 5.0
    return GraspOutputs(torch.zeros(rois, CANDIDATES_PER_ROI, 5), stability,
                        torch.zeros(rois, CANDIDATES_PER_ROI, 12), anchors)


def test_the_confidence_target_is_whether_the_top_candidate_matches_a_grasp_of_the_rois_own_object():
    # RoI 0: its top-1 lies on its object's grasp. RoI 1: its top-1 lies on RoI 0's object's grasp, its own
    # object's grasp is under another candidate. RoI 2: top-1 on its own grasp but turned 40 degrees away.
    outputs = one_candidate_outputs([3, 3, 7])
    owner_grasps = torch.tensor([[[60.0, 0, 10, 10, 0], [0, 0, 0, 0, 0]],
                                 [[100.0, 0, 10, 10, 0], [0, 0, 0, 0, 0]],
                                 [[140.0, 1, 10, 10, 0.7], [400.0, 0, 10, 10, 0]]])
    valid = torch.tensor([[True, False], [True, False], [True, True]])
    assert top_grasp_right(outputs, owner_grasps, valid).tolist() == [1.0, 0.0, 0.0]
    owner_grasps[2, 0, 4] = 0.3  # 17 degrees: within the 30-degree tolerance
    assert top_grasp_right(outputs, owner_grasps, valid).tolist() == [1.0, 0.0, 1.0]
    assert top_grasp_right(one_candidate_outputs([]), owner_grasps[:0], valid[:0]).shape == (0,)


def test_the_ranking_targets_are_the_candidates_that_match_a_grasp_of_the_rois_own_object():
    outputs = one_candidate_outputs([0, 0])
    # RoI 0: a grasp 30 px long halfway between candidates 3 and 4 (Jaccard 1/3 with each) and one on
    # candidate 3 turned 40 degrees away; RoI 1: a grasp on candidate 3 turned 17 degrees, and padding on
    # candidate 0.
    owner_grasps = torch.tensor([[[70.0, 0, 30, 10, 0], [60.0, 0, 10, 10, 0.7]],
                                 [[60.0, 0, 10, 10, 0.3], [0.0, 0, 10, 10, 0]]])
    valid = torch.tensor([[True, True], [True, False]])
    matching = matching_candidates(outputs, owner_grasps, valid)
    assert matching.shape == (2, CANDIDATES_PER_ROI)
    assert matching[0].nonzero().flatten().tolist() == [3, 4]
    assert matching[1].nonzero().flatten().tolist() == [3]
    # with regressed rectangles: the rule of grasp_match_matrix, candidate by candidate
    generator = torch.Generator().manual_seed(0)
    moved = outputs._replace(regression=0.3 * torch.randn((2, CANDIDATES_PER_ROI, 5), generator=generator))
    expected = [grasp_match_matrix(decode(moved.regression[roi], moved.anchors[roi]).numpy(),
                                   owner_grasps[roi][valid[roi]].numpy()).any(axis=1) for roi in range(2)]
    moved_matching = matching_candidates(moved, owner_grasps, valid)
    assert moved_matching.numpy().tolist() == [row.tolist() for row in expected]
    assert moved_matching.any() and not torch.equal(moved_matching, matching)


def test_the_ranking_term_on_matching_candidates_trains(batch):
    torch.manual_seed(0)
    images, targets, _ = batch
    model = build_model("tog", "resnet18", grasp_ranking_weight=0.5, grasp_ranking_matches=True, **SMALL)
    model.train()
    torch.manual_seed(1)
    losses = model(images, targets)
    assert all(torch.isfinite(value) for value in losses.values())
    losses["grasp_stability"].backward()
    assert float(model.grasp_head.stability.weight.grad.abs().sum()) > 0
    # the same weights and RoI sampling with the term on the positive anchors: only the stability loss differs
    model.options = replace(model.options, grasp_ranking_matches=False)
    torch.manual_seed(1)
    with torch.no_grad():
        on_anchors = model(images, targets)
    assert float(on_anchors["grasp_stability"]) != float(losses["grasp_stability"].detach())
    assert float(on_anchors["grasp_regression"]) == float(losses["grasp_regression"].detach())


def test_rescored_detections_keep_their_class_scores():
    class_scores = torch.tensor([0.9, 0.5])
    detections = [{"boxes": torch.zeros(2, 4), "scores": class_scores.clone()}, {"scores": torch.zeros(0)}]
    out = rescored(detections, (torch.tensor([0.5, 1.0]), torch.zeros(0)))
    assert torch.allclose(out[0]["scores"], torch.tensor([0.45, 0.5]))
    assert torch.equal(out[0]["class_scores"], class_scores) and torch.equal(detections[0]["scores"], class_scores)
    assert out[1]["scores"].shape == (0,)


def test_the_confidence_head_trains_apart_and_multiplies_the_detection_scores(batch):
    torch.manual_seed(0)
    images, targets, _ = batch
    model = build_model("tog", "resnet18", grasp_confidence=True, box_score_threshold=0.0, **SMALL)
    model.train()
    losses = model(images, targets)
    assert torch.isfinite(losses["grasp_confidence"]) and losses["grasp_confidence"] > 0
    losses["grasp_confidence"].backward()
    head = model.grasp_head
    assert float(head.confidence.conv.weight.grad.abs().sum()) > 0
    # its inputs are detached: the loss reaches no other layer
    assert all(parameter.grad is None for name, parameter in model.named_parameters()
               if not name.startswith("grasp_head.confidence"))
    model.eval()
    with torch.no_grad():
        head.confidence.logit.weight.zero_()
        head.confidence.logit.bias.fill_(math.log(3.0))  # P = 0.75
        outputs = model(images)
    assert sum(len(output["scores"]) for output in outputs) > 0
    for output in outputs:
        assert torch.allclose(output["scores"], 0.75 * output["class_scores"])
    with pytest.raises(ValueError, match="grasp_confidence needs RoIs"):
        build_model("fcgn-task", "resnet18", grasp_confidence=True, **SMALL)
    # trained end to end, the confidence loss reaches the grasp trunk and the backbone too
    model = build_model("tog", "resnet18", grasp_confidence=True, grasp_confidence_trains_features=True, **SMALL)
    model.train()
    model(images, targets)["grasp_confidence"].backward()
    assert float(model.grasp_head.blocks[0].conv1.weight.grad.abs().sum()) > 0
    assert model.backbone.body.conv1.weight.grad is not None


def test_stability_per_category_uses_the_pair_of_each_rois_category(batch):
    torch.manual_seed(0)
    head = GraspHead(16, 16, "group", stability_categories=3)
    pooled = torch.randn(2, 16, 7, 7)
    stability = head(pooled, torch.tensor([2, 0]))[1]
    every = head._per_candidate(head.stability(head.blocks(head.entry(pooled))), 6).reshape(2, CANDIDATES_PER_ROI, 3, 2)
    assert torch.equal(stability[0], every[0, :, 2]) and torch.equal(stability[1], every[1, :, 0])
    with pytest.raises(ValueError, match="category"):
        head(pooled)

    images, targets, _ = batch
    model = build_model("tog", "resnet18", grasp_stability_per_category=True, box_score_threshold=0.0, **SMALL)
    model.train()
    model(images, targets)["grasp_stability"].backward()
    # only the pairs of the categories of the objects that trained are trained
    grad = model.grasp_head.stability.weight.grad.reshape(4, len(CATEGORIES), 2, -1).abs().sum(dim=(0, 2, 3))
    trained = torch.cat([target["labels"] for target in targets]).unique() - 1
    assert (grad[trained] > 0).all() and (grad.count_nonzero() == len(trained))
    model.eval()
    with torch.no_grad():
        model.grasp_head.stability.bias.zero_()
        model.grasp_head.stability.weight.zero_()
        model.grasp_head.stability.bias.reshape(4, len(CATEGORIES), 2)[:, :, 1] = torch.arange(len(CATEGORIES)) - 4.5
        outputs = model(images)
    assert sum(len(output["labels"]) for output in outputs) > 0
    for output in outputs:  # P(stable) of a detection follows its label's bias
        expected = torch.sigmoid(output["labels"].float() - 1 - 4.5)[:, None].expand_as(output["grasp_stability"])
        torch.testing.assert_close(output["grasp_stability"], expected)
    with pytest.raises(ValueError, match="roi"):
        build_model("fcgn-task", "resnet18", grasp_stability_per_category=True, **SMALL)


def test_the_regression_radius_trains_the_regression_of_the_candidates_near_a_grasp(batch):
    images, targets, _ = batch
    seen = {}
    for radius in (0.0, 1.0):
        torch.manual_seed(0)
        model = build_model("tog", "resnet18", grasp_regression_radius=radius, **SMALL)
        model.train()
        original = model._grasp_losses

        def keep(outputs, grasp_targets, radius=radius, original=original):
            seen[radius] = grasp_targets
            return original(outputs, grasp_targets)

        model._grasp_losses = keep
        losses = model(images, targets)
        assert math.isfinite(float(losses["grasp_regression"].detach()))
    assert seen[0.0].regressed is None
    wide = seen[1.0]
    # the same RoIs and positives; more candidates regress, the positives among them
    assert torch.equal(wide.positive, seen[0.0].positive)
    assert bool((wide.positive <= wide.regressed).all()) and int(wide.regressed.sum()) > int(wide.positive.sum())
    with pytest.raises(ValueError, match="roi"):
        build_model("fcgn-task", "resnet18", grasp_regression_radius=1.0, **SMALL)


def test_the_fine_map_reaches_the_grasp_head_only(batch):
    images, targets, _ = batch
    model = build_model("tog", "resnet18", grasp_fine_map=True, fpn_min_stride=8, fpn_max_stride=16,
                        rpn_anchor_sizes=(16, 32, 64), box_score_threshold=0.0, **SMALL)
    features = model.backbone(torch.stack(images))
    # C2 at stride 4 beside the FPN maps; the RPN is given the FPN maps alone
    assert features[FINE_MAP].shape[1:] == (C2_CHANNELS["resnet18"], 96 // 4, 96 // 4)
    assert list(pyramid(features)) == ["0", "1", "pool"]
    model.train()
    model(images, targets)["grasp_stability"].backward()
    # the grasp loss trains the projection of C2 and reaches C2 through it
    assert float(model.grasp_head.fine_entry[0].weight.grad.abs().sum()) > 0
    assert float(model.backbone.body.layer1[0].conv1.weight.grad.abs().sum()) > 0
    model.zero_grad()
    model(images, targets)["rcnn_class"].backward()
    assert model.grasp_head.fine_entry[0].weight.grad is None or not model.grasp_head.fine_entry[0].weight.grad.any()
    # changing C2's projection changes the candidates and leaves the boxes as they were
    model.eval()
    with torch.no_grad():
        before = model(images)
        model.grasp_head.fine_entry[1].bias.add_(1.0)
        after = model(images)
    assert sum(len(output["boxes"]) for output in before) > 0
    for first, second in zip(before, after, strict=True):
        assert torch.equal(first["boxes"], second["boxes"])
        assert not torch.equal(first["grasp_stability"], second["grasp_stability"])
    head = GraspHead(16, 16, "group", fine_channels=8)
    with pytest.raises(ValueError, match="C2"):
        head(torch.randn(2, 16, 7, 7))
    with pytest.raises(ValueError, match="fpn_min_stride 8"):
        build_model("tog", "resnet18", grasp_fine_map=True, **SMALL)
    with pytest.raises(ValueError, match="roi"):
        build_model("fcgn-task", "resnet18", grasp_fine_map=True, fpn_min_stride=8, **SMALL)


def test_context_cells_show_the_grasp_head_what_lies_around_its_roi(batch):
    images, targets, _ = batch
    # one cell more on each side: 9 cells of the RoI's own cell size over the box widened about its centre
    torch.testing.assert_close(widened_boxes(torch.tensor([[10.0, 20.0, 38.0, 34.0]]), 9 / 7),
                               torch.tensor([[6.0, 18.0, 42.0, 36.0]]))
    torch.manual_seed(0)
    model = build_model("tog", "resnet18", grasp_context_cells=1, **SMALL)
    model.train()
    assert all(math.isfinite(float(value.detach())) for value in model(images, targets).values())
    plain = build_model("tog", "resnet18", **SMALL)
    plain.load_state_dict(model.state_dict())  # the context adds no weights
    model.eval()
    plain.eval()
    image_sizes = [tuple(image.shape[-2:]) for image in images]
    rois = [torch.tensor([[16.0, 16.0, 72.0, 72.0]]), torch.tensor([[30.0, 20.0, 60.0, 80.0]])]
    with torch.no_grad():
        features = model.backbone(torch.stack(images))
        # FPN level "0" (stride 4) pixel (row 10, column 20) is sampled by the box widened to 8-80 px
        # (columns 2-20), not by the box itself (16-72 px: columns 4-18)
        edited = {name: feature.clone() for name, feature in features.items()}
        edited["0"][0, :, 10, 20] += 5.0
        for detector, sees_context in ((model, True), (plain, False)):
            outputs = detector.grasp_outputs(features, rois, image_sizes)
            # the candidates stay the RoI's 7 x 7 x 4, on the RoI's own anchors
            assert outputs.stability.shape == (2, CANDIDATES_PER_ROI, 2)
            anchors = roi_anchors(torch.cat(rois), detector.options.grasp_anchor_size)
            torch.testing.assert_close(outputs.anchors, anchors)
            changed = detector.grasp_outputs(edited, rois, image_sizes)
            assert torch.equal(changed.stability[0], outputs.stability[0]) != sees_context
            assert torch.equal(changed.stability[1], outputs.stability[1])  # the second image is not edited
    with pytest.raises(ValueError, match="0 or more"):
        build_model("tog", "resnet18", grasp_context_cells=-1, **SMALL)
    with pytest.raises(ValueError, match="roi"):
        build_model("fcgn-task", "resnet18", grasp_context_cells=1, **SMALL)


def test_a_finer_grasp_grid_gives_each_roi_more_candidates(batch):
    images, targets, _ = batch
    seen = {}
    for grid in (7, 14):
        torch.manual_seed(0)
        model = build_model("tog-crfs", "resnet18", grasp_grid=grid, box_score_threshold=0.0, **SMALL)
        model.train()
        original = model._grasp_losses

        def keep(outputs, grasp_targets, grid=grid, original=original):
            seen[grid] = (outputs, grasp_targets)
            return original(outputs, grasp_targets)

        model._grasp_losses = keep
        losses = model(images, targets)
        assert all(math.isfinite(float(value.detach())) for value in losses.values())
        losses["grasp_stability"].backward()
        assert float(model.grasp_head.stability.weight.grad.abs().sum()) > 0
        model.eval()
        with torch.no_grad():
            outputs = model(images)
        assert sum(len(output["boxes"]) for output in outputs) > 0
        for output in outputs:
            assert output["grasp_stability"].shape[1] == grid * grid * 4
            assert output["grasps"].shape[1:] == (grid * grid * 4, 5)
    coarse, fine = seen[7], seen[14]
    assert fine[0].anchors.shape[1] == 14 * 14 * 4 and fine[0].stability.shape[1] == 14 * 14 * 4
    # the same RoIs (one seed): the cells of the finer grid are half as wide, and no fewer candidates are
    # positive (grasps that shared a 7 x 7 cell may fall into different ones)
    def step(anchors):  # from the first cell of each RoI to the next one in its row
        return anchors[:, 4, 0] - anchors[:, 0, 0]

    torch.testing.assert_close(2 * step(fine[0].anchors), step(coarse[0].anchors))
    assert int(fine[1].positive.sum()) >= int(coarse[1].positive.sum()) > 0
    with pytest.raises(ValueError, match="grasp_grid"):
        build_model("fcgn-task", "resnet18", grasp_grid=14, **SMALL)
    with pytest.raises(ValueError, match="grasp_grid"):
        build_model("tog", "resnet18", grasp_grid=0, **SMALL)
