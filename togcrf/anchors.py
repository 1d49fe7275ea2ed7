"""Oriented grasp anchors inside a RoI, their matching to ground truth and the delta encoding.

Each RoI is divided into a ``GRID x GRID`` (7 x 7) grid of cells, the cells of
the 7 x 7 RoIAlign output (paper, Section IV-B). Every cell holds
``len(ANCHOR_ANGLES)`` (4) oriented square anchors centred on the cell, one per
angle; every anchor is one grasp candidate, so a RoI has 7 x 7 x 4 = 196
candidates. Candidate ``k`` of a RoI is cell row ``i``, column ``j`` and angle
``a`` with ``k = (i * GRID + j) * 4 + a``; the grasp head's output channels
and the CRF's positions follow the same order.

Geometry and encoding follow ROI-GD (REFERENCE section 3):

- anchors at -67.5, -22.5, 22.5, 67.5 degrees, so every grasp angle lies
  within 22.5 degrees (mod 180) of one anchor angle;
- ``dx = (x - xa) / wa``, ``dy = (y - ya) / ha``, ``dh = log(h / ha)``,
  ``dw = log(w / wa)``, ``dtheta = (theta - theta_a) / 22.5 deg``, each divided
  by ``DELTA_STD`` (0.4);
- an anchor is positive for a ground-truth grasp when the grasp centre lies in
  the anchor's cell (``|dx|, |dy| <= cell / 2``) and the angle difference
  (mod 180 degrees) is at most 22.5 degrees; with several matches the target
  is the mean of their encodings.

Our choice: the anchor square has a fixed side in pixels of the network input
(``anchor_size``, default 16 px), not a size relative to the RoI cell. Grasp
rectangles scale with the gripper opening and the finger width, not with the
size of the object's box (a long knife and a short one have the same
opening), and matching only uses the cell and the angle, so the size only
normalises the regression.

Rectangles are ``(x, y, h, w, theta)``: centre (px), opening (px), finger
width (px), angle of the closing direction to the image x axis (rad, in
``[-pi/2, pi/2)``), as in ``osgd.contract.samples.Sample.grasp_rectangles``.
"""

from __future__ import annotations

import math

import torch

#: Cells per side of a RoI: the 7 x 7 adaptive pooling of the paper (Section IV-B).
GRID = 7

#: Anchor angles, radians: -67.5, -22.5, 22.5, 67.5 degrees (REFERENCE section 3).
ANCHOR_ANGLES = tuple(math.radians(angle) for angle in (-67.5, -22.5, 22.5, 67.5))

#: Anchors per RoI: 7 x 7 cells x 4 angles.
CANDIDATES_PER_ROI = GRID * GRID * len(ANCHOR_ANGLES)

#: Angle step that normalises ``dtheta``: half the spacing of the anchor angles (22.5 degrees).
ANGLE_STEP = math.radians(22.5)

#: Every delta is divided by this, as ROI-GD does (REFERENCE section 3).
DELTA_STD = 0.4

#: Default side of the anchor square, pixels of the network input (our choice, see module docstring).
DEFAULT_ANCHOR_SIZE = 16.0


def wrap_angle(angle: torch.Tensor) -> torch.Tensor:
    """Wrap angles (rad) into ``[-pi/2, pi/2)``: a grasp rectangle is symmetric under 180 degrees."""
    return torch.remainder(angle + math.pi / 2, math.pi) - math.pi / 2


def cell_centres(grid: int = GRID) -> torch.Tensor:
    """Cell centres of the grid in RoI-normalised coordinates.

    Returns
    -------
    (grid * grid * 4, 2) float32
        ``(u, v)`` in ``(0, 1)`` for every candidate, in candidate order
        (u along the RoI's x, v along its y).
    """
    steps = (torch.arange(grid, dtype=torch.float32) + 0.5) / grid
    v, u = torch.meshgrid(steps, steps, indexing="ij")
    centres = torch.stack([u.reshape(-1), v.reshape(-1)], dim=-1)
    return centres.repeat_interleave(len(ANCHOR_ANGLES), dim=0)


def roi_anchors(rois: torch.Tensor, anchor_size: float = DEFAULT_ANCHOR_SIZE, grid: int = GRID) -> torch.Tensor:
    """The oriented anchors of every RoI.

    Parameters
    ----------
    rois : (R, 4) float
        ``x1, y1, x2, y2`` in pixels.
    anchor_size : float
        Side of the anchor square, pixels.

    Returns
    -------
    (R, grid * grid * 4, 5) float
        ``(x, y, h, w, theta)`` per candidate, in candidate order.
    """
    centres = cell_centres(grid).to(device=rois.device, dtype=rois.dtype)
    origin = rois[:, None, :2]
    size = (rois[:, None, 2:] - rois[:, None, :2]).clamp(min=1e-3)
    xy = origin + centres[None] * size
    count = centres.shape[0]
    angles = torch.tensor(ANCHOR_ANGLES, device=rois.device, dtype=rois.dtype).repeat(grid * grid)
    sides = torch.full((rois.shape[0], count, 2), float(anchor_size), device=rois.device, dtype=rois.dtype)
    return torch.cat([xy, sides, angles[None, :, None].expand(rois.shape[0], count, 1)], dim=-1)


