"""The FCGN + Task baseline of Table II (paper, Section V-B).

FCGN (Zhou et al., "Fully convolutional grasp detection network with
oriented anchor box", IROS 2018) detects grasps with oriented anchors over
the whole image's feature map, for single objects. The paper generalises it
to stacked objects "by a simple combination with Faster-RCNN" and adds "a
task prediction layer on its feature map". Here:

- the model is the TOG models' detector, :class:`togcrf.model.GraspDetector`
  (same ResNet + FPN backbone, RPN and RCNN head), with its "image" grasp
  branch in place of TOG's "roi" branch, so the two differ only in where
  grasps come from;
- the grasp branch runs on one FPN level of the whole image (default level
  "1", stride 8 px): a 1 x 1 entry convolution, ``fcgn_blocks`` ResBlocks and
  the same regression (4 x 5), stability (4 x 2) and task (4 x T)
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
This module holds the branch's own parts (anchors over the image, training
targets, candidates of each box), which :class:`togcrf.model.GraspDetector`
composes; it imports nothing from ``togcrf.model``. The model is
``togcrf.model.build_model("fcgn-task")``, its options
:class:`togcrf.model.options.FcgnOptions` (the ``fcgn`` option group).
"""

from __future__ import annotations

import torch

from togcrf.anchors import ANCHOR_ANGLES, match


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


def image_grasp_targets(targets: list[dict[str, torch.Tensor]], anchors: torch.Tensor,
                        stride: float, task_count: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Training targets of the candidates of every image: each ground-truth grasp of an image is a target
    of the anchors of its cell within 22.5 degrees.

    Parameters
    ----------
    targets : list of dict
        Per image, ``grasps`` (M, 5) and ``grasp_tasks`` (M,) int64.
    anchors : (K, 5) float32
        :func:`image_anchors` of the feature map.
    stride : float
        Pixels per cell.
    task_count : int
        Task labels of the vocabulary.

    Returns
    -------
    positive : (B, K) bool
    regression_targets : (B, K, 5) float32
    task_targets : (B, K, T) float32
        As :func:`togcrf.anchors.match`.
    """
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
    cell = anchors.new_tensor([[0.0, 0.0, stride, stride]]).expand(batch, 4)
    return match(anchors[None].expand(batch, -1, -1), cell, grasps, valid, tasks, task_count, grid=1)


def box_candidates(rectangles: torch.Tensor, stable: torch.Tensor, task_probs: torch.Tensor, boxes: torch.Tensor,
                   keep: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One image's candidates given to its detected boxes: the ``keep`` most stable whose centre lies inside.

    A candidate inside several boxes goes to each. Boxes with fewer than the
    most (C) are padded with empty rectangles (zero size, at the box centre)
    of stability 0 and uniform task probabilities.

    Parameters
    ----------
    rectangles : (K, 5) float
        Decoded candidates of the whole image, ``(x, y, h, w, theta)``.
    stable : (K,) float
        P(stable).
    task_probs : (K, T) float
    boxes : (N, 4) float
        ``(x1, y1, x2, y2)``.
    keep : int
        Most candidates per box.

    Returns
    -------
    grasps : (N, C, 5) float
        Most stable first; C = the most candidates inside one box, at most ``keep``.
    stability : (N, C) float
    task_probs : (N, C, T) float
    """
    centres = rectangles[:, :2]
    inside = ((centres[None] >= boxes[:, None, :2]) & (centres[None] <= boxes[:, None, 2:])).all(dim=-1)
    # Most stable candidates first, those outside the box pushed behind every inside one.
    ranking = torch.where(inside, stable[None], stable.new_tensor(-1.0))
    count = int(inside.sum(dim=1).clamp(max=keep).max()) if len(boxes) else 0
    order = ranking.argsort(dim=1, descending=True)[:, :count]
    chosen_inside = torch.gather(inside, 1, order)
    grasps = rectangles[order]
    empty = torch.zeros_like(grasps)
    empty[..., :2] = ((boxes[:, :2] + boxes[:, 2:]) / 2)[:, None]
    return (torch.where(chosen_inside[..., None], grasps, empty),
            torch.where(chosen_inside, stable[order], 0.0),
            torch.where(chosen_inside[..., None], task_probs[order], 1.0 / task_probs.shape[-1]))
