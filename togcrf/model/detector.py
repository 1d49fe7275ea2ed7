"""The detector of every model of Table II (paper, Section IV-B/C, Fig. 3): :class:`GraspDetector`.

Depth image -> ResNet with a feature pyramid (``togcrf.model.backbone``) -> RPN -> RoIAlign 7 x 7 ->
the RCNN box branch (torchvision's two-layer MLP head and predictor: box refinement and the vocabulary's
categories plus background), and one grasp branch, as torchvision's ``RoIHeads`` holds its box, mask and keypoint
branches:

- "roi" (TOG and TOG-CRFs): the grasp head (``togcrf.model.grasp_head``) on the pooled features of each
  RoI, 196 candidates per RoI (``togcrf.anchors``);
- "image" (FCGN + Task, ``togcrf.fcgn``): the same head on one FPN map of the whole image, 4 candidates
  per cell, given at inference to the detected boxes that contain them.

For the CRF variants the task logits go through :class:`togcrf.crf.MeanFieldCrf`. The model API is the
contract in ``docs/togcrf.md``: train mode returns a dict of scalar losses (``togcrf.losses.LOSS_KEYS``),
eval mode a list of per-image detections with grasp candidates.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import torch
from torch import nn
from torchvision.models.detection.anchor_utils import AnchorGenerator
from torchvision.models.detection.faster_rcnn import FastRCNNPredictor, TwoMLPHead
from torchvision.models.detection.image_list import ImageList
from torchvision.models.detection.roi_heads import RoIHeads, fastrcnn_loss
from torchvision.models.detection.rpn import RegionProposalNetwork, RPNHead
from torchvision.ops.poolers import initLevelMapper

from osgd.contract.taxonomy import VOCABULARY
from togcrf.anchors import GRID, decode, match, roi_anchors
from togcrf.crf import MeanFieldCrf
from togcrf.fcgn import box_candidates, image_anchors, image_grasp_targets
from togcrf.losses import LOSS_KEYS, grasp_losses, top1_task_hits
from togcrf.model.backbone import build_backbone, kept_strides
from togcrf.model.grasp_head import GraspOutputs, build_grasp_head, stable_probability
from togcrf.model.options import ModelOptions
from togcrf.model.registry import GRASP_BRANCHES
from togcrf.model.targets import GraspTargets, grasp_training_rois, padded_object_grasps
from togcrf.roi_align import FastMultiScaleRoIAlign

#: Images are padded to a multiple of this (the coarsest FPN level, stride 32).
SIZE_DIVISIBLE = 32

#: The ``LossOptions`` weight of each loss of ``LOSS_KEYS``, in its order.
LOSS_WEIGHTS = dict(zip(LOSS_KEYS, ("rpn", "rpn", "rcnn", "rcnn", "stability", "regression", "task"), strict=True))

#: torchvision's names of the RPN and RCNN losses, the first four of ``LOSS_KEYS``.
TORCHVISION_LOSSES = dict(zip(LOSS_KEYS[:4], ("loss_objectness", "loss_rpn_box_reg", "loss_classifier",
                                              "loss_box_reg"), strict=True))


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


def build_rpn(options: ModelOptions) -> RegionProposalNetwork:
    """torchvision's RPN with one anchor size and 3 aspect ratios per FPN level ("pool" included)."""
    strides = kept_strides(options.backbone)
    levels = len(strides) + 1  # the "pool" level of the RPN
    rpn = options.rpn
    if len(rpn.anchor_sizes) != levels:
        raise ValueError(f"rpn.anchor_sizes {list(rpn.anchor_sizes)}: expected {levels} sizes, one per FPN "
                         f"level (strides {(*strides, 2 * strides[-1])})")
    anchor_generator = AnchorGenerator(tuple((size,) for size in rpn.anchor_sizes), ((0.5, 1.0, 2.0),) * levels)
    return RegionProposalNetwork(
        anchor_generator, RPNHead(options.backbone.fpn_channels, 3),
        fg_iou_thresh=0.7, bg_iou_thresh=0.3, batch_size_per_image=256, positive_fraction=0.5,
        pre_nms_top_n={"training": rpn.pre_nms_train, "testing": rpn.pre_nms_test},
        post_nms_top_n={"training": rpn.post_nms_train, "testing": rpn.post_nms_test},
        nms_thresh=rpn.nms_threshold,
    )


