"""The TOG and TOG-CRFs detectors (paper, Section IV-B/C, Fig. 3).

Depth image -> ResNet (1-channel input, trainable GroupNorm or BatchNorm, no
pretrained weights) with a feature pyramid -> RPN -> RoIAlign 7 x 7 -> two
branches on the pooled features of each RoI:

- the RCNN head (torchvision's two-layer MLP head and predictor): box
  refinement and the 10 categories plus background;
- the grasp detector: 3 ResBlocks, then three 3 x 3 convolutions with 4 x 5
  regression, 4 x 2 stability and 4 x 12 task channels: 196 candidates per
  RoI (``togcrf.anchors``). For the CRF variants the task logits go through
  :class:`togcrf.crf.MeanFieldCrf`.

Our choices, documented against the paper: a feature pyramid (torchvision's
``resnet_fpn_backbone``) in place of the single C4 map, because the objects
span a wide range of sizes and it is torchvision's supported path;
GroupNorm by default, because batch statistics of 2-4 depth images are
noisy and GroupNorm behaves the same in training and evaluation (REFERENCE
section 8: the frozen batch norm default diverges from scratch). During
training the grasp branch runs on up to ``grasp_rois_per_image`` of the
RCNN's sampled foreground RoIs (ground-truth boxes plus proposals with IoU >=
0.5), each taking its grasp targets from the object it is matched to.
Per-class box NMS at 0.5, not ROI-GD's 0.3, so that overlapping objects of
one category in a pile can both be detected (``ModelOptions``).

The model API is the contract in ``docs/togcrf.md``: train mode returns a
dict of scalar losses, eval mode a list of per-image detections with grasp
candidates.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, fields

import torch
from torch import nn
from torch.nn import functional
from torchvision.models import resnet
from torchvision.models.detection.anchor_utils import AnchorGenerator
from torchvision.models.detection.backbone_utils import BackboneWithFPN
from torchvision.models.detection.faster_rcnn import FastRCNNPredictor, TwoMLPHead
from torchvision.models.detection.image_list import ImageList
from torchvision.models.detection.roi_heads import RoIHeads, fastrcnn_loss
from torchvision.models.detection.rpn import RegionProposalNetwork, RPNHead
from torchvision.ops import MultiScaleRoIAlign
from torchvision.ops.feature_pyramid_network import LastLevelMaxPool
from torchvision.ops.poolers import initLevelMapper

from osgd.contract.taxonomy import CATEGORIES, TASKS
from togcrf.anchors import ANCHOR_ANGLES, DEFAULT_ANCHOR_SIZE, GRID, decode, match, near_ground_truth, roi_anchors
from togcrf.crf import DEFAULT_BANDWIDTH, DEFAULT_ITERATIONS, MeanFieldCrf
from togcrf.losses import DEFAULT_NEGATIVE_RATIO, grasp_losses, top1_task_hits

logger = logging.getLogger(__name__)

#: Model names, in the order of Table II.
MODEL_NAMES = ("fcgn-task", "tog", "tog-crfs-omega", "tog-crfs-mu", "tog-crfs")

#: Which CRF terms each TOG variant uses: (omega, mu); None = no CRF.
CRF_TERMS: dict[str, tuple[bool, bool] | None] = {
    "tog": None,
    "tog-crfs-omega": (True, False),
    "tog-crfs-mu": (False, True),
    "tog-crfs": (True, True),
}

#: Supported ResNet depths (the paper uses resnet101).
BACKBONES = ("resnet18", "resnet34", "resnet50", "resnet101")

#: Strides of the ResNet stages C2-C5, pixels of the network input.
RESNET_STRIDES = (4, 8, 16, 32)

#: Images are padded to a multiple of this (the coarsest FPN level, stride 32).
SIZE_DIVISIBLE = 32


@dataclass(frozen=True)
class ModelOptions:
    """Options of the TOG models (every one has a default; all go into checkpoints).

    Attributes
    ----------
    norm : {"group", "batch"}
        Normalisation layers of the backbone and grasp head.
    fpn_channels : int
        Channels of every FPN map (torchvision: 256).
    fpn_min_stride : {4, 8}
        Finest FPN level: 4 pools RoIs from ResNet C2-C5 (torchvision's
        default), 8 from C3-C5 only (about a third less work at 192 px; the
        tools are at least 10 px wide there).
    fpn_norm : bool
        Normalise the FPN's lateral and output convolutions with ``norm``.
        torchvision's FPN has none; from scratch its maps grow large and
        uncentred and the clip then fires on every step (issue #15 review).
    grasp_trunk_norm : bool
        A last normalisation on the grasp ResBlocks' output. Their identity
        path is never normalised, so after 3 blocks the features are all
        positive and large (mean 1.9) without it.
    rpn_anchor_sizes : tuple of int
        RPN anchor side per FPN level (one per level, the "pool" level
        included), pixels of the network input.
    rpn_pre_nms_train, rpn_post_nms_train, rpn_pre_nms_test, rpn_post_nms_test : int
        Proposals kept per level before / per image after the RPN NMS.
    rpn_nms_threshold : float
        RPN NMS IoU (REFERENCE section 3: 0.7).
    box_batch_per_image : int
        RoIs sampled per image for the RCNN loss.
    box_head_size : int
        Width of the RCNN's two fully connected layers (torchvision: 1024).
    box_score_threshold, box_nms_threshold : float
        Detection score floor and per-class NMS IoU. Our choice: 0.5
        (torchvision's default), not ROI-GD's 0.3 (REFERENCE section 3). In
        piles, objects of one category overlap: in the default dataset 10 %
        of the objects have a same-category neighbour whose box overlaps
        theirs at IoU > 0.3, and at 0.3 only one of each such pair can be
        detected; at IoU > 0.5 it is 2.5 % (``docs/togcrf.md``).
    detections_per_image : int
    grasp_anchor_size : float
        Side of the square grasp anchors, pixels (``togcrf.anchors``).
    grasp_positive_radius : float
        Cells around a ground-truth grasp's own cell whose anchors are
        positive for it (0: the paper's own cell; ``togcrf.anchors``).
    grasp_ignore_radius : float or None
        Anchors within this many cells beyond their own of a ground-truth
        grasp (angle within 45 degrees) are never hard negatives (None:
        every anchor that is not positive may be; ``togcrf.anchors``).
    grasp_rois_per_image : int
        Foreground RoIs per image that train the grasp branch.
    grasp_channels : int
        Channels of the grasp ResBlocks.
    crf_iterations : int
    crf_bandwidth : float
        Gaussian kernel bandwidth, RoI units.
    negative_ratio : int
        Hard negatives per positive candidate.
    weight_rpn, weight_rcnn, weight_stability, weight_regression, weight_task : float
        Loss weights (RPN: objectness and box; RCNN: class and box).
    """

    norm: str = "group"
    fpn_channels: int = 256
    fpn_min_stride: int = 4
    fpn_norm: bool = True
    grasp_trunk_norm: bool = True
    rpn_anchor_sizes: tuple[int, ...] = (16, 32, 64, 128, 256)
    rpn_pre_nms_train: int = 1000
    rpn_post_nms_train: int = 500
    rpn_pre_nms_test: int = 500
    rpn_post_nms_test: int = 300
    rpn_nms_threshold: float = 0.7
    box_batch_per_image: int = 256
    box_head_size: int = 1024
    box_score_threshold: float = 0.05
    box_nms_threshold: float = 0.5
    detections_per_image: int = 50
    grasp_anchor_size: float = DEFAULT_ANCHOR_SIZE
    grasp_positive_radius: float = 0.0
    grasp_ignore_radius: float | None = None
    grasp_rois_per_image: int = 16
    grasp_channels: int = 256
    crf_iterations: int = DEFAULT_ITERATIONS
    crf_bandwidth: float = DEFAULT_BANDWIDTH
    negative_ratio: int = DEFAULT_NEGATIVE_RATIO
    weight_rpn: float = 1.0
    weight_rcnn: float = 1.0
    weight_stability: float = 1.0
    weight_regression: float = 1.0
    weight_task: float = 1.0

    @staticmethod
    def from_dict(options: dict) -> ModelOptions:
        """Options from keyword values; unknown names raise a TypeError that lists the known ones."""
        known = {field.name for field in fields(ModelOptions)}
        unknown = sorted(set(options) - known)
        if unknown:
            raise TypeError(f"unknown model options {unknown}; known: {sorted(known)}")
        values = dict(options)
        if "rpn_anchor_sizes" in values:
            values["rpn_anchor_sizes"] = tuple(int(size) for size in values["rpn_anchor_sizes"])
        return ModelOptions(**values)


def norm_layer(kind: str) -> type[nn.Module] | callable:
    """A constructor ``channels -> normalisation module`` for ``kind`` in {"group", "batch"}."""
    if kind == "batch":
        return nn.BatchNorm2d
    if kind == "group":
        return lambda channels: nn.GroupNorm(min(32, channels), channels)
    raise ValueError(f"unknown normalisation {kind!r}; expected 'group' or 'batch'")


def build_backbone(name: str, norm: str = "group", channels: int = 256, min_stride: int = 4,
                   fpn_norm: bool = True) -> BackboneWithFPN:
    """A ResNet + FPN backbone for 1-channel depth input, randomly initialised, fully trainable.

    Parameters
    ----------
    name : str
        One of ``BACKBONES``.
    norm : {"group", "batch"}
        Normalisation of the ResNet (and of the FPN with ``fpn_norm``).
    channels : int
        FPN channels.
    min_stride : {4, 8}
        Stride of the finest FPN map.
    fpn_norm : bool

    Returns
    -------
    BackboneWithFPN
        Maps "0", "1", ... at strides ``min_stride`` ... 32 and "pool" at 64.
    """
    if name not in BACKBONES:
        raise ValueError(f"unknown backbone {name!r}; expected one of {BACKBONES}")
    if min_stride not in RESNET_STRIDES[:2]:
        raise ValueError(f"fpn_min_stride {min_stride}: expected 4 or 8")
    body = resnet.__dict__[name](weights=None, norm_layer=norm_layer(norm))
    body.conv1 = nn.Conv2d(1, body.conv1.out_channels, kernel_size=7, stride=2, padding=3, bias=False)
    nn.init.kaiming_normal_(body.conv1.weight, mode="fan_out", nonlinearity="relu")
    stages = [stage for stage, stride in enumerate(RESNET_STRIDES, start=1) if stride >= min_stride]
    stage_channels = body.inplanes // 8  # C2's width: 64 (basic blocks) or 256 (bottlenecks)
    return BackboneWithFPN(
        body, {f"layer{stage}": str(index) for index, stage in enumerate(stages)},
        [stage_channels * 2 ** (stage - 1) for stage in stages], channels,
        extra_blocks=LastLevelMaxPool(), norm_layer=norm_layer(norm) if fpn_norm else None)


def fpn_strides(options: ModelOptions) -> tuple[int, ...]:
    """Strides of the FPN maps that RoIs are pooled from ("0", "1", ...; "pool" excluded)."""
    return tuple(stride for stride in RESNET_STRIDES if stride >= options.fpn_min_stride)


class ResBlock(nn.Module):
    """A basic residual block at constant resolution: conv-norm-relu-conv-norm + identity, relu."""

    def __init__(self, channels: int, norm: str) -> None:
        super().__init__()
        make_norm = norm_layer(norm)
        self.conv1 = nn.Conv2d(channels, channels, 3, padding=1, bias=False)
        self.norm1 = make_norm(channels)
        self.conv2 = nn.Conv2d(channels, channels, 3, padding=1, bias=False)
        self.norm2 = make_norm(channels)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        out = functional.relu(self.norm1(self.conv1(features)))
        return functional.relu(features + self.norm2(self.conv2(out)))


class GraspHead(nn.Module):
    """3 ResBlocks and the regression, stability and task convolutions (paper, Section IV-B).

    Input (R, C, 7, 7) pooled RoI features; outputs per candidate, in the
    candidate order of ``togcrf.anchors``: regression (R, 196, 5), stability
    logits (R, 196, 2), task logits (R, 196, 12).
    """

    def __init__(self, in_channels: int, channels: int, norm: str, task_count: int = len(TASKS),
                 blocks: int = 3, output_norm: bool = True) -> None:
        super().__init__()
        self.anchors = len(ANCHOR_ANGLES)
        self.task_count = task_count
        self.entry = nn.Identity() if in_channels == channels else nn.Conv2d(in_channels, channels, 1)
        trunk = [ResBlock(channels, norm) for _ in range(blocks)]
        self.blocks = nn.Sequential(*trunk, *([norm_layer(norm)(channels)] if output_norm else []))
        self.regression = nn.Conv2d(channels, self.anchors * 5, 3, padding=1)
        self.stability = nn.Conv2d(channels, self.anchors * 2, 3, padding=1)
        self.task = nn.Conv2d(channels, self.anchors * task_count, 3, padding=1)
        for layer in (self.regression, self.stability, self.task):
            nn.init.normal_(layer.weight, std=0.01)
            nn.init.zeros_(layer.bias)

    def _per_candidate(self, output: torch.Tensor, width: int) -> torch.Tensor:
        # channel a * width + d of cell (i, j) -> candidate (i * 7 + j) * 4 + a, component d
        rois, _, rows, columns = output.shape
        return output.permute(0, 2, 3, 1).reshape(rois, rows * columns * self.anchors, width)

    def forward(self, pooled: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        features = self.blocks(self.entry(pooled))
        return (
            self._per_candidate(self.regression(features), 5),
            self._per_candidate(self.stability(features), 2),
            self._per_candidate(self.task(features), self.task_count),
        )


def batch_images(images: list[torch.Tensor]) -> ImageList:
    """Pad (1, H, W) images into one (B, 1, H', W') tensor, H' and W' multiples of 32 (top-left aligned)."""
    if not images:
        raise ValueError("the model needs at least one image")
    for index, image in enumerate(images):
        if image.dim() != 3 or image.shape[0] != 1:
            raise ValueError(f"image {index} has shape {tuple(image.shape)}; expected (1, H, W) depth")
    height = max(image.shape[1] for image in images)
    width = max(image.shape[2] for image in images)
    height = -(-height // SIZE_DIVISIBLE) * SIZE_DIVISIBLE
    width = -(-width // SIZE_DIVISIBLE) * SIZE_DIVISIBLE
    batch = images[0].new_zeros((len(images), 1, height, width))
    for index, image in enumerate(images):
        batch[index, :, : image.shape[1], : image.shape[2]] = image
    return ImageList(batch, [(int(image.shape[1]), int(image.shape[2])) for image in images])


def padded_object_grasps(targets: list[dict[str, torch.Tensor]]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor,
                                                                           torch.Tensor]:
    """The ground-truth grasps of every object of the batch, padded to a common count.

    Returns
    -------
    grasps : (O, G, 5) float
        O = objects of all images (image by image), G = most grasps of one object.
    valid : (O, G) bool
    tasks : (O, G) int64
    first_object : (B,) int64
        Row of each image's first object.
    """
    device = targets[0]["boxes"].device
    counts_per_image = [len(target["boxes"]) for target in targets]
    first_object = torch.tensor([0, *counts_per_image[:-1]], device=device).cumsum(0)
    total = sum(counts_per_image)
    owners = torch.cat([target["grasp_objects"] + first for target, first in zip(targets, first_object, strict=True)])
    grasps = torch.cat([target["grasps"] for target in targets])
    tasks = torch.cat([target["grasp_tasks"] for target in targets])
    per_object = torch.bincount(owners, minlength=total) if len(owners) else torch.zeros(total, dtype=torch.int64,
                                                                                         device=device)
    most = max(int(per_object.max()) if total else 0, 1)
    order = torch.argsort(owners, stable=True)
    owners, grasps, tasks = owners[order], grasps[order], tasks[order]
    starts = torch.cumsum(per_object, 0) - per_object
    slot = torch.arange(len(owners), device=device) - starts[owners]
    padded = grasps.new_zeros((total, most, 5))
    valid = torch.zeros((total, most), dtype=torch.bool, device=device)
    padded_tasks = torch.zeros((total, most), dtype=torch.int64, device=device)
    padded[owners, slot] = grasps
    valid[owners, slot] = True
    padded_tasks[owners, slot] = tasks
    return padded, valid, padded_tasks, first_object


class TogDetector(nn.Module):
    """TOG / TOG-CRFs: detector, grasp head and (optionally) the task CRF.

    Parameters
    ----------
    backbone : str
        One of ``BACKBONES``.
    crf_terms : (bool, bool) or None
        ``(use_omega, use_mu)`` of the CRF; None for TOG (no CRF).
    options : ModelOptions
    """

    def __init__(self, backbone: str = "resnet18", crf_terms: tuple[bool, bool] | None = None,
                 options: ModelOptions | None = None) -> None:
        super().__init__()
        self.options = options = options or ModelOptions()
        self.backbone = build_backbone(backbone, options.norm, options.fpn_channels, options.fpn_min_stride,
                                       options.fpn_norm)
        strides = fpn_strides(options)
        levels = len(strides) + 1  # the "pool" level of the RPN
        if len(options.rpn_anchor_sizes) != levels:
            raise ValueError(f"rpn_anchor_sizes {options.rpn_anchor_sizes}: expected {levels} sizes, one per FPN "
                             f"level (strides {(*strides, 2 * strides[-1])})")
        anchor_generator = AnchorGenerator(tuple((size,) for size in options.rpn_anchor_sizes),
                                           ((0.5, 1.0, 2.0),) * levels)
        self.rpn = RegionProposalNetwork(
            anchor_generator, RPNHead(options.fpn_channels, 3),
            fg_iou_thresh=0.7, bg_iou_thresh=0.3, batch_size_per_image=256, positive_fraction=0.5,
            pre_nms_top_n={"training": options.rpn_pre_nms_train, "testing": options.rpn_pre_nms_test},
            post_nms_top_n={"training": options.rpn_post_nms_train, "testing": options.rpn_post_nms_test},
            nms_thresh=options.rpn_nms_threshold,
        )
        roi_pool = MultiScaleRoIAlign([str(level) for level in range(len(strides))], output_size=GRID,
                                      sampling_ratio=2)
        # torchvision infers the level scales from the first batch's image sizes and caches them; with
        # small images padded to a multiple of 32 that guess is off by a level, and it would depend on
        # which batch came first: the FPN strides are known, so fix the scales.
        roi_pool.scales = [1.0 / stride for stride in strides]
        roi_pool.map_levels = initLevelMapper(int(math.log2(strides[0])), int(math.log2(strides[-1])))
        self.roi_heads = RoIHeads(
            roi_pool, TwoMLPHead(options.fpn_channels * GRID * GRID, options.box_head_size),
            FastRCNNPredictor(options.box_head_size, len(CATEGORIES) + 1),
            fg_iou_thresh=0.5, bg_iou_thresh=0.5, batch_size_per_image=options.box_batch_per_image,
            positive_fraction=0.25, bbox_reg_weights=None, score_thresh=options.box_score_threshold,
            nms_thresh=options.box_nms_threshold, detections_per_img=options.detections_per_image,
        )
        self.grasp_head = GraspHead(options.fpn_channels, options.grasp_channels, options.norm,
                                    output_norm=options.grasp_trunk_norm)
        self.crf = None if crf_terms is None else MeanFieldCrf(
            len(TASKS), use_omega=crf_terms[0], use_mu=crf_terms[1],
            iterations=options.crf_iterations, bandwidth=options.crf_bandwidth,
        )
        #: Counts of the last training step for on-the-fly metrics: {"acc_t_hits", "acc_t_rois"}.
        self.last_training_stats: dict[str, int] = {}

    def task_log_probs(self, task_logits: torch.Tensor) -> torch.Tensor:
        """``log P(task | stable)`` per candidate: CRF marginals, or log-softmax without CRF (float32)."""
        with torch.autocast(device_type=task_logits.device.type, enabled=False):
            logits = task_logits.float()
            if self.crf is None:
                return torch.log_softmax(logits, dim=-1)
            return self.crf(logits)

    def grasp_outputs(self, features: dict[str, torch.Tensor], rois: list[torch.Tensor],
                      image_sizes: list[tuple[int, int]]) -> tuple[torch.Tensor, ...]:
        """Grasp branch on RoIs (a list of (n_b, 4) boxes per image).

        Returns
        -------
        regression (R, 196, 5), stability_logits (R, 196, 2), task_log_probs (R, 196, 12), anchors (R, 196, 5)
        """
        pooled = self.roi_heads.box_roi_pool(features, rois, image_sizes)
        regression, stability, task_logits = self.grasp_head(pooled)
        all_rois = torch.cat(rois) if rois else pooled.new_zeros((0, 4))
        anchors = roi_anchors(all_rois.float(), self.options.grasp_anchor_size)
        return regression, stability, self.task_log_probs(task_logits), anchors

    def forward(self, images: list[torch.Tensor], targets: list[dict[str, torch.Tensor]] | None = None):
        """Losses (train mode, with targets) or detections (eval mode); see the module docstring."""
        image_list = batch_images(images)
        features = self.backbone(image_list.tensors)
        if self.training:
            if targets is None:
                raise ValueError("the model is in train mode: pass targets, or call model.eval()")
            return self._training_losses(image_list, features, targets)
        proposals, _ = self.rpn(image_list, features)
        detections, _ = self.roi_heads(features, proposals, image_list.image_sizes)
        return self._detect_grasps(features, detections, image_list.image_sizes)

    def _training_losses(self, image_list: ImageList, features: dict[str, torch.Tensor],
                         targets: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
        options = self.options
        proposals, rpn_losses = self.rpn(image_list, features, targets)
        heads = self.roi_heads
        proposals, matched, labels, box_targets = heads.select_training_samples(proposals, targets)
        box_features = heads.box_head(heads.box_roi_pool(features, proposals, image_list.image_sizes))
        class_logits, box_regression = heads.box_predictor(box_features)
        class_loss, box_loss = fastrcnn_loss(class_logits, box_regression, labels, box_targets)

        # the grasp branch: foreground RoIs (GT boxes and proposals with IoU >= 0.5), capped per image
        grasps, valid, tasks, first_object = padded_object_grasps(targets)
        grasp_rois, grasp_owner = [], []
        for image_index, (image_proposals, image_labels, image_matched) in enumerate(
                zip(proposals, labels, matched, strict=True)):
            foreground = torch.nonzero(image_labels > 0).flatten()
            if len(foreground) > options.grasp_rois_per_image:
                keep = torch.randperm(len(foreground), device=foreground.device)[: options.grasp_rois_per_image]
                foreground = foreground[keep]
            grasp_rois.append(image_proposals[foreground].detach())
            grasp_owner.append(image_matched[foreground] + first_object[image_index])
        owners = torch.cat(grasp_owner)
        regression, stability, task_log_probs, anchors = self.grasp_outputs(
            features, grasp_rois, image_list.image_sizes)
        roi_boxes, owner_grasps = torch.cat(grasp_rois).float(), grasps[owners].float()
        positive, regression_targets, task_targets = match(
            anchors, roi_boxes, owner_grasps, valid[owners], tasks[owners], len(TASKS),
            positive_radius=options.grasp_positive_radius)
        ignored = None if options.grasp_ignore_radius is None else near_ground_truth(
            anchors, roi_boxes, owner_grasps, valid[owners], options.grasp_ignore_radius)
        grasp = grasp_losses(stability, regression, task_log_probs, positive, regression_targets, task_targets,
                             options.negative_ratio, ignored)
        hits, rois = top1_task_hits(stability, task_log_probs, positive, task_targets)
        self.last_training_stats = {"acc_t_hits": hits, "acc_t_rois": rois,
                                    "positive_candidates": int(positive.sum())}
        return {
            "rpn_objectness": options.weight_rpn * rpn_losses["loss_objectness"],
            "rpn_box": options.weight_rpn * rpn_losses["loss_rpn_box_reg"],
            "rcnn_class": options.weight_rcnn * class_loss,
            "rcnn_box": options.weight_rcnn * box_loss,
            "grasp_stability": options.weight_stability * grasp["grasp_stability"],
            "grasp_regression": options.weight_regression * grasp["grasp_regression"],
            "grasp_task": options.weight_task * grasp["grasp_task"],
        }

    def _detect_grasps(self, features: dict[str, torch.Tensor], detections: list[dict[str, torch.Tensor]],
                       image_sizes: list[tuple[int, int]]) -> list[dict[str, torch.Tensor]]:
        boxes = [detection["boxes"] for detection in detections]
        regression, stability, task_log_probs, anchors = self.grasp_outputs(features, boxes, image_sizes)
        rectangles = decode(regression.float(), anchors)
        stable = stability.float().softmax(dim=-1)[..., 1]
        task_probs = task_log_probs.exp()
        results, start = [], 0
        for detection in detections:
            count = len(detection["boxes"])
            end = start + count
            results.append({
                "boxes": detection["boxes"].float(),
                "labels": detection["labels"],
                "scores": detection["scores"].float(),
                "grasps": rectangles[start:end],
                "grasp_stability": stable[start:end],
                "grasp_task_probs": task_probs[start:end],
            })
            start = end
        return results


def build_model(name: str, backbone: str = "resnet18", **options) -> nn.Module:
    """A model of Table II by name.

    Parameters
    ----------
    name : str
        One of ``MODEL_NAMES``.
    backbone : str
        One of ``BACKBONES``.
    **options
        :class:`ModelOptions` fields (for "fcgn-task": that model's options).

    Raises
    ------
    ValueError
        Unknown name or backbone.
    TypeError
        Unknown option.
    NotImplementedError
        "fcgn-task" before ``togcrf.fcgn`` exists.
    """
    if name == "fcgn-task":
        try:
            from togcrf.fcgn import FcgnTask  # noqa: PLC0415 - the evaluation engineer's module, optional
        except ModuleNotFoundError as error:
            if error.name != "togcrf.fcgn":
                raise
            raise NotImplementedError("model 'fcgn-task' needs togcrf/fcgn.py, which is not written yet") from error
        return FcgnTask(backbone=backbone, **options)
    if name not in CRF_TERMS:
        raise ValueError(f"unknown model {name!r}; expected one of {MODEL_NAMES}")
    return TogDetector(backbone, CRF_TERMS[name], ModelOptions.from_dict(options))


def model_options_dict(options: ModelOptions) -> dict:
    """Options as plain JSON-able values."""
    values = asdict(options)
    values["rpn_anchor_sizes"] = list(values["rpn_anchor_sizes"])
    return values
