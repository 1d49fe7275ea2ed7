"""The grasp head (paper, Section IV-B): 3 ResBlocks, then the regression, stability and task convolutions.

Input (R, C, H, W) features: pooled RoIs, 7 x 7 (the "roi" branch of TOG and TOG-CRFs), or whole FPN
maps (the "image" branch of FCGN + Task). Outputs per candidate, 4 per cell, cell (i, j) angle a being
candidate (i * W + j) * 4 + a (the order of ``togcrf.anchors``): regression (R, H * W * 4, 5), stability
logits (R, H * W * 4, 2), task logits (R, H * W * 4, T) for the vocabulary's T tasks: 196 candidates per RoI.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import nn
from torch.nn import functional

from togcrf.anchors import ANCHOR_ANGLES
from togcrf.model.backbone import norm_layer
from togcrf.model.options import ModelOptions


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
    """

    regression: torch.Tensor
    stability: torch.Tensor
    task_log_probs: torch.Tensor
    anchors: torch.Tensor


def stable_probability(stability: torch.Tensor) -> torch.Tensor:
    """P(stable) of each candidate, the key that ranks a RoI's candidates: (R, K, 2) logits -> (R, K) float32."""
    return stability.float().softmax(dim=-1)[..., 1]


class GraspHead(nn.Module):
    """3 ResBlocks (``blocks``) and the regression, stability and task convolutions (see the module docstring)."""

    def __init__(self, in_channels: int, channels: int, norm: str, task_count: int,
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
        # channel a * width + d of cell (i, j) -> candidate (i * W + j) * 4 + a, component d
        rois, _, rows, columns = output.shape
        return output.permute(0, 2, 3, 1).reshape(rois, rows * columns * self.anchors, width)

    def forward(self, pooled: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Regression (R, K, 5), stability logits (R, K, 2) and task logits (R, K, T) per candidate."""
        features = self.blocks(self.entry(pooled))
        # the stability first: the order the three outputs are made in is the order autograd sums their
        # gradients into ``features``, and the recorded training trace (tests/test_training_trace.py) has it so
        stability = self._per_candidate(self.stability(features), 2)
        return self._per_candidate(self.regression(features), 5), stability, self._per_candidate(
            self.task(features), self.task_count)


def build_grasp_head(grasp_branch: str, options: ModelOptions, task_count: int) -> GraspHead:
    """The grasp head of a branch: 3 ResBlocks of ``grasp_head.channels`` ("roi") or ``fcgn.blocks`` of
    ``fcgn.channels`` ("image"), ``task_count`` task logits per candidate."""
    norm, trunk_norm = options.backbone.norm, options.grasp_head.trunk_norm
    if grasp_branch == "image":
        return GraspHead(options.backbone.fpn_channels, options.fcgn.channels, norm, task_count,
                         blocks=options.fcgn.blocks, output_norm=trunk_norm)
    return GraspHead(options.backbone.fpn_channels, options.grasp_head.channels, norm, task_count,
                     output_norm=trunk_norm)