def build_roi_pool(options: ModelOptions) -> FastMultiScaleRoIAlign:
    """RoIAlign 7 x 7 on the FPN maps: torchvision's, with a faster CPU backward (:mod:`togcrf.roi_align`) and
    the level scales fixed from the FPN strides."""
    strides = kept_strides(options.backbone)
    roi_pool = FastMultiScaleRoIAlign([str(level) for level in range(len(strides))], output_size=GRID,
                                      sampling_ratio=2)
    # torchvision infers the level scales from the first batch's image sizes and caches them; with
    # small images padded to a multiple of 32 that guess is off by a level, and it would depend on
    # which batch came first: the FPN strides are known, so fix the scales.
    roi_pool.scales = [1.0 / stride for stride in strides]
    roi_pool.map_levels = initLevelMapper(int(math.log2(strides[0])), int(math.log2(strides[-1])))
    return roi_pool


def build_roi_heads(options: ModelOptions, category_count: int) -> RoIHeads:
    """torchvision's RoIHeads: RoIAlign 7 x 7 (:func:`build_roi_pool`), the RCNN's MLP head and predictor
    (``category_count`` classes and the background); the grasp branch pools through the same RoIAlign."""
    box = options.box_head
    return RoIHeads(
        build_roi_pool(options), TwoMLPHead(options.backbone.fpn_channels * GRID * GRID, box.size),
        FastRCNNPredictor(box.size, category_count + 1),
        fg_iou_thresh=0.5, bg_iou_thresh=0.5, batch_size_per_image=box.batch_per_image,
        positive_fraction=0.25, bbox_reg_weights=None, score_thresh=box.score_threshold,
        nms_thresh=box.nms_threshold, detections_per_img=box.detections_per_image,
    )


def image_branch_stride(grasp_branch: str, options: ModelOptions) -> int | None:
    """Pixels per cell of the "image" branch's FPN map (None for the "roi" branch), the branch checked."""
    if grasp_branch not in GRASP_BRANCHES:
        raise ValueError(f"unknown grasp branch {grasp_branch!r}; expected one of {GRASP_BRANCHES}")
    if grasp_branch == "roi":
        return None
    strides = kept_strides(options.backbone)
    if not 0 <= options.fcgn.level < len(strides):
        raise ValueError(f"fcgn.level must be 0-{len(strides) - 1} (FPN strides {strides}), "
                         f"got {options.fcgn.level}")
    return strides[options.fcgn.level]