def encode(grasps: torch.Tensor, anchors: torch.Tensor) -> torch.Tensor:
    """Regression targets of grasps relative to anchors (broadcasting).

    Parameters
    ----------
    grasps, anchors : (..., 5) float
        Rectangles ``(x, y, h, w, theta)``, pixels and radians.

    Returns
    -------
    (..., 5) float
        ``(dx, dy, dh, dw, dtheta) / DELTA_STD``.
    """
    dx = (grasps[..., 0] - anchors[..., 0]) / anchors[..., 3]
    dy = (grasps[..., 1] - anchors[..., 1]) / anchors[..., 2]
    dh = torch.log(grasps[..., 2].clamp(min=1e-3) / anchors[..., 2])
    dw = torch.log(grasps[..., 3].clamp(min=1e-3) / anchors[..., 3])
    dtheta = wrap_angle(grasps[..., 4] - anchors[..., 4]) / ANGLE_STEP
    return torch.stack([dx, dy, dh, dw, dtheta], dim=-1) / DELTA_STD


#: Clamp of log-size deltas before ``exp``, as torchvision's box coder does (log(1000 / 16)).
_MAX_LOG_SIZE = math.log(1000.0 / 16)


def decode(deltas: torch.Tensor, anchors: torch.Tensor) -> torch.Tensor:
    """Rectangles from regression outputs: the inverse of :func:`encode`.

    Parameters
    ----------
    deltas, anchors : (..., 5) float

    Returns
    -------
    (..., 5) float
        ``(x, y, h, w, theta)``, theta wrapped into ``[-pi/2, pi/2)``.
    """
    scaled = deltas * DELTA_STD
    x = anchors[..., 0] + scaled[..., 0] * anchors[..., 3]
    y = anchors[..., 1] + scaled[..., 1] * anchors[..., 2]
    h = anchors[..., 2] * torch.exp(scaled[..., 2].clamp(max=_MAX_LOG_SIZE))
    w = anchors[..., 3] * torch.exp(scaled[..., 3].clamp(max=_MAX_LOG_SIZE))
    theta = wrap_angle(anchors[..., 4] + scaled[..., 4] * ANGLE_STEP)
    return torch.stack([x, y, h, w, theta], dim=-1)


def match(
    anchors: torch.Tensor,
    rois: torch.Tensor,
    grasps: torch.Tensor,
    grasp_valid: torch.Tensor,
    grasp_tasks: torch.Tensor,
    task_count: int,
    grid: int = GRID,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Assign the ground-truth grasps of each RoI's object to its anchors.

    Parameters
    ----------
    anchors : (R, K, 5) float
        From :func:`roi_anchors`.
    rois : (R, 4) float
        The RoIs, pixels (they give the cell size).
    grasps : (R, G, 5) float
        Ground-truth rectangles of the object each RoI is matched to, padded.
    grasp_valid : (R, G) bool
        False on padding.
    grasp_tasks : (R, G) int64
        Task index of each ground-truth grasp.
    task_count : int
    grid : int
        Cells per side of the RoI.

    Returns
    -------
    positive : (R, K) bool
        Anchors that match at least one grasp.
    regression_targets : (R, K, 5) float
        Mean encoding of the matched grasps (zero where not positive).
    task_targets : (R, K, task_count) float
        Fraction of the matched grasps with each task (a soft label: one
        grasp position may be annotated with several tasks); zero where not
        positive.
    """
    matched = _near(anchors, rois, grasps, grasp_valid, grid, 0.5, ANGLE_STEP)
    weights = matched.to(anchors.dtype)
    count = weights.sum(dim=-1)
    positive = count > 0
    denominator = count.clamp(min=1.0)[..., None]
    # encode only the matched (RoI, anchor, grasp) pairs, a few hundred of the R x K x G
    roi, candidate, grasp = matched.nonzero(as_tuple=True)
    regression_targets = anchors.new_zeros(anchors.shape[0] * anchors.shape[1], 5).index_add_(
        0, roi * anchors.shape[1] + candidate, encode(grasps[roi, grasp], anchors[roi, candidate]))
    regression_targets = regression_targets.view(anchors.shape) / denominator
    one_hot = torch.nn.functional.one_hot(grasp_tasks.clamp(min=0), task_count).to(anchors.dtype)
    task_targets = torch.einsum("rkg,rgt->rkt", weights, one_hot) / denominator
    return positive, regression_targets, task_targets


def _near(anchors: torch.Tensor, rois: torch.Tensor, grasps: torch.Tensor, grasp_valid: torch.Tensor, grid: int,
          cells: float, angle: float) -> torch.Tensor:
    """(R, K, G) bool: grasp centre within ``cells`` cells of the anchor centre on both axes, angle within ``angle``."""
    cell = (rois[:, 2:] - rois[:, :2]).clamp(min=1e-3) / grid
    offset = grasps[:, None, :, :2] - anchors[:, :, None, :2]
    inside = (offset.abs() <= cell[:, None, None, :] * cells).all(dim=-1)
    angle_ok = wrap_angle(grasps[:, None, :, 4] - anchors[:, :, None, 4]).abs() <= angle + 1e-6
    return inside & angle_ok & grasp_valid[:, None, :]
