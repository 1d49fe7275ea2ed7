"""Training targets of the grasp branches: each object's ground-truth grasps, and the RoIs that train the head.

During training the "roi" grasp head runs on up to ``grasp_head.rois_per_image`` of the RCNN's sampled
foreground RoIs (ground-truth boxes plus proposals with IoU >= 0.5), each taking its grasp targets from
the object it is matched to; ``togcrf.anchors.match`` assigns them to the candidates.
"""

from __future__ import annotations

from typing import NamedTuple

import torch


class GraspTargets(NamedTuple):
    """Training targets of a grasp branch's candidates (``togcrf.anchors.match``).

    Attributes
    ----------
    positive : (R, K) bool
    regression : (R, K, 5) float
    tasks : (R, K, T) float
        Soft task labels of the positives.
    """

    positive: torch.Tensor
    regression: torch.Tensor
    tasks: torch.Tensor


def padded_object_grasps(targets: list[dict[str, torch.Tensor]],
                         ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
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
