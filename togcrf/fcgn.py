"""The FCGN + Task baseline of Table II (paper, Section V-B).

FCGN (Zhou et al., "Fully convolutional grasp detection network with
oriented anchor box", IROS 2018) detects grasps with oriented anchors over
the whole image's feature map, for single objects. The paper generalises it
to stacked objects "by a simple combination with Faster-RCNN" and adds "a
task prediction layer on its feature map". Here:

- the detector part is the TOG model's (same ResNet + FPN backbone, RPN and
  RCNN head: :class:`togcrf.model.TogDetector`), so the two differ only in
  where grasps come from;
- the grasp part runs on one FPN level of the whole image (default level
  "1", stride 8 px): a 1 x 1 entry convolution, ``fcgn_blocks`` ResBlocks and
  the same regression (4 x 5), stability (4 x 2) and task (4 x 12)
  convolutions as TOG's grasp head, with 4 oriented anchors per cell
  centred on it (``togcrf.anchors``: angles, encoding, matching with the
  cell being the stride);
- training: every ground-truth grasp of the image is a target of the
  anchors of its cell within 22.5 degrees; losses as TOG's
  (``togcrf.losses``), hard negatives per image; no task CRF;
- inference: each detected box gets the candidates whose centre lies
  inside it (a candidate inside several overlapping boxes goes to each),
  the ``fcgn_candidates_per_box`` most stable of them (196 by default, as
  many as a TOG RoI has). Boxes with fewer candidates are padded to the
  image's common count K with empty rectangles (zero size, at the box
  centre) of stability 0 and uniform task probabilities, so the metrics
  never rank them above a real candidate.

The model API is that of the TOG models (docs/togcrf.md, the contract).
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, fields

import torch
from torchvision.models.detection.image_list import ImageList

from osgd.contract.taxonomy import TASKS
from togcrf.anchors import ANCHOR_ANGLES, decode, match
from togcrf.losses import grasp_losses, top1_task_hits
from togcrf.model import GraspHead, ModelOptions, TogDetector, fpn_strides

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FcgnOptions(ModelOptions):
    """Options of FCGN + Task: those of the TOG models plus the grasp part's.

    A subclass of :class:`togcrf.model.ModelOptions`, so the training code
    stores every field in checkpoints and the model is rebuilt the same.

    Attributes
    ----------
    fcgn_level : int
        FPN level the grasp part runs on: "0"-"3" are strides 4-32 px.
    fcgn_channels : int
        Channels of the grasp part's ResBlocks.
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


def image_anchors(rows: int, columns: int, stride: float, anchor_size: float,
                  device: torch.device | None = None) -> torch.Tensor:
    """Oriented anchors at every cell of a feature map.

    Parameters
    ----------
    rows, columns : int
        Feature map size.
    stride : float
        Pixels per cell.
    anchor_size : float
        Side of the anchor square, pixels.

    Returns
    -------
    (rows * columns * 4, 5) float32
        ``(x, y, h, w, theta)``; candidate ``(i * columns + j) * 4 + a`` is
        cell row ``i``, column ``j``, angle ``a`` (the grasp head's order).
    """
    ys = (torch.arange(rows, dtype=torch.float32, device=device) + 0.5) * stride
    xs = (torch.arange(columns, dtype=torch.float32, device=device) + 0.5) * stride
    grid_y, grid_x = torch.meshgrid(ys, xs, indexing="ij")
    centres = torch.stack([grid_x.reshape(-1), grid_y.reshape(-1)], dim=-1).repeat_interleave(len(ANCHOR_ANGLES), 0)
    angles = torch.tensor(ANCHOR_ANGLES, dtype=torch.float32, device=device).repeat(rows * columns)
    sides = torch.full((len(centres), 2), float(anchor_size), device=device)
    return torch.cat([centres, sides, angles[:, None]], dim=-1)


