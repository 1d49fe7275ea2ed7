"""Test-time views: the grasp candidates of each detection averaged over flipped and turned copies of the image.

The detector is trained on images flipped and turned by quarter turns
(:class:`togcrf.data.Augmentation`), so each of the eight views of an image
(the identity, the two mirrors, both, and the same four after one quarter
turn) is an input it knows. :func:`view_averaged_output` detects the boxes
once, on the image as given, then runs the backbone and the grasp head of
the "roi" branch on every other view with the boxes carried into that view,
and averages each candidate's P(stable) and task probabilities over the
views. The 7 x 7 cells and 4 anchor angles of a RoI map onto those of the
carried box exactly (:func:`candidate_permutation`), so the average is taken
candidate by candidate. Boxes, scores and the candidates' rectangles stay
those of the image as given: only the choice of the top-1 grasp and the
task probabilities change.

It is test-time augmentation as detection toolkits offer it (e.g.
MMDetection's ``TestTimeAugmentation`` of flips); here it is applied to the
grasp head only. Each view costs one more backbone and grasp-head pass:
eight views take about five times the time of one (the RPN and the box
branch run once).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import torch

from togcrf.anchors import ANCHOR_ANGLES, GRID
from togcrf.data import Augmentation, transform_angles, transform_points
from togcrf.model import batch_images, stable_probability

#: The views, in the order they are added: the identity, mirror x, mirror y, both, then the same after a turn.
VIEWS = tuple(Augmentation(flip_x=flip_x, flip_y=flip_y, quarter_turns=turns)
              for turns in (0, 1) for flip_x, flip_y in ((False, False), (True, False), (False, True), (True, True)))

#: How many views may be averaged: the first 1, 2, 4 or 8 of ``VIEWS`` (each a group of symmetries).
VIEW_COUNTS = (1, 2, 4, 8)


def check_view_count(views: int) -> None:
    """Raise ValueError unless ``views`` is one of ``VIEW_COUNTS``."""
    if views not in VIEW_COUNTS:
        raise ValueError(f"test-time views: {views} is not allowed; expected one of "
                         f"{', '.join(map(str, VIEW_COUNTS))} (1 = the image as given)")


def views_label(views: int) -> str:
    """What names a row or policy run with test-time views: `` [8 views]``, or nothing for 1 view."""
    return f" [{views} views]" if views > 1 else ""


def view_image(image: torch.Tensor, view: Augmentation) -> torch.Tensor:
    """The ``(..., H, W)`` image seen in a view: the pixel permutation of :func:`togcrf.data.augment`."""
    if view.flip_x:
        image = torch.flip(image, dims=(-1,))
    if view.flip_y:
        image = torch.flip(image, dims=(-2,))
    return torch.rot90(image, view.quarter_turns % 4, dims=(-2, -1))


def view_boxes(boxes: torch.Tensor, shape: tuple[int, int], view: Augmentation) -> torch.Tensor:
    """``(N, 4)`` boxes ``x1, y1, x2, y2`` of an image of ``shape`` (H, W), carried into a view.

    A box's edges lie on the (H + 1) x (W + 1) lattice of pixel corners, the
    frame RoIAlign samples in: a mirror maps an edge ``x`` to ``W - x``
    (a pixel centre ``x`` goes to ``W - 1 - x``, :func:`togcrf.data.transform_points`).
    Carried as pixel centres instead, the boxes would sit 1 px off in the
    mirrored views.
    """
    height, width = shape
    corners = torch.cat([boxes[:, :2], boxes[:, 2:]]).double().cpu().numpy()
    moved = torch.from_numpy(transform_points(corners, (height + 1, width + 1), view, 1.0)).reshape(2, -1, 2)
    return torch.cat([moved.amin(dim=0), moved.amax(dim=0)], dim=1).to(boxes)


@lru_cache(maxsize=4 * len(VIEWS))
def candidate_permutation(view: Augmentation, grid: int = GRID) -> torch.Tensor:
    """``(grid * grid * 4,)`` long (196 on the paper's 7 x 7 cells): entry ``c`` is the index, in a view's RoI,
    of candidate ``c`` of the RoI as given (computed once per view and grid; callers must not modify it).

    Candidate ``(i * grid + j) * 4 + a`` is cell row i, column j, anchor angle a
    (:mod:`togcrf.anchors`). The cells move as the pixels of a grid x grid image
    (:func:`togcrf.data.transform_points`), the angles as grasp angles
    (:func:`togcrf.data.transform_angles`); both anchor sets are symmetric
    under the views, so every candidate lands on one.
    """
    rows, columns = np.meshgrid(np.arange(grid), np.arange(grid), indexing="ij")
    cells = np.stack([columns.ravel(), rows.ravel()], axis=1).astype(np.float64)
    moved = np.rint(transform_points(cells, (grid, grid), view, 1.0)).astype(np.int64)
    angles = np.asarray(ANCHOR_ANGLES)
    turned = transform_angles(angles, view)
    gap = np.abs(np.remainder(turned[:, None] - angles[None, :] + np.pi / 2, np.pi) - np.pi / 2)
    anchor = gap.argmin(axis=1)
    cell = moved[:, 1] * grid + moved[:, 0]
    return torch.from_numpy((cell[:, None] * len(angles) + anchor[None, :]).ravel())


def view_grasps(model: torch.nn.Module, image: torch.Tensor, boxes: torch.Tensor, view: Augmentation,
                ) -> tuple[torch.Tensor, torch.Tensor]:
    """P(stable) ``(N, K)`` and task probabilities ``(N, K, T)`` (K = 196 on 7 x 7 cells) of ``(N, 4)`` boxes
    seen in one view, in the candidate order of the image as given."""
    seen = view_image(image, view)
    images = batch_images([seen])
    features = model.backbone(images.tensors)
    outputs = model.grasp_outputs(features, [view_boxes(boxes, tuple(image.shape[-2:]), view)], images.image_sizes)
    order = candidate_permutation(view).to(boxes.device)
    stable = stable_probability(outputs.stability)
    return stable[:, order], outputs.task_log_probs.exp()[:, order]


def view_averaged_output(model: torch.nn.Module, image: torch.Tensor, views: int) -> dict[str, torch.Tensor]:
    """One image's model output (eval mode, the contract of ``togcrf.model``) with the candidates' P(stable)
    and task probabilities averaged over the first ``views`` of ``VIEWS``.

    Parameters
    ----------
    model : GraspDetector
        With the "roi" grasp branch (TOG, TOG-CRFs), in eval mode.
    image : (1, H, W) float
        The network input.
    views : int
        One of ``VIEW_COUNTS``; 1 gives the model's own output.

    Raises
    ------
    ValueError
        If ``views`` is not allowed, or the model has the "image" grasp branch (FCGN + Task).
    """
    check_view_count(views)
    if views > 1 and model.grasp_branch != "roi":
        raise ValueError("test-time views need the \"roi\" grasp branch (TOG, TOG-CRFs); FCGN + Task has none")
    output = model([image])[0]
    if views == 1 or len(output["boxes"]) == 0:
        return output
    stable, tasks = output["grasp_stability"].double(), output["grasp_task_probs"].double()
    for view in VIEWS[1:views]:
        view_stable, view_tasks = view_grasps(model, image, output["boxes"], view)
        stable, tasks = stable + view_stable.double(), tasks + view_tasks.double()
    return {**output, "grasp_stability": (stable / views).float(), "grasp_task_probs": (tasks / views).float()}
