"""The models of Table II: TOG, TOG-CRFs (paper, Section IV-B/C, Fig. 3) and FCGN + Task.

Every model is one :class:`GraspDetector`: depth image -> ResNet (1-channel
input, trainable GroupNorm or BatchNorm, no pretrained weights) with a
feature pyramid -> RPN -> RoIAlign 7 x 7 -> the RCNN box branch
(torchvision's two-layer MLP head and predictor: box refinement and the 10
categories plus background), and one grasp branch, as torchvision's
``RoIHeads`` holds its box, mask and keypoint branches:

- "roi" (TOG and TOG-CRFs): on the pooled features of each RoI, 3
  ResBlocks, then three 3 x 3 convolutions with 4 x 5 regression, 4 x 2
  stability (4 x 2 per category with ``grasp_stability_per_category``) and
  4 x 12 task channels: 196 candidates per RoI
  (``togcrf.anchors``); with ``grasp_object_map`` a fourth, one channel per
  cell: the cell lies on the RoI's own object; with ``grasp_confidence`` a
  small head that predicts whether the RoI's top-1 candidate is a right grasp
  (:class:`TopGraspConfidence`), whose probability multiplies the detection
  score; with ``grasp_fine_map`` it pools ResNet C2 (stride 4) of each RoI
  as well;
- "image" (FCGN + Task, ``togcrf.fcgn``): the same convolutions on one FPN
  map of the whole image, 4 candidates per cell, given at inference to the
  detected boxes that contain them.

For the CRF variants the task logits go through
:class:`togcrf.crf.MeanFieldCrf`. ``MODELS`` is the registry of the model
names (Table II's rows, in order); :func:`build_model` builds one by name.

Our choices, documented against the paper: a feature pyramid (torchvision's
``resnet_fpn_backbone``) in place of the single C4 map, because the objects
span a wide range of sizes and it is torchvision's supported path;
GroupNorm by default, because batch statistics of 2-4 depth images are
noisy and GroupNorm behaves the same in training and evaluation (REFERENCE
section 8: the frozen batch norm default diverges from scratch). During
training the "roi" grasp branch runs on up to ``grasp_rois_per_image`` of the
RCNN's sampled foreground RoIs (ground-truth boxes plus proposals with IoU >=
0.5), each taking its grasp targets from the object it is matched to.
Per-class box NMS at 0.5, not ROI-GD's 0.3, so that overlapping objects of
one category in a pile can both be detected (``ModelOptions``).

The model API is the contract in ``docs/togcrf.md``: train mode returns a
dict of scalar losses (``togcrf.losses.LOSS_KEYS``), eval mode a list of
per-image detections with grasp candidates.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, fields
from typing import NamedTuple

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
from torchvision.ops import roi_align
from torchvision.ops.feature_pyramid_network import LastLevelMaxPool
from torchvision.ops.poolers import initLevelMapper

from osgd.contract.taxonomy import CATEGORIES, TASKS
from togcrf.anchors import (
    ANCHOR_ANGLES,
    DEFAULT_ANCHOR_SIZE,
    GRID,
    decode,
    match,
    near_ground_truth,
    regression_targets_within,
    roi_anchors,
)
from togcrf.crf import DEFAULT_BANDWIDTH, DEFAULT_ITERATIONS, MeanFieldCrf
from togcrf.fcgn import box_candidates, image_anchors, image_grasp_targets
from togcrf.losses import DEFAULT_NEGATIVE_RATIO, LOSS_KEYS, binary_loss, grasp_losses, top1_task_hits
from togcrf.metrics import GRASP_ANGLE_TOLERANCE, GRASP_JACCARD_THRESHOLD, paired_grasp_match
from togcrf.roi_align import FastMultiScaleRoIAlign, convert_boxes_to_roi_format, roi_align_fast_backward

logger = logging.getLogger(__name__)

#: Grasp branches of :class:`GraspDetector`: "roi" (TOG: candidates in each RoI of the RCNN) and "image"
#: (FCGN + Task: candidates over the whole image's feature map, ``togcrf.fcgn``).
GRASP_BRANCHES = ("roi", "image")


@dataclass(frozen=True)
class ModelSpec:
    """One model of Table II.

    Attributes
    ----------
    paper_name : str
        Its row name in Table II.
    grasp_branch : {"roi", "image"}
        Its grasp branch (``GRASP_BRANCHES``).
    crf_terms : (bool, bool) or None
        ``(use_omega, use_mu)`` of its task CRF; None: no CRF.
    """

    paper_name: str
    grasp_branch: str
    crf_terms: tuple[bool, bool] | None = None


#: The registry of the models, by name, in the row order of Table II: the only list of model names
#: (``togcrf.train``, ``togcrf.evaluate`` and ``togcrf.reproduce`` import theirs from here).
MODELS: dict[str, ModelSpec] = {
    "fcgn-task": ModelSpec("FCGN + Task", "image"),
    "tog": ModelSpec("TOG", "roi"),
    "tog-crfs-omega": ModelSpec("TOG-CRFs omega", "roi", (True, False)),
    "tog-crfs-mu": ModelSpec("TOG-CRFs mu", "roi", (False, True)),
    "tog-crfs": ModelSpec("TOG-CRFs", "roi", (True, True)),
}

#: Model names, in the order of Table II.
MODEL_NAMES = tuple(MODELS)

#: Row names of Table II, by model name.
PAPER_NAMES = {name: spec.paper_name for name, spec in MODELS.items()}

#: Supported ResNet depths (the paper uses resnet101), with the channels of their C2 (64 per basic block, 256
#: per bottleneck; He et al. 2016, Table 1).
C2_CHANNELS = {"resnet18": 64, "resnet34": 64, "resnet50": 256, "resnet101": 256}
BACKBONES = tuple(C2_CHANNELS)

#: Strides of the ResNet stages C2-C5, pixels of the network input.
RESNET_STRIDES = (4, 8, 16, 32)

#: Images are padded to a multiple of this (the coarsest FPN level, stride 32).
SIZE_DIVISIBLE = 32

#: Key of ResNet C2 (stride 4) among the backbone's maps with ``grasp_fine_map``: only the grasp head pools it.
FINE_MAP = "c2"


@dataclass(frozen=True)
class ModelOptions:
    """Options of the models (every one has a default; all go into checkpoints).

    Those of the "roi" grasp branch (TOG); FCGN + Task's are :class:`FcgnOptions`.

    Attributes
    ----------
    norm : {"group", "batch"}
        Normalisation layers of the backbone and grasp head.
    fpn_channels : int
        Channels of every FPN map (torchvision: 256).
    fpn_min_stride : {4, 8}
        Finest FPN level: 4 pools RoIs from ResNet C2 up (torchvision's
        default), 8 from C3 up only (about a third less work at 192 px; the
        tools are at least 10 px wide there).
    fpn_max_stride : {16, 32}
        Coarsest ResNet stage the FPN takes: 32 (torchvision's) keeps C5; 16
        stops the ResNet after C4, which drops its last stage (docs/togcrf.md,
        "Model"); the "pool" level is then at stride 32 and
        ``rpn_anchor_sizes`` needs one size fewer.
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
    grasp_regression_radius : float
        Anchors within this many cells beyond their own of a ground-truth
        grasp (angle within 22.5 degrees) regress to the nearest such grasp,
        while their stability label stays the paper's (0: only the positives
        regress; ``togcrf.anchors.regression_targets_within``). Our addition (issue
        #15): a quarter of the top-1 candidates of the recipe's TOG lie one
        cell from an annotated grasp, and only 30 % of those match it, since
        nothing taught their regression to reach it. Measured, not adopted:
        at radius 1 those match for 36 % but the positives for 87 % instead
        of 91 %, and mAP-G reads 25.1 against 25.2 (docs/togcrf-evaluation.md,
        "Regression from the neighbouring cells").
    grasp_object_map : bool
        The "roi" grasp head also predicts, per cell, whether the cell lies
        on the RoI's own object (trained against the share of the cell that
        the object's instance mask covers, RoIAligned onto the 7 x 7 cells as
        Mask R-CNN's mask targets); at inference a candidate's P(stable) is multiplied by its
        cell's P(own object). Our addition (issue #15): in piles, a box holds
        parts of its neighbours, and the most stable candidate of a detection
        lay on another object in 18 % of the claimed objects.
    grasp_ranking_weight : float
        Weight of a listwise "a positive candidate ranks first" term added to
        the stability loss (``togcrf.losses.top1_ranking_loss``; 0: the
        paper's cross entropy alone). Our addition (issue #15): mAP-G judges
        only a detection's top-1 candidate, and ranking the candidates that
        match an annotation first would lift the recipe's mAP-G from 18.6 to
        42.3 at its mAP of 49.2 (``benchmarks/grasp_ranking.py``, "grasp
        oracle", docs/togcrf-evaluation.md). At 1.0 in a 60-minute A/B it
        raised the top-1 match from 57.3 to 59.9 % but cost 7 points of box
        mAP and 1.4 of mAP-G. At 0.2, in the CPU recipe since 2026-11-29: at
        the same 48,440 images, mAP-G 27.5 and 29.8 against 25.6 and 22.9
        (seeds 0 and 1), box mAP -0.4 and +0.9 (docs/togcrf-evaluation.md,
        "The top-1 ranking term at weight 0.2 at the images of a 60-minute
        run").
    grasp_ranking_matches : bool
        The ranking term puts first the candidates whose regressed rectangle
        matches a ground-truth grasp of the RoI's object as mAP-G judges it
        (:func:`matching_candidates`; Jaccard > 0.25, angle within 30
        degrees), rather than the positive anchors (False: the anchors whose
        cell holds an annotated grasp centre). Our addition (issue #15): a
        sixth of the claimed objects get a top-1 beside one of their grasps,
        two fifths of them at a positive anchor whose regression misses the
        grasp, the rest a cell away (docs/togcrf-evaluation.md, "Where the
        top-1 misses"); this asks the ranking for exactly what the metric
        counts. Only with ``grasp_ranking_weight`` > 0. Measured, not
        adopted: at the same 48,440 images mAP-G 28.8 and 27.6 against 27.5
        and 29.8 (seeds 0 and 1; docs/togcrf-evaluation.md, "The ranking
        term on the candidates that match").
    grasp_confidence : bool
        The "roi" grasp head also predicts, per RoI, whether its top-1
        candidate matches one of its object's ground-truth grasps
        (:class:`TopGraspConfidence`, trained on the detached grasp features
        with binary cross entropy); at inference a detection's score is its
        class score times that probability, as Mask Scoring R-CNN (Huang et
        al., CVPR 2019) multiplies the class score by a predicted mask IoU.
        Our addition (issue #15): mAP-G counts a detection only when its
        top-1 grasp is right, and ranking the detections whose top-1 is right
        first would lift the recipe's mAP-G from 25 to 45 with the same
        grasps (``benchmarks/grasp_ranking.py``, "order oracle"), while the
        top-1 P(stable) tells right from wrong at ROC AUC 0.71 only.
        Measured, not adopted: the head reaches AUC 0.77-0.78 and gives
        +1.0-1.6 mAP-G for -8 to -9 mAP (docs/togcrf-evaluation.md, "A head
        that says whether its top-1 grasp is right").
    grasp_confidence_trains_features : bool
        The confidence loss also reaches the grasp trunk and what lies
        under it (False: the head sees detached features and changes
        nothing else the model learns).
    grasp_stability_per_category : bool
        The stability convolution of the "roi" grasp head gives each
        candidate one pair of logits per category, and a RoI uses its
        category's pair (in training its object's, at inference its
        detected label), as Mask R-CNN (He et al., ICCV 2017) predicts one
        mask per class. Our addition (issue #15): where the annotated grasps
        of an object lie depends on its category, and the top-1 candidate,
        which mAP-G judges, misses an annotation for 4 in 10 detections.
    grasp_fine_map : bool
        The "roi" grasp head also pools ResNet C2 (stride 4) of each RoI and
        adds it, projected and normalised, to the FPN features it pools
        (:class:`BackboneWithFineMap`); the RPN and the box branch do not see
        it. Our addition (issue #15): at the recipe's 160 px every RoI pools
        the stride-8 map, so a 40 px tool spans 5 feature pixels for its 7
        grasp cells, and 43 % of the wrong top-1 candidates lie one cell from
        an annotated grasp. Needs ``fpn_min_stride`` 8 (at 4, C2 is the
        finest FPN level already). Measured, not adopted: at the same 48,440
        images mAP-G 26.9 against 25.6 and Acc-T top-1 61.5 against 63.6, one
        seed (docs/togcrf-evaluation.md, "ResNet C2 for the grasp head at the
        same number of images").
    grasp_grid : int
        Cells per side of the "roi" grasp head's candidates (4 anchor angles
        per cell; 7: the paper's 7 x 7 x 4 = 196). The head's trunk runs on
        the 7 x 7 pooled RoI as always; with another grid its output is
        resized to ``grasp_grid`` x ``grasp_grid`` (bilinear) before the
        output convolutions, and the anchors, the matching and the CRF use
        the finer cells. Our addition (issue #15): at the recipe's 160 px a
        cell measures about 10 px, as much as the rows of annotated grasps
        are apart, while the regression moves a candidate's centre by a
        median 1.2 px; a sixth of the claimed objects get a top-1 that
        overlaps one of their grasps at its angle but misses it by about half
        a finger width (docs/togcrf-evaluation.md, "Where the top-1 misses").
        Measured, not adopted: at 14 (with ``grasp_ignore_radius`` 0.5), mAP-G
        29.2 against 29.9 and as many near misses, one seed at 16 % fewer
        images (docs/togcrf-evaluation.md, "A finer grid of grasp candidates").
    grasp_context_cells : int
        Cells of context the "roi" grasp head sees beyond each side of its
        RoI: it pools ``7 + 2 * c`` cells per side, of the same size, over
        the RoI widened about its centre, runs its ResBlocks on them and
        keeps the central 7 x 7 for its outputs, so the candidates, anchors
        and targets stay the RoI's own (0: the RoI alone, as the paper's
        head). Our addition (issue #15): the top-1 grasp of a claimed
        object lies on a neighbour or the table for 6-8 % of them, and the
        hand's collision with what lies around the object removes another
        3-6 % from the ground truth (docs/togcrf-evaluation.md, "Which
        filter leaves the top-1 without a valid grasp"); the head cannot
        see what lies just outside the box. Measured, not adopted: at 1,
        7 % fewer images in 60 minutes, mAP-G 29.5 against 29.8 and the
        top-1 on another object as often (7.3 against 6.4 % of the claimed
        objects), one seed (docs/togcrf-evaluation.md, "Context around the
        RoI for the grasp head").
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
    weight_object_map, weight_confidence : float
        Loss weights (RPN: objectness and box; RCNN: class and box).
    """

    norm: str = "group"
    fpn_channels: int = 256
    fpn_min_stride: int = 4
    fpn_max_stride: int = 32
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
    grasp_regression_radius: float = 0.0
    grasp_object_map: bool = False
    grasp_ranking_weight: float = 0.0
    grasp_ranking_matches: bool = False
    grasp_confidence: bool = False
    grasp_confidence_trains_features: bool = False
    grasp_stability_per_category: bool = False
    grasp_fine_map: bool = False
    grasp_grid: int = GRID
    grasp_context_cells: int = 0
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
    weight_object_map: float = 1.0
    weight_confidence: float = 1.0

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


@dataclass(frozen=True)
class FcgnOptions(ModelOptions):
    """Options of FCGN + Task (the "image" grasp branch): those of :class:`ModelOptions` plus the branch's.

    A subclass of :class:`ModelOptions`, so the training code stores every
    field in checkpoints and the model is rebuilt the same.

    Attributes
    ----------
    fcgn_level : int
        FPN level the grasp branch runs on, an index into the FPN's strides: "0" is the
        ``fpn_min_stride`` map (4 px by default, so "0"-"3" are strides 4-32 px).
    fcgn_channels : int
        Channels of the grasp branch's ResBlocks.
    fcgn_blocks : int
        ResBlocks before the output convolutions.
    fcgn_candidates_per_box : int
        Most stable candidates kept per detected box at inference.
    """

    fcgn_level: int = 1
    fcgn_channels: int = 128
    fcgn_blocks: int = 1
    fcgn_candidates_per_box: int = 196

    @staticmethod
    def from_dict(options: dict) -> FcgnOptions:
        """Options from keyword values; unknown names raise a TypeError that lists the known ones."""
        own = {field.name for field in fields(FcgnOptions)} - {field.name for field in fields(ModelOptions)}
        base = ModelOptions.from_dict({key: value for key, value in options.items() if key not in own})
        return FcgnOptions(**asdict(base), **{key: value for key, value in options.items() if key in own})


#: The options of each grasp branch.
BRANCH_OPTIONS: dict[str, type[ModelOptions]] = {"roi": ModelOptions, "image": FcgnOptions}


def norm_layer(kind: str) -> type[nn.Module] | callable:
    """A constructor ``channels -> normalisation module`` for ``kind`` in {"group", "batch"}."""
    if kind == "batch":
        return nn.BatchNorm2d
    if kind == "group":
        return lambda channels: nn.GroupNorm(min(32, channels), channels)
    raise ValueError(f"unknown normalisation {kind!r}; expected 'group' or 'batch'")


class BackboneWithFineMap(BackboneWithFPN):
    """torchvision's ResNet + FPN that also returns ResNet C2 (stride 4) under ``FINE_MAP``, outside the FPN.

    The FPN starts at C3 (``fpn_min_stride`` 8); the grasp head pools C2 as
    well (``ModelOptions.grasp_fine_map``). :func:`pyramid` gives the other
    maps, the ones the RPN and the box branch see.
    """

    def forward(self, images: torch.Tensor) -> dict[str, torch.Tensor]:
        stages = self.body(images)
        fine = stages.pop(FINE_MAP)
        maps = self.fpn(stages)
        maps[FINE_MAP] = fine
        return maps


def pyramid(features: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The FPN maps of the backbone's output, without ``FINE_MAP`` (the RPN takes every map it is given)."""
    return {name: feature for name, feature in features.items() if name != FINE_MAP}


def build_backbone(name: str, norm: str = "group", channels: int = 256, min_stride: int = 4,
                   fpn_norm: bool = True, max_stride: int = 32, fine_map: bool = False) -> BackboneWithFPN:
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
    max_stride : {16, 32}
        Stride of the coarsest ResNet stage kept; the body drops the stages after it.
    fine_map : bool
        Also return ResNet C2 under ``FINE_MAP`` (:class:`BackboneWithFineMap`); needs ``min_stride`` 8.

    Returns
    -------
    BackboneWithFPN
        Maps "0", "1", ... at strides ``min_stride`` ... ``max_stride`` and "pool" at twice that.
    """
    if name not in BACKBONES:
        raise ValueError(f"unknown backbone {name!r}; expected one of {BACKBONES}")
    if min_stride not in RESNET_STRIDES[:2]:
        raise ValueError(f"fpn_min_stride {min_stride}: expected 4 or 8")
    if max_stride not in RESNET_STRIDES[2:]:
        raise ValueError(f"fpn_max_stride {max_stride}: expected 16 or 32")
    if fine_map and min_stride != RESNET_STRIDES[1]:
        raise ValueError(f"grasp_fine_map needs fpn_min_stride 8, got {min_stride}: at 4 the finest FPN level is "
                         "C2 already")
    body = resnet.__dict__[name](weights=None, norm_layer=norm_layer(norm))
    body.conv1 = nn.Conv2d(1, body.conv1.out_channels, kernel_size=7, stride=2, padding=3, bias=False)
    nn.init.kaiming_normal_(body.conv1.weight, mode="fan_out", nonlinearity="relu")
    stages = [RESNET_STRIDES.index(stride) + 1 for stride in _kept_strides(min_stride, max_stride)]
    stage_channels = C2_CHANNELS[name]
    returned = {f"layer{stage}": str(index) for index, stage in enumerate(stages)}
    return (BackboneWithFineMap if fine_map else BackboneWithFPN)(
        body, {"layer1": FINE_MAP} | returned if fine_map else returned,
        [stage_channels * 2 ** (stage - 1) for stage in stages], channels,
        extra_blocks=LastLevelMaxPool(), norm_layer=norm_layer(norm) if fpn_norm else None)


def _kept_strides(min_stride: int, max_stride: int) -> tuple[int, ...]:
    """Strides of the ResNet stages the FPN takes, finest first."""
    return tuple(stride for stride in RESNET_STRIDES if min_stride <= stride <= max_stride)


def fpn_strides(options: ModelOptions) -> tuple[int, ...]:
    """Strides of the FPN maps that RoIs are pooled from ("0", "1", ...; "pool" excluded)."""
    return _kept_strides(options.fpn_min_stride, options.fpn_max_stride)


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


def stable_probability(stability: torch.Tensor, object_map: torch.Tensor | None) -> torch.Tensor:
    """The key that ranks a RoI's candidates: P(stable), times P(own object) of its cell with an object map.

    Parameters
    ----------
    stability : (R, K, 2) float
        Stability logits, index 1 = stable.
    object_map : (R, K / 4) float or None
        Per cell, the logit of "on the RoI's own object".

    Returns
    -------
    (R, K) float32
    """
    stable = stability.float().softmax(dim=-1)[..., 1]
    if object_map is None:
        return stable
    return stable * object_map.float().sigmoid().repeat_interleave(len(ANCHOR_ANGLES), dim=1)


class TopGraspConfidence(nn.Module):
    """The logit that a RoI's top-1 candidate is a right grasp (``ModelOptions.grasp_confidence``).

    Sees the grasp trunk's features of the RoI (detached unless
    ``trains_features``, so that it does not change what the other outputs
    learn), the P(stable) of every candidate and where the top-1 candidate
    lies: a 3 x 3 convolution over those maps, then two fully connected
    layers, as Mask Scoring R-CNN's MaskIoU head (Huang et al., CVPR 2019)
    rates a mask from the RoI features and the mask.
    """

    def __init__(self, channels: int, anchors: int, grid: int = GRID, hidden: int = 64, width: int = 256,
                 trains_features: bool = False) -> None:
        super().__init__()
        self.anchors = anchors
        self.trains_features = trains_features
        self.conv = nn.Conv2d(channels + 2 * anchors, hidden, 3, padding=1)
        self.fc = nn.Linear(hidden * grid * grid, width)
        self.logit = nn.Linear(width, 1)

    def forward(self, features: torch.Tensor, stable: torch.Tensor) -> torch.Tensor:
        """(R,) logits from trunk features (R, C, G, G) and the candidates' ranking key (R, G * G * 4)."""
        rois, _, rows, columns = features.shape
        def as_maps(values: torch.Tensor) -> torch.Tensor:  # candidate (i * G + j) * 4 + a -> map a at (i, j)
            return values.reshape(rois, rows, columns, self.anchors).permute(0, 3, 1, 2).to(features.dtype)
        stable = stable.detach()
        top = functional.one_hot(stable.argmax(dim=1), stable.shape[1]) if rois else stable
        features = features if self.trains_features else features.detach()
        maps = torch.cat([features, as_maps(stable), as_maps(top)], dim=1)
        hidden = functional.relu(self.fc(functional.relu(self.conv(maps)).flatten(start_dim=1)))
        return self.logit(hidden).flatten()


class GraspHead(nn.Module):
    """3 ResBlocks and the regression, stability and task convolutions (paper, Section IV-B).

    Input (R, C, H, W) features: pooled RoIs, 7 x 7 (the "roi" branch), or
    whole FPN maps (the "image" branch). Outputs per candidate, 4 per cell,
    cell (i, j) angle a being candidate (i * W + j) * 4 + a (the order of
    ``togcrf.anchors``): regression (R, H * W * 4, 5), stability logits
    (R, H * W * 4, 2), task logits (R, H * W * 4, 12); 196 candidates per RoI.
    With ``object_map``, one logit per cell (R, H * W); with ``confidence``,
    one per RoI (R,) (:class:`TopGraspConfidence`). With ``fine_channels``, a
    second pooled map (R, fine_channels, H, W) (ResNet C2,
    ``ModelOptions.grasp_fine_map``) is projected, normalised and added to
    the first before the ResBlocks. With ``grid``, the ResBlocks' output is
    resized to ``grid`` x ``grid`` (bilinear) before the output
    convolutions (``ModelOptions.grasp_grid``), so a RoI has
    ``grid * grid * 4`` candidates; None keeps the input's size. With
    ``context`` c, the pooled input holds c cells of context on each side
    of the RoI ((R, C, H + 2c, W + 2c), ``ModelOptions.grasp_context_cells``)
    and the ResBlocks' output is cropped to its central H x W.
    """

    def __init__(self, in_channels: int, channels: int, norm: str, task_count: int = len(TASKS),
                 blocks: int = 3, output_norm: bool = True, object_map: bool = False,
                 confidence: bool = False, confidence_trains_features: bool = False,
                 stability_categories: int = 1, fine_channels: int = 0, grid: int | None = None,
                 context: int = 0) -> None:
        super().__init__()
        #: Cells of context on each side of the pooled input, cropped after the ResBlocks.
        self.context = context
        self.anchors = len(ANCHOR_ANGLES)
        #: Cells per side of the candidates (None: the input's own; ``ModelOptions.grasp_grid``).
        self.grid = grid
        self.task_count = task_count
        #: Pairs of stability logits per candidate: 1, or one per category (``grasp_stability_per_category``).
        self.stability_categories = stability_categories
        self.entry = nn.Identity() if in_channels == channels else nn.Conv2d(in_channels, channels, 1)
        #: Projects the pooled ResNet C2 onto the trunk's channels (``ModelOptions.grasp_fine_map``).
        self.fine_entry = nn.Sequential(nn.Conv2d(fine_channels, channels, 1, bias=False),
                                        norm_layer(norm)(channels)) if fine_channels else None
        trunk = [ResBlock(channels, norm) for _ in range(blocks)]
        self.blocks = nn.Sequential(*trunk, *([norm_layer(norm)(channels)] if output_norm else []))
        self.regression = nn.Conv2d(channels, self.anchors * 5, 3, padding=1)
        self.stability = nn.Conv2d(channels, self.anchors * 2 * stability_categories, 3, padding=1)
        self.task = nn.Conv2d(channels, self.anchors * task_count, 3, padding=1)
        #: One logit per cell: the cell lies on the RoI's own object (``ModelOptions.grasp_object_map``).
        self.object_map = nn.Conv2d(channels, 1, 3, padding=1) if object_map else None
        for layer in (self.regression, self.stability, self.task, self.object_map):
            if layer is not None:
                nn.init.normal_(layer.weight, std=0.01)
                nn.init.zeros_(layer.bias)
        #: The logit that the top-1 candidate is right (``ModelOptions.grasp_confidence``).
        self.confidence = TopGraspConfidence(channels, self.anchors, grid or GRID,
                                             trains_features=confidence_trains_features) if (
            confidence) else None

    def _per_candidate(self, output: torch.Tensor, width: int) -> torch.Tensor:
        # channel a * width + d of cell (i, j) -> candidate (i * 7 + j) * 4 + a, component d
        rois, _, rows, columns = output.shape
        return output.permute(0, 2, 3, 1).reshape(rois, rows * columns * self.anchors, width)

    def _stability(self, features: torch.Tensor, categories: torch.Tensor | None) -> torch.Tensor:
        """(R, K, 2) stability logits; with one pair per category, the pair of each RoI's category (R,)."""
        stability = self._per_candidate(self.stability(features), 2 * self.stability_categories)
        if self.stability_categories == 1:
            return stability
        if categories is None:
            raise ValueError("grasp_stability_per_category: the grasp head needs each RoI's category")
        rois, candidates, _ = stability.shape
        pairs = stability.reshape(rois, candidates, self.stability_categories, 2)
        return pairs.gather(2, categories.reshape(rois, 1, 1, 1).expand(rois, candidates, 1, 2)).squeeze(2)

    def forward(self, pooled: torch.Tensor, categories: torch.Tensor | None = None, fine: torch.Tensor | None = None,
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        """Regression, stability and task per candidate, the object map per cell ``(R, H * W)`` or None, and
        the top-1 confidence logit per RoI ``(R,)`` or None; ``categories`` (R,) long: each RoI's category
        index, needed with one stability pair per category; ``fine`` the pooled C2, needed with
        ``fine_channels``."""
        features = self.entry(pooled)
        if self.fine_entry is not None:
            if fine is None:
                raise ValueError("grasp_fine_map: the grasp head needs each RoI's pooled ResNet C2")
            features = features + self.fine_entry(fine.to(features.dtype))
        features = self.blocks(features)
        if self.context:
            features = features[..., self.context:-self.context, self.context:-self.context]
        if self.grid is not None and features.shape[-2:] != (self.grid, self.grid):
            features = functional.interpolate(features, size=(self.grid, self.grid), mode="bilinear",
                                              align_corners=False)
        object_map = None if self.object_map is None else self.object_map(features).flatten(start_dim=1)
        stability = self._stability(features, categories)
        confidence = None if self.confidence is None else self.confidence(
            features, stable_probability(stability, object_map))  # the head detaches them
        return (
            self._per_candidate(self.regression(features), 5),
            stability,
            self._per_candidate(self.task(features), self.task_count),
            object_map,
            confidence,
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


class GraspOutputs(NamedTuple):
    """A grasp branch's outputs: R RoIs or images of K candidates.

    Attributes
    ----------
    regression : (R, K, 5) float
        Encoded deltas (``togcrf.anchors.encode``).
    stability : (R, K, 2) float
        Stability logits, index 1 = stable.
    task_log_probs : (R, K, T) float32
        ``log P(task | stable)``.
    anchors : (R, K, 5) or (K, 5) float32
        The candidates' anchors (those of the "image" branch are the same for every image).
    object_map : (R, GRID * GRID) float or None
        Per RoI cell, the logit of "on the RoI's own object" (``ModelOptions.grasp_object_map``).
    confidence : (R,) float or None
        Per RoI, the logit of "the top-1 candidate is right" (``ModelOptions.grasp_confidence``).
    """

    regression: torch.Tensor
    stability: torch.Tensor
    task_log_probs: torch.Tensor
    anchors: torch.Tensor
    object_map: torch.Tensor | None = None
    confidence: torch.Tensor | None = None


class GraspTargets(NamedTuple):
    """Training targets of a grasp branch's candidates (``togcrf.anchors.match``).

    Attributes
    ----------
    positive : (R, K) bool
    regression : (R, K, 5) float
    tasks : (R, K, T) float
        Soft task labels of the positives.
    ignored : (R, K) bool or None
        Candidates that may not be hard negatives.
    object_map : (R, GRID * GRID) float or None
        Share of each RoI cell covered by the RoI's object's instance mask.
    confidence : (R,) float or None
        1 where the RoI's top-1 candidate matches a ground-truth grasp of its object (:func:`top_grasp_right`).
    regressed : (R, K) bool or None
        Candidates whose regression is trained (None: the positives; ``ModelOptions.grasp_regression_radius``).
    ranked : (R, K) bool or None
        Candidates the ranking term puts first (None: the positives; ``ModelOptions.grasp_ranking_matches``).
    """

    positive: torch.Tensor
    regression: torch.Tensor
    tasks: torch.Tensor
    ignored: torch.Tensor | None = None
    object_map: torch.Tensor | None = None
    confidence: torch.Tensor | None = None
    regressed: torch.Tensor | None = None
    ranked: torch.Tensor | None = None


def build_rpn(options: ModelOptions) -> RegionProposalNetwork:
    """torchvision's RPN with one anchor size and 3 aspect ratios per FPN level ("pool" included)."""
    strides = fpn_strides(options)
    levels = len(strides) + 1  # the "pool" level of the RPN
    if len(options.rpn_anchor_sizes) != levels:
        raise ValueError(f"rpn_anchor_sizes {options.rpn_anchor_sizes}: expected {levels} sizes, one per FPN "
                         f"level (strides {(*strides, 2 * strides[-1])})")
    anchor_generator = AnchorGenerator(tuple((size,) for size in options.rpn_anchor_sizes),
                                       ((0.5, 1.0, 2.0),) * levels)
    return RegionProposalNetwork(
        anchor_generator, RPNHead(options.fpn_channels, 3),
        fg_iou_thresh=0.7, bg_iou_thresh=0.3, batch_size_per_image=256, positive_fraction=0.5,
        pre_nms_top_n={"training": options.rpn_pre_nms_train, "testing": options.rpn_pre_nms_test},
        post_nms_top_n={"training": options.rpn_post_nms_train, "testing": options.rpn_post_nms_test},
        nms_thresh=options.rpn_nms_threshold,
    )


def build_roi_pool(options: ModelOptions, size: int = GRID) -> FastMultiScaleRoIAlign:
    """RoIAlign ``size`` x ``size`` on the FPN maps: torchvision's, with a faster CPU backward
    (:mod:`togcrf.roi_align`) and the level scales fixed from the FPN strides."""
    strides = fpn_strides(options)
    roi_pool = FastMultiScaleRoIAlign([str(level) for level in range(len(strides))], output_size=size,
                                      sampling_ratio=2)
    # torchvision infers the level scales from the first batch's image sizes and caches them; with
    # small images padded to a multiple of 32 that guess is off by a level, and it would depend on
    # which batch came first: the FPN strides are known, so fix the scales.
    roi_pool.scales = [1.0 / stride for stride in strides]
    roi_pool.map_levels = initLevelMapper(int(math.log2(strides[0])), int(math.log2(strides[-1])))
    return roi_pool


def build_roi_heads(options: ModelOptions) -> RoIHeads:
    """torchvision's RoIHeads: RoIAlign 7 x 7 on the FPN maps (:func:`build_roi_pool`), the RCNN's two-layer
    MLP head and predictor. The grasp branch pools through the same RoIAlign, or through its own wider one
    with ``grasp_context_cells``."""
    return RoIHeads(
        build_roi_pool(options), TwoMLPHead(options.fpn_channels * GRID * GRID, options.box_head_size),
        FastRCNNPredictor(options.box_head_size, len(CATEGORIES) + 1),
        fg_iou_thresh=0.5, bg_iou_thresh=0.5, batch_size_per_image=options.box_batch_per_image,
        positive_fraction=0.25, bbox_reg_weights=None, score_thresh=options.box_score_threshold,
        nms_thresh=options.box_nms_threshold, detections_per_img=options.detections_per_image,
    )


def image_branch_stride(grasp_branch: str, options: ModelOptions) -> int | None:
    """Pixels per cell of the "image" branch's FPN map (None for the "roi" branch), the branch checked.

    Raises
    ------
    ValueError
        Unknown branch, or ``fcgn_level`` not an FPN level.
    TypeError
        The "image" branch without :class:`FcgnOptions`.
    """
    if grasp_branch not in GRASP_BRANCHES:
        raise ValueError(f"unknown grasp branch {grasp_branch!r}; expected one of {GRASP_BRANCHES}")
    if grasp_branch == "roi":
        return None
    if not isinstance(options, FcgnOptions):
        raise TypeError(f"the 'image' grasp branch needs FcgnOptions, got {type(options).__name__}")
    strides = fpn_strides(options)
    if not 0 <= options.fcgn_level < len(strides):
        raise ValueError(f"fcgn_level must be 0-{len(strides) - 1} (FPN strides {strides}), "
                         f"got {options.fcgn_level}")
    return strides[options.fcgn_level]


def build_grasp_head(grasp_branch: str, options: ModelOptions, backbone: str = "resnet18") -> GraspHead:
    """The grasp head of a branch: 3 ResBlocks of ``grasp_channels`` ("roi") or ``fcgn_blocks`` of
    ``fcgn_channels`` ("image"); ``backbone`` sets the channels of its C2 input with ``grasp_fine_map``."""
    if grasp_branch == "image":
        return GraspHead(options.fpn_channels, options.fcgn_channels, options.norm, blocks=options.fcgn_blocks,
                         output_norm=options.grasp_trunk_norm)
    return GraspHead(options.fpn_channels, options.grasp_channels, options.norm,
                     output_norm=options.grasp_trunk_norm, object_map=options.grasp_object_map,
                     confidence=options.grasp_confidence,
                     confidence_trains_features=options.grasp_confidence_trains_features,
                     stability_categories=len(CATEGORIES) if options.grasp_stability_per_category else 1,
                     fine_channels=C2_CHANNELS[backbone] if options.grasp_fine_map else 0, grid=options.grasp_grid,
                     context=options.grasp_context_cells)


def widened_boxes(boxes: torch.Tensor, factor: float) -> torch.Tensor:
    """``(n, 4)`` boxes ``x1, y1, x2, y2`` scaled by ``factor`` about their centres."""
    centres = (boxes[:, :2] + boxes[:, 2:]) / 2
    half = (boxes[:, 2:] - boxes[:, :2]) * (factor / 2)
    return torch.cat([centres - half, centres + half], dim=1)


def grasp_training_rois(proposals: list[torch.Tensor], labels: list[torch.Tensor], matched: list[torch.Tensor],
                        first_object: torch.Tensor, limit: int) -> tuple[list[torch.Tensor], torch.Tensor]:
    """The RoIs that train the "roi" branch: up to ``limit`` random foreground RoIs of each image.

    Parameters
    ----------
    proposals : list of (n_b, 4) float
        The RCNN's sampled RoIs of each image (ground-truth boxes among them).
    labels : list of (n_b,) int64
        Their categories; 0 = background.
    matched : list of (n_b,) int64
        The object of its image each RoI is matched to.
    first_object : (B,) int64
        Row of each image's first object in :func:`padded_object_grasps`.
    limit : int

    Returns
    -------
    rois : list of (m_b, 4) float
        Detached.
    owners : (sum m_b,) int64
        Row of each RoI's object in :func:`padded_object_grasps`.
    """
    rois, owners = [], []
    for image_index, (image_proposals, image_labels, image_matched) in enumerate(
            zip(proposals, labels, matched, strict=True)):
        foreground = torch.nonzero(image_labels > 0).flatten()
        if len(foreground) > limit:
            keep = torch.randperm(len(foreground), device=foreground.device)[:limit]
            foreground = foreground[keep]
        rois.append(image_proposals[foreground].detach())
        owners.append(image_matched[foreground] + first_object[image_index])
    return rois, torch.cat(owners)


def object_map_targets(targets: list[dict[str, torch.Tensor]], rois: torch.Tensor, owners: torch.Tensor,
                       grid: int = GRID) -> torch.Tensor:
    """The share of each RoI cell that its object's instance mask covers (Mask R-CNN's mask targets, 7 x 7).

    Parameters
    ----------
    targets : list of dict
        Per image, ``instance_mask`` (H, W) and ``mask_values`` (N,) (``togcrf.data.sample_targets``).
    rois : (R, 4) float
        All images' RoIs, pixels.
    owners : (R,) int64
        Each RoI's object, numbered over the batch image by image (:func:`padded_object_grasps`).

    Returns
    -------
    (R, grid * grid) float
        In the cells' order (row by row), as the grasp head's object map.
    """
    if any("instance_mask" not in target for target in targets):
        raise ValueError("grasp_object_map needs the samples' instance masks in the targets "
                         "(instance_mask, mask_values; togcrf.data.SamplesDataset gives them)")
    height = max(target["instance_mask"].shape[0] for target in targets)
    width = max(target["instance_mask"].shape[1] for target in targets)
    masks = []
    for target in targets:
        own = target["instance_mask"][None].to(torch.int64) == target["mask_values"][:, None, None]
        masks.append(functional.pad(own.float(), (0, width - own.shape[2], 0, height - own.shape[1])))
    masks = torch.cat(masks)[:, None]
    boxes = torch.cat([owners[:, None].to(rois.dtype), rois], dim=1)
    return roi_align(masks, boxes.to(masks.dtype), grid, spatial_scale=1.0, sampling_ratio=2).flatten(start_dim=1)


def top_grasp_right(outputs: GraspOutputs, owner_grasps: torch.Tensor, owner_valid: torch.Tensor) -> torch.Tensor:
    """Whether each training RoI's top-1 candidate is a right grasp: the target of ``grasp_confidence``.

    Right as mAP-G judges a detection's top-1 grasp (:func:`rectangles_matching`: Jaccard
    > 0.25 and angle within 30 degrees of one of the ground-truth grasps of the object the RoI is
    matched to), the top-1 ranked as at inference (:func:`stable_probability`).

    Parameters
    ----------
    outputs : GraspOutputs
        Of R RoIs.
    owner_grasps : (R, G, 5) float
        The ground-truth grasps of each RoI's object, padded.
    owner_valid : (R, G) bool

    Returns
    -------
    (R,) float32
        1.0 or 0.0.
    """
    rois = outputs.stability.shape[0]
    if rois == 0:
        return outputs.stability.new_zeros((0,), dtype=torch.float32)
    with torch.no_grad():
        top = stable_probability(outputs.stability, outputs.object_map).argmax(dim=1)
        rows = torch.arange(rois, device=top.device)
        rectangles = decode(outputs.regression[rows, top].float(), outputs.anchors[rows, top].float())
    return rectangles_matching(rectangles[:, None], owner_grasps, owner_valid)[:, 0].float()


def matching_candidates(outputs: GraspOutputs, owner_grasps: torch.Tensor, owner_valid: torch.Tensor,
                        ) -> torch.Tensor:
    """Which candidates of each training RoI match a ground-truth grasp of its object: the targets of
    ``grasp_ranking_matches``.

    A candidate matches as mAP-G judges a detection's top-1 grasp: its regressed rectangle against the
    grasps of the object the RoI is matched to (:func:`rectangles_matching`).

    Parameters
    ----------
    outputs : GraspOutputs
        Of R RoIs with K candidates each.
    owner_grasps : (R, G, 5) float
        The ground-truth grasps of each RoI's object, padded.
    owner_valid : (R, G) bool

    Returns
    -------
    (R, K) bool
    """
    with torch.no_grad():
        rectangles = decode(outputs.regression.float(), outputs.anchors.float())
    return rectangles_matching(rectangles, owner_grasps, owner_valid)


def rectangles_matching(rectangles: torch.Tensor, owner_grasps: torch.Tensor, owner_valid: torch.Tensor,
                        ) -> torch.Tensor:
    """Which rectangles of each RoI match a ground-truth grasp of its object, as mAP-G judges a grasp.

    The rule is ``togcrf.metrics.paired_grasp_match``'s (Jaccard > 0.25, angle within 30 degrees). Only
    the pairs that could match go to its exact polygon test: close in angle, and with bounding boxes that
    overlap by more than the Jaccard threshold allows the rectangles themselves to (a little margin for
    float32).

    Parameters
    ----------
    rectangles : (R, M, 5) float
        ``x, y, h, w, theta`` per RoI.
    owner_grasps : (R, G, 5) float
        The ground-truth grasps of each RoI's object, padded.
    owner_valid : (R, G) bool

    Returns
    -------
    (R, M) bool
    """
    with torch.no_grad():
        rectangles = rectangles.float()[:, :, None]
        grasps = owner_grasps.float()[:, None]
        difference = (rectangles[..., 4] - grasps[..., 4]).abs() % math.pi
        angle_close = torch.minimum(difference, math.pi - difference) < GRASP_ANGLE_TOLERANCE + 1e-3
        # Jaccard > t needs an intersection above t / (1 + t) of the two areas' sum, and the intersection
        # of the rectangles is at most that of their axis-aligned bounding boxes.
        areas = (rectangles[..., 2] * rectangles[..., 3]).abs() + (grasps[..., 2] * grasps[..., 3]).abs()
        needed = 0.99 * GRASP_JACCARD_THRESHOLD / (1 + GRASP_JACCARD_THRESHOLD) * areas - 1e-3
        close = angle_close & owner_valid[:, None, :] & (_bounding_box_overlap(rectangles, grasps) > needed)
        roi, candidate, grasp = close.nonzero(as_tuple=True)
        hits = torch.from_numpy(paired_grasp_match(rectangles[roi, candidate, 0].cpu().numpy(),
                                                   grasps[roi, 0, grasp].cpu().numpy())).to(roi.device)
        matching = torch.zeros(rectangles.shape[:2], dtype=torch.bool, device=roi.device)
        matching[roi[hits], candidate[hits]] = True
    return matching


def _bounding_box_overlap(first: torch.Tensor, second: torch.Tensor) -> torch.Tensor:
    """Area shared by the axis-aligned bounding boxes of rotated rectangles (broadcasting): (..., 5) -> (...)."""
    def half_sides(rectangles: torch.Tensor) -> torch.Tensor:
        cos, sin = rectangles[..., 4].cos().abs(), rectangles[..., 4].sin().abs()
        opening, width = rectangles[..., 2].abs() / 2, rectangles[..., 3].abs() / 2
        return torch.stack([opening * cos + width * sin, opening * sin + width * cos], dim=-1)

    first_half, second_half = half_sides(first), half_sides(second)
    low = torch.maximum(first[..., :2] - first_half, second[..., :2] - second_half)
    high = torch.minimum(first[..., :2] + first_half, second[..., :2] + second_half)
    return (high - low).clamp(min=0).prod(dim=-1)


def rescored(detections: list[dict[str, torch.Tensor]], confidence: tuple[torch.Tensor, ...],
             ) -> list[dict[str, torch.Tensor]]:
    """Detections whose ``scores`` are their class scores (kept as ``class_scores``) times ``confidence``."""
    return [{**detection, "scores": detection["scores"] * probability.to(detection["scores"].dtype),
             "class_scores": detection["scores"]}
            for detection, probability in zip(detections, confidence, strict=True)]


#: The ``ModelOptions`` weight of each loss of ``LOSS_KEYS``, in its order.
LOSS_WEIGHTS = dict(zip(LOSS_KEYS, ("weight_rpn", "weight_rpn", "weight_rcnn", "weight_rcnn", "weight_stability",
                                    "weight_regression", "weight_task", "weight_object_map", "weight_confidence"),
                        strict=True))

#: torchvision's names of the RPN and RCNN losses, the first four of ``LOSS_KEYS``.
TORCHVISION_LOSSES = dict(zip(LOSS_KEYS[:4], ("loss_objectness", "loss_rpn_box_reg", "loss_classifier",
                                              "loss_box_reg"), strict=True))


def weighted_losses(options: ModelOptions, detector_losses: dict[str, torch.Tensor],
                    grasp: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The losses a model returns: each of ``LOSS_KEYS``, in its order, times its weight.

    Parameters
    ----------
    options : ModelOptions
    detector_losses : dict of scalar tensors
        torchvision's RPN and RCNN losses, by torchvision's names.
    grasp : dict of scalar tensors
        ``togcrf.losses.grasp_losses``.
    """
    values = {key: detector_losses[name] for key, name in TORCHVISION_LOSSES.items()} | grasp
    return {key: getattr(options, LOSS_WEIGHTS[key]) * values[key] for key in LOSS_KEYS}


def detection_output(detection: dict[str, torch.Tensor], grasps: torch.Tensor, stability: torch.Tensor,
                     task_probs: torch.Tensor) -> dict[str, torch.Tensor]:
    """One image's output in eval mode (the contract): its detections with their grasp candidates.

    Parameters
    ----------
    detection : dict
        The RCNN's ``boxes`` (N, 4), ``labels`` (N,) and ``scores`` (N,); with ``grasp_confidence`` also
        ``class_scores`` (N,), the scores before :func:`rescored`, passed on.
    grasps : (N, K, 5) float
        Rectangles ``(x, y, h, w, theta)``, pixels of the network input.
    stability : (N, K) float
        P(stable).
    task_probs : (N, K, T) float
    """
    extra = {"class_scores": detection["class_scores"].float()} if "class_scores" in detection else {}
    return {
        "boxes": detection["boxes"].float(),
        "labels": detection["labels"],
        "scores": detection["scores"].float(),
        "grasps": grasps,
        "grasp_stability": stability,
        "grasp_task_probs": task_probs,
        **extra,
    }


class GraspDetector(nn.Module):
    """The detector of every model: backbone, RPN, RCNN box branch, one grasp branch and the task CRF.

    Both grasp branches share the detector, the :class:`GraspHead` and the
    losses; the attributes, and so the checkpoint keys, are the same:
    ``backbone``, ``rpn``, ``roi_heads`` (torchvision's, for the boxes),
    ``grasp_head`` and ``crf`` (None without the CRF).

    Parameters
    ----------
    backbone : str
        One of ``BACKBONES``.
    crf_terms : (bool, bool) or None
        ``(use_omega, use_mu)`` of the CRF; None: no CRF.
    options : ModelOptions
        :class:`FcgnOptions` for the "image" branch.
    grasp_branch : {"roi", "image"}
        "roi": TOG's, on the RoIs; "image": FCGN's, on FPN map ``fcgn_level`` of the whole image.
    """

    def __init__(self, backbone: str = "resnet18", crf_terms: tuple[bool, bool] | None = None,
                 options: ModelOptions | None = None, grasp_branch: str = "roi") -> None:
        super().__init__()
        self.options = options = options or ModelOptions()
        self.grasp_branch = grasp_branch
        #: Pixels per cell of the "image" branch's feature map; None for the "roi" branch.
        self.grasp_stride = image_branch_stride(grasp_branch, options)
        for option in ("grasp_object_map", "grasp_confidence", "grasp_stability_per_category",
                       "grasp_regression_radius", "grasp_fine_map", "grasp_context_cells"):
            if grasp_branch == "image" and getattr(options, option):
                raise ValueError(f"{option} needs RoIs: it is an option of the \"roi\" grasp branch (TOG, "
                                 "TOG-CRFs), not of FCGN + Task")
        if options.grasp_context_cells < 0:
            raise ValueError(f"grasp_context_cells {options.grasp_context_cells}: expected 0 or more cells")
        if options.grasp_grid < 1 or (grasp_branch == "image" and options.grasp_grid != GRID):
            raise ValueError(f"grasp_grid {options.grasp_grid}: expected a whole number of cells of at least 1, "
                             f"for the \"roi\" grasp branch (TOG, TOG-CRFs) only ({GRID} otherwise)")
        self.backbone = build_backbone(backbone, options.norm, options.fpn_channels, options.fpn_min_stride,
                                       options.fpn_norm, options.fpn_max_stride, options.grasp_fine_map)
        self.rpn = build_rpn(options)
        self.roi_heads = build_roi_heads(options)
        self.grasp_head = build_grasp_head(grasp_branch, options, backbone)
        #: The grasp head's own RoIAlign, ``7 + 2 * grasp_context_cells`` cells per side (None without context).
        self.grasp_roi_pool = build_roi_pool(options, GRID + 2 * options.grasp_context_cells) if (
            options.grasp_context_cells) else None
        self.crf = None if crf_terms is None else MeanFieldCrf(
            len(TASKS), use_omega=crf_terms[0], use_mu=crf_terms[1],
            iterations=options.crf_iterations, bandwidth=options.crf_bandwidth, grid=options.grasp_grid,
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
                      image_sizes: list[tuple[int, int]], labels: list[torch.Tensor] | None = None) -> GraspOutputs:
        """The grasp head on RoIs (a list of (n_b, 4) boxes per image), as the "roi" branch runs it.

        ``labels`` (a list of (n_b,) category index + 1) are needed with ``grasp_stability_per_category``.

        Returns
        -------
        GraspOutputs
            R = all RoIs, K = ``grasp_grid`` ** 2 * 4 (196 on the paper's 7 x 7 cells); anchors (R, K, 5).
        """
        size = GRID + 2 * self.options.grasp_context_cells
        pool, pooled_rois = self.roi_heads.box_roi_pool, rois
        if self.grasp_roi_pool is not None:  # the RoIs with their context around them
            pool, pooled_rois = self.grasp_roi_pool, [widened_boxes(boxes, size / GRID) for boxes in rois]
        pooled = pool(features, pooled_rois, image_sizes)
        fine = None if FINE_MAP not in features else roi_align_fast_backward(
            features[FINE_MAP], convert_boxes_to_roi_format(pooled_rois), (size, size), 1.0 / RESNET_STRIDES[0],
            sampling_ratio=2)
        categories = None if labels is None else torch.cat(labels).long() - 1
        regression, stability, task_logits, object_map, confidence = self.grasp_head(pooled, categories, fine)
        all_rois = torch.cat(rois) if rois else pooled.new_zeros((0, 4))
        anchors = roi_anchors(all_rois.float(), self.options.grasp_anchor_size, self.options.grasp_grid)
        return GraspOutputs(regression, stability, self.task_log_probs(task_logits), anchors, object_map, confidence)

    def image_grasp_outputs(self, features: dict[str, torch.Tensor]) -> GraspOutputs:
        """The grasp head on FPN map ``fcgn_level`` of every image, as the "image" branch runs it.

        Returns
        -------
        GraspOutputs
            R = images, K = 4 per cell of the map; anchors (K, 5).
        """
        level = features[str(self.options.fcgn_level)]
        regression, stability, task_logits, _, _ = self.grasp_head(level)
        anchors = image_anchors(level.shape[2], level.shape[3], self.grasp_stride, self.options.grasp_anchor_size,
                                device=level.device)
        return GraspOutputs(regression, stability, self.task_log_probs(task_logits), anchors)

    def forward(self, images: list[torch.Tensor], targets: list[dict[str, torch.Tensor]] | None = None,
                ) -> dict[str, torch.Tensor] | list[dict[str, torch.Tensor]]:
        """Losses (train mode, with targets) or detections (eval mode); see the module docstring.

        Parameters
        ----------
        images : list of (1, H, W) float
            Depth images.
        targets : list of dict, optional
            Per image (train mode): ``boxes`` (N, 4), ``labels`` (N,), ``grasps`` (M, 5),
            ``grasp_objects`` (M,) and ``grasp_tasks`` (M,); with ``grasp_object_map`` also
            ``instance_mask`` (H, W) and ``mask_values`` (N,) (``togcrf.data.sample_targets``).

        Returns
        -------
        dict of scalar tensors or list of dict
            Train mode: the losses, ``LOSS_KEYS``. Eval mode, per image: ``boxes`` (N, 4), ``labels`` (N,),
            ``scores`` (N,), ``grasps`` (N, K, 5), ``grasp_stability`` (N, K), ``grasp_task_probs`` (N, K, 12).
        """
        image_list = batch_images(images)
        features = self.backbone(image_list.tensors)
        if self.training:
            if targets is None:
                raise ValueError("the model is in train mode: pass targets, or call model.eval()")
            return self._training_losses(image_list, features, targets)
        proposals, _ = self.rpn(image_list, pyramid(features))
        detections, _ = self.roi_heads(features, proposals, image_list.image_sizes)
        if self.grasp_branch == "image":
            return self._image_detections(features, detections)
        return self._roi_detections(features, detections, image_list.image_sizes)

    def _training_losses(self, image_list: ImageList, features: dict[str, torch.Tensor],
                         targets: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
        """RPN, RCNN box branch and grasp branch in train mode: the weighted ``LOSS_KEYS``."""
        proposals, rpn_losses = self.rpn(image_list, pyramid(features), targets)
        sampled, box_losses = self._box_losses(features, proposals, image_list.image_sizes, targets)
        if self.grasp_branch == "image":
            outputs, grasp_targets = self._image_training_grasps(features, targets)
        else:
            outputs, grasp_targets = self._roi_training_grasps(features, sampled, image_list.image_sizes, targets)
        return weighted_losses(self.options, rpn_losses | box_losses, self._grasp_losses(outputs, grasp_targets))

    def _box_losses(self, features: dict[str, torch.Tensor], proposals: list[torch.Tensor],
                    image_sizes: list[tuple[int, int]], targets: list[dict[str, torch.Tensor]],
                    ) -> tuple[tuple[list[torch.Tensor], ...], dict[str, torch.Tensor]]:
        """The RCNN box branch in train mode: the training half of torchvision's ``RoIHeads.forward``.

        Returns
        -------
        sampled : (proposals, labels, matched)
            Per image, the sampled RoIs (n_b, 4), their labels (n_b,) (0 = background) and the index of
            the object each is matched to (n_b,).
        losses : dict of scalar tensors
            "loss_classifier" and "loss_box_reg".
        """
        heads = self.roi_heads
        proposals, matched, labels, box_targets = heads.select_training_samples(proposals, targets)
        box_features = heads.box_head(heads.box_roi_pool(features, proposals, image_sizes))
        class_logits, box_regression = heads.box_predictor(box_features)
        class_loss, box_loss = fastrcnn_loss(class_logits, box_regression, labels, box_targets)
        return (proposals, labels, matched), {"loss_classifier": class_loss, "loss_box_reg": box_loss}

    def _roi_training_grasps(self, features: dict[str, torch.Tensor], sampled: tuple[list[torch.Tensor], ...],
                             image_sizes: list[tuple[int, int]], targets: list[dict[str, torch.Tensor]],
                             ) -> tuple[GraspOutputs, GraspTargets]:
        """The "roi" branch in train mode: foreground RoIs (ground-truth boxes and proposals with IoU >= 0.5),
        capped per image, each with the grasps of the object it is matched to."""
        options = self.options
        grasps, valid, tasks, first_object = padded_object_grasps(targets)
        rois, owners = grasp_training_rois(*sampled, first_object, options.grasp_rois_per_image)
        owner_labels = torch.cat([target["labels"] for target in targets])[owners]
        outputs = self.grasp_outputs(features, rois, image_sizes, [owner_labels])
        roi_boxes, owner_grasps = torch.cat(rois).float(), grasps[owners].float()
        grid = options.grasp_grid
        positive, regression_targets, task_targets = match(
            outputs.anchors, roi_boxes, owner_grasps, valid[owners], tasks[owners], len(TASKS), grid,
            positive_radius=options.grasp_positive_radius)
        ignored = None if options.grasp_ignore_radius is None else near_ground_truth(
            outputs.anchors, roi_boxes, owner_grasps, valid[owners], options.grasp_ignore_radius, grid)
        regressed = None
        if options.grasp_regression_radius > 0:
            regressed, regression_targets = regression_targets_within(
                outputs.anchors, roi_boxes, owner_grasps, valid[owners], options.grasp_regression_radius, grid)
        object_map = object_map_targets(targets, roi_boxes, owners, grid) if options.grasp_object_map else None
        confidence = None if outputs.confidence is None else top_grasp_right(outputs, owner_grasps, valid[owners])
        ranks_matches = options.grasp_ranking_matches and options.grasp_ranking_weight > 0
        ranked = matching_candidates(outputs, owner_grasps, valid[owners]) if ranks_matches else None
        return outputs, GraspTargets(positive, regression_targets, task_targets, ignored, object_map, confidence,
                                     regressed, ranked)

    def _image_training_grasps(self, features: dict[str, torch.Tensor], targets: list[dict[str, torch.Tensor]],
                               ) -> tuple[GraspOutputs, GraspTargets]:
        """The "image" branch in train mode: every grasp of an image is a target of its cell's anchors."""
        outputs = self.image_grasp_outputs(features)
        return outputs, GraspTargets(*image_grasp_targets(targets, outputs.anchors, self.grasp_stride))

    def _grasp_losses(self, outputs: GraspOutputs, targets: GraspTargets) -> dict[str, torch.Tensor]:
        """``togcrf.losses.grasp_losses`` of a branch; sets ``last_training_stats``."""
        grasp = grasp_losses(outputs.stability, outputs.regression, outputs.task_log_probs, targets.positive,
                             targets.regression, targets.tasks, self.options.negative_ratio, targets.ignored,
                             self.options.grasp_ranking_weight, targets.regressed, targets.ranked)
        grasp["grasp_object_map"] = binary_loss(outputs.object_map, targets.object_map, outputs.stability)
        grasp["grasp_confidence"] = binary_loss(outputs.confidence, targets.confidence, outputs.stability)
        hits, rois = top1_task_hits(outputs.stability, outputs.task_log_probs, targets.positive, targets.tasks)
        self.last_training_stats = {"acc_t_hits": hits, "acc_t_rois": rois,
                                    "positive_candidates": int(targets.positive.sum())}
        return grasp

    def _roi_detections(self, features: dict[str, torch.Tensor], detections: list[dict[str, torch.Tensor]],
                        image_sizes: list[tuple[int, int]]) -> list[dict[str, torch.Tensor]]:
        """The "roi" branch in eval mode: the candidates of each detected box (196 on 7 x 7 cells)."""
        counts = [len(detection["boxes"]) for detection in detections]
        outputs = self.grasp_outputs(features, [detection["boxes"] for detection in detections], image_sizes,
                                     [detection["labels"] for detection in detections])
        rectangles = decode(outputs.regression.float(), outputs.anchors)
        stable = stable_probability(outputs.stability, outputs.object_map)
        task_probs = outputs.task_log_probs.exp()
        if outputs.confidence is not None:
            detections = rescored(detections, outputs.confidence.float().sigmoid().split(counts))
        return [detection_output(detection, *per_image) for detection, *per_image in zip(
            detections, rectangles.split(counts), stable.split(counts), task_probs.split(counts), strict=True)]

    def _image_detections(self, features: dict[str, torch.Tensor],
                          detections: list[dict[str, torch.Tensor]]) -> list[dict[str, torch.Tensor]]:
        """The "image" branch in eval mode: the candidates of the whole image, given to the boxes that
        contain their centres (``togcrf.fcgn.box_candidates``)."""
        outputs = self.image_grasp_outputs(features)
        rectangles = decode(outputs.regression.float(), outputs.anchors[None])
        stable = outputs.stability.float().softmax(dim=-1)[..., 1]
        task_probs = outputs.task_log_probs.exp()
        keep = self.options.fcgn_candidates_per_box
        return [detection_output(detection, *box_candidates(
            rectangles[index], stable[index], task_probs[index], detection["boxes"].float(), keep))
            for index, detection in enumerate(detections)]


#: The name older code gives the detector.
TogDetector = GraspDetector


def build_model(name: str, backbone: str = "resnet18", **options) -> GraspDetector:
    """A model of Table II by name (``MODELS``).

    Parameters
    ----------
    name : str
        One of ``MODEL_NAMES``.
    backbone : str
        One of ``BACKBONES``.
    **options
        :class:`ModelOptions` fields (for "fcgn-task": :class:`FcgnOptions` fields).

    Raises
    ------
    ValueError
        Unknown name or backbone.
    TypeError
        Unknown option.
    """
    if name not in MODELS:
        raise ValueError(f"unknown model {name!r}; expected one of {MODEL_NAMES}")
    spec = MODELS[name]
    return GraspDetector(backbone, spec.crf_terms, BRANCH_OPTIONS[spec.grasp_branch].from_dict(options),
                         spec.grasp_branch)


def model_options_dict(options: ModelOptions) -> dict:
    """Options as plain JSON-able values."""
    values = asdict(options)
    values["rpn_anchor_sizes"] = list(values["rpn_anchor_sizes"])
    return values