class FcgnTask(TogDetector):
    """FCGN + Task: whole-image oriented-anchor grasps and a task head, with Faster R-CNN boxes.

    Parameters
    ----------
    backbone : str
        One of ``togcrf.model.BACKBONES``.
    **options
        :class:`FcgnOptions` and :class:`togcrf.model.ModelOptions` fields.
    """

    def __init__(self, backbone: str = "resnet18", **options) -> None:
        fcgn = FcgnOptions.from_dict(options)
        super().__init__(backbone, crf_terms=None, options=fcgn)
        strides = fpn_strides(fcgn)
        if not 0 <= fcgn.fcgn_level < len(strides):
            raise ValueError(f"fcgn_level must be 0-{len(strides) - 1} (FPN strides {strides}), "
                             f"got {fcgn.fcgn_level}")
        # The TOG RoI head is replaced: FCGN predicts grasps on the whole image instead.
        self.grasp_head = GraspHead(fcgn.fpn_channels, fcgn.fcgn_channels, fcgn.norm, blocks=fcgn.fcgn_blocks,
                                    output_norm=fcgn.grasp_trunk_norm)
        self.stride = strides[fcgn.fcgn_level]

    def image_grasps(self, features: dict[str, torch.Tensor]) -> tuple[torch.Tensor, ...]:
        """Grasp outputs over the whole feature map of every image.

        Returns
        -------
        regression (B, K, 5), stability_logits (B, K, 2), task_log_probs (B, K, 12), anchors (K, 5)
        """
        level = features[str(self.options.fcgn_level)]
        regression, stability, task_logits = self.grasp_head(level)
        anchors = image_anchors(level.shape[2], level.shape[3], self.stride, self.options.grasp_anchor_size,
                                device=level.device)
        return regression, stability, self.task_log_probs(task_logits), anchors

    def _training_losses(self, image_list: ImageList, features: dict[str, torch.Tensor],
                     targets: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
        options = self.options
        proposals, rpn_losses = self.rpn(image_list, features, targets)
        detection_losses = self.roi_heads(features, proposals, image_list.image_sizes, targets)[1]
        regression, stability, task_log_probs, anchors = self.image_grasps(features)
        batch = len(targets)
        most = max(1, *(len(target["grasps"]) for target in targets))
        grasps = anchors.new_zeros((batch, most, 5))
        valid = torch.zeros((batch, most), dtype=torch.bool, device=anchors.device)
        tasks = torch.zeros((batch, most), dtype=torch.int64, device=anchors.device)
        for index, target in enumerate(targets):
            count = len(target["grasps"])
            grasps[index, :count] = target["grasps"].float()
            valid[index, :count] = True
            tasks[index, :count] = target["grasp_tasks"]
        # ``match`` takes the cell size from a RoI and a grid; one cell of side ``stride`` is that size.
        cell = anchors.new_tensor([[0.0, 0.0, self.stride, self.stride]]).expand(batch, 4)
        positive, regression_targets, task_targets = match(
            anchors[None].expand(batch, -1, -1), cell, grasps, valid, tasks, len(TASKS), grid=1)
        grasp = grasp_losses(stability, regression, task_log_probs, positive, regression_targets, task_targets,
                             options.negative_ratio)
        hits, rois = top1_task_hits(stability, task_log_probs, positive, task_targets)
        self.last_training_stats = {"acc_t_hits": hits, "acc_t_rois": rois,
                                    "positive_candidates": int(positive.sum())}
        return {
            "rpn_objectness": options.weight_rpn * rpn_losses["loss_objectness"],
            "rpn_box": options.weight_rpn * rpn_losses["loss_rpn_box_reg"],
            "rcnn_class": options.weight_rcnn * detection_losses["loss_classifier"],
            "rcnn_box": options.weight_rcnn * detection_losses["loss_box_reg"],
            "grasp_stability": options.weight_stability * grasp["grasp_stability"],
            "grasp_regression": options.weight_regression * grasp["grasp_regression"],
            "grasp_task": options.weight_task * grasp["grasp_task"],
        }

    def _detect_grasps(self, features: dict[str, torch.Tensor], detections: list[dict[str, torch.Tensor]],
                       image_sizes: list[tuple[int, int]]) -> list[dict[str, torch.Tensor]]:
        """Grasps over the whole image, each assigned to the detected boxes that contain its centre."""
        regression, stability, task_log_probs, anchors = self.image_grasps(features)
        rectangles = decode(regression.float(), anchors[None])
        stable = stability.float().softmax(dim=-1)[..., 1]
        task_probs = task_log_probs.exp()
        keep_per_box = self.options.fcgn_candidates_per_box
        results = []
        for index, detection in enumerate(detections):
            boxes = detection["boxes"].float()
            centres = rectangles[index, :, :2]
            inside = ((centres[None] >= boxes[:, None, :2]) & (centres[None] <= boxes[:, None, 2:])).all(dim=-1)
            # Most stable candidates first, those outside the box pushed behind every inside one.
            ranking = torch.where(inside, stable[index][None], stable.new_tensor(-1.0))
            count = int(inside.sum(dim=1).clamp(max=keep_per_box).max()) if len(boxes) else 0
            order = ranking.argsort(dim=1, descending=True)[:, :count]
            chosen_inside = torch.gather(inside, 1, order)
            grasps = rectangles[index][order]
            empty = torch.zeros_like(grasps)
            empty[..., :2] = ((boxes[:, :2] + boxes[:, 2:]) / 2)[:, None]
            grasps = torch.where(chosen_inside[..., None], grasps, empty)
            results.append({
                "boxes": boxes,
                "labels": detection["labels"],
                "scores": detection["scores"].float(),
                "grasps": grasps,
                "grasp_stability": torch.where(chosen_inside, stable[index][order], 0.0),
                "grasp_task_probs": torch.where(chosen_inside[..., None], task_probs[index][order],
                                                1.0 / len(TASKS)),
            })
        return results