def weighted_losses(options: ModelOptions, detector_losses: dict[str, torch.Tensor],
                    grasp: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The losses a model returns: each of ``LOSS_KEYS``, in its order, times its weight (``loss.*``).

    ``detector_losses`` are torchvision's RPN and RCNN losses by torchvision's names, ``grasp``
    ``togcrf.losses.grasp_losses``.
    """
    values = {key: detector_losses[name] for key, name in TORCHVISION_LOSSES.items()} | grasp
    return {key: getattr(options.loss, LOSS_WEIGHTS[key]) * values[key] for key in LOSS_KEYS}


def detection_output(detection: dict[str, torch.Tensor], grasps: torch.Tensor, stability: torch.Tensor,
                     task_probs: torch.Tensor) -> dict[str, torch.Tensor]:
    """One image's output in eval mode (the contract): its detections with their grasp candidates.

    Parameters
    ----------
    detection : dict
        The RCNN's ``boxes`` (N, 4), ``labels`` (N,) and ``scores`` (N,).
    grasps : (N, K, 5) float
        Rectangles ``(x, y, h, w, theta)``, pixels of the network input.
    stability : (N, K) float
        P(stable).
    task_probs : (N, K, T) float
    """
    return {"boxes": detection["boxes"].float(), "labels": detection["labels"], "scores": detection["scores"].float(),
            "grasps": grasps, "grasp_stability": stability, "grasp_task_probs": task_probs}


class GraspDetector(nn.Module):
    """The detector of every model: backbone, RPN, RCNN box branch, one grasp branch and the task CRF.

    Both grasp branches share the detector, the grasp head and the losses; the attributes, and so the
    checkpoint keys, are the same: ``backbone``, ``rpn``, ``roi_heads`` (torchvision's, for the boxes),
    ``grasp_head`` and ``crf`` (None without the CRF).

    Parameters
    ----------
    backbone : str
        One of ``togcrf.model.backbone.BACKBONES``.
    crf_terms : (bool, bool) or None
        ``(use_omega, use_mu)`` of the CRF; None: no CRF.
    options : ModelOptions
    grasp_branch : {"roi", "image"}
        "roi": TOG's, on the RoIs; "image": FCGN's, on FPN map ``fcgn.level`` of the whole image.
    vocabulary : mapping, optional
        ``{"categories": [...], "tasks": [...]}``: the classes and task logits, in order (default Table I's,
        ``osgd.contract.taxonomy.VOCABULARY``); kept as :attr:`vocabulary`.
    """

    def __init__(self, backbone: str = "resnet18", crf_terms: tuple[bool, bool] | None = None,
                 options: ModelOptions | None = None, grasp_branch: str = "roi",
                 vocabulary: Mapping[str, Sequence[str]] | None = None) -> None:
        super().__init__()
        vocabulary = VOCABULARY if vocabulary is None else vocabulary
        self.vocabulary = {"categories": tuple(vocabulary["categories"]), "tasks": tuple(vocabulary["tasks"])}
        self.task_count = len(self.vocabulary["tasks"])
        self.options = options = options or ModelOptions()
        self.grasp_branch = grasp_branch
        #: Pixels per cell of the "image" branch's feature map; None for the "roi" branch.
        self.grasp_stride = image_branch_stride(grasp_branch, options)
        self.backbone = build_backbone(backbone, options.backbone)
        self.rpn = build_rpn(options)
        self.roi_heads = build_roi_heads(options, len(self.vocabulary["categories"]))
        self.grasp_head = build_grasp_head(grasp_branch, options, self.task_count)
        self.crf = None if crf_terms is None else MeanFieldCrf(
            self.task_count, use_omega=crf_terms[0], use_mu=crf_terms[1], iterations=options.crf.iterations,
            bandwidth=options.crf.bandwidth)
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
                      image_sizes: list[tuple[int, int]]) -> GraspOutputs:
        """The grasp head on RoIs (a list of (n_b, 4) boxes per image), as the "roi" branch runs it.

        Returns
        -------
        GraspOutputs
            R = all RoIs, K = 196 (7 x 7 cells, 4 angles); anchors (R, K, 5).
        """
        pooled = self.roi_heads.box_roi_pool(features, rois, image_sizes)
        regression, stability, task_logits = self.grasp_head(pooled)
        all_rois = torch.cat(rois) if rois else pooled.new_zeros((0, 4))
        anchors = roi_anchors(all_rois.float(), self.options.grasp_head.anchor_size)
        return GraspOutputs(regression, stability, self.task_log_probs(task_logits), anchors)

    def image_grasp_outputs(self, features: dict[str, torch.Tensor]) -> GraspOutputs:
        """The grasp head on FPN map ``fcgn.level`` of every image, as the "image" branch runs it.

        Returns
        -------
        GraspOutputs
            R = images, K = 4 per cell of the map; anchors (K, 5).
        """
        level = features[str(self.options.fcgn.level)]
        regression, stability, task_logits = self.grasp_head(level)
        anchors = image_anchors(level.shape[2], level.shape[3], self.grasp_stride,
                                self.options.grasp_head.anchor_size, device=level.device)
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
            ``grasp_objects`` (M,) and ``grasp_tasks`` (M,) (``togcrf.data.sample_targets``).

        Returns
        -------
        dict of scalar tensors or list of dict
            Train mode: the losses, ``LOSS_KEYS``. Eval mode, per image: ``boxes`` (N, 4), ``labels`` (N,),
            ``scores`` (N,), ``grasps`` (N, K, 5), ``grasp_stability`` (N, K), ``grasp_task_probs`` (N, K, T).
        """
        image_list = batch_images(images)
        features = self.backbone(image_list.tensors)
        if self.training:
            if targets is None:
                raise ValueError("the model is in train mode: pass targets, or call model.eval()")
            return self._training_losses(image_list, features, targets)
        proposals, _ = self.rpn(image_list, features)
        detections, _ = self.roi_heads(features, proposals, image_list.image_sizes)
        if self.grasp_branch == "image":
            return self._image_detections(features, detections)
        return self._roi_detections(features, detections, image_list.image_sizes)

    def _training_losses(self, image_list: ImageList, features: dict[str, torch.Tensor],
                         targets: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
        """RPN, RCNN box branch and grasp branch in train mode: the weighted ``LOSS_KEYS``."""
        proposals, rpn_losses = self.rpn(image_list, features, targets)
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
        """The "roi" branch in train mode: foreground RoIs, capped per image, each with the grasps of the object
        it is matched to (``togcrf.model.targets``)."""
        grasps, valid, tasks, first_object = padded_object_grasps(targets)
        rois, owners = grasp_training_rois(*sampled, first_object, self.options.grasp_head.rois_per_image)
        outputs = self.grasp_outputs(features, rois, image_sizes)
        positive, regression_targets, task_targets = match(
            outputs.anchors, torch.cat(rois).float(), grasps[owners].float(), valid[owners], tasks[owners],
            self.task_count)
        return outputs, GraspTargets(positive, regression_targets, task_targets)

    def _image_training_grasps(self, features: dict[str, torch.Tensor], targets: list[dict[str, torch.Tensor]],
                               ) -> tuple[GraspOutputs, GraspTargets]:
        """The "image" branch in train mode: every grasp of an image is a target of its cell's anchors."""
        outputs = self.image_grasp_outputs(features)
        return outputs, GraspTargets(*image_grasp_targets(targets, outputs.anchors, self.grasp_stride,
                                                               self.task_count))

    def _grasp_losses(self, outputs: GraspOutputs, targets: GraspTargets) -> dict[str, torch.Tensor]:
        """``togcrf.losses.grasp_losses`` of a branch; sets ``last_training_stats``."""
        loss = self.options.loss
        grasp = grasp_losses(outputs.stability, outputs.regression, outputs.task_log_probs, targets.positive,
                             targets.regression, targets.tasks, loss.negative_ratio, loss.ranking_weight)
        hits, rois = top1_task_hits(outputs.stability, outputs.task_log_probs, targets.positive, targets.tasks)
        self.last_training_stats = {"acc_t_hits": hits, "acc_t_rois": rois,
                                    "positive_candidates": int(targets.positive.sum())}
        return grasp

    def _roi_detections(self, features: dict[str, torch.Tensor], detections: list[dict[str, torch.Tensor]],
                        image_sizes: list[tuple[int, int]]) -> list[dict[str, torch.Tensor]]:
        """The "roi" branch in eval mode: the 196 candidates of each detected box."""
        counts = [len(detection["boxes"]) for detection in detections]
        outputs = self.grasp_outputs(features, [detection["boxes"] for detection in detections], image_sizes)
        rectangles = decode(outputs.regression.float(), outputs.anchors)
        stable = stable_probability(outputs.stability)
        task_probs = outputs.task_log_probs.exp()
        return [detection_output(detection, *per_image) for detection, *per_image in zip(
            detections, rectangles.split(counts), stable.split(counts), task_probs.split(counts), strict=True)]

    def _image_detections(self, features: dict[str, torch.Tensor],
                          detections: list[dict[str, torch.Tensor]]) -> list[dict[str, torch.Tensor]]:
        """The "image" branch in eval mode: the candidates of the whole image, given to the boxes that
        contain their centres (``togcrf.fcgn.box_candidates``)."""
        outputs = self.image_grasp_outputs(features)
        rectangles = decode(outputs.regression.float(), outputs.anchors[None])
        stable = stable_probability(outputs.stability)
        task_probs = outputs.task_log_probs.exp()
        keep = self.options.fcgn.candidates_per_box
        return [detection_output(detection, *box_candidates(
            rectangles[index], stable[index], task_probs[index], detection["boxes"].float(), keep))
            for index, detection in enumerate(detections)]
