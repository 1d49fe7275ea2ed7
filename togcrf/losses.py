"""Losses of the grasp detector (REFERENCE section 3, paper Section IV-B/C).

- stability: 2-way cross entropy over the candidates of the foreground RoIs,
  with all positives and the hardest negatives, 3 negatives per positive
  (hard negative mining as ROI-GD); optionally plus a top-1 ranking term
  (``loss.ranking_weight`` of ``togcrf.model.options``, :func:`top1_ranking_loss`);
- regression: smooth L1 on the encoded rectangles of positive candidates;
- task: cross entropy of the positive candidates' task targets against the
  log marginals ``log Q`` of the CRF (log-softmax of the task logits for TOG).

The RPN and RCNN losses are torchvision's (``togcrf.model``). ``LOSS_KEYS``
are the names of the losses every model returns in train mode, defined here
only (``togcrf.model`` and ``togcrf.train`` import them).
"""

from __future__ import annotations

import torch
from torch.nn import functional

#: Negatives kept per positive candidate (REFERENCE section 3).
DEFAULT_NEGATIVE_RATIO = 3

#: The losses of a model in train mode, in the order of the columns of metrics.csv (``togcrf.train``): RPN
#: objectness and box, RCNN class and box, then the grasp branch's (``GRASP_LOSS_KEYS``).
LOSS_KEYS = ("rpn_objectness", "rpn_box", "rcnn_class", "rcnn_box", "grasp_stability", "grasp_regression",
             "grasp_task")

#: The losses of :func:`grasp_losses`: stability, regression, task.
GRASP_LOSS_KEYS = LOSS_KEYS[4:7]


def hard_negative_selection(losses: torch.Tensor, positive: torch.Tensor, ratio: int) -> torch.Tensor:
    """Positives plus, per row, the ``ratio * positives`` negatives of highest loss.

    A row without positives keeps its ``ratio`` hardest negatives, so that RoIs
    in which no ground-truth grasp is visible still learn "not stable".

    Parameters
    ----------
    losses : (R, K) float
        Per-candidate loss.
    positive : (R, K) bool
    ratio : int

    Returns
    -------
    (R, K) bool
        Candidates that enter the loss.
    """
    negative_losses = losses.detach().masked_fill(positive, float("-inf"))
    order = negative_losses.argsort(dim=1, descending=True)
    rank = order.argsort(dim=1)
    negatives_wanted = (positive.sum(dim=1) * ratio).clamp(min=ratio)
    hard_negatives = (rank < negatives_wanted[:, None]) & ~positive
    return positive | hard_negatives


def top1_ranking_loss(stability_logits: torch.Tensor, positive: torch.Tensor) -> torch.Tensor:
    """Listwise loss of "a positive candidate ranks first", per RoI with a positive.

    The candidates of a RoI are ranked by P(stable), that is by the margin
    ``logit[stable] - logit[unstable]``; this is the cross entropy of a softmax
    over the RoI's margins against the set of its positives,
    ``logsumexp(all margins) - logsumexp(positive margins)``, averaged over the
    RoIs that have a positive. It is zero only when the positives outrank every
    negative by far, which is what mAP-G asks of the top-1 grasp. The paper
    trains the stability with the cross entropy alone; this term is ours.

    Parameters
    ----------
    stability_logits : (R, K, 2) float
        Index 1 = stable.
    positive : (R, K) bool

    Returns
    -------
    scalar tensor
        Zero (kept in the graph) when no RoI has a positive.
    """
    rows = positive.any(dim=1)
    if not bool(rows.any()):
        return stability_logits.sum() * 0
    margins = (stability_logits[..., 1] - stability_logits[..., 0])[rows].float()
    positive_margins = margins.masked_fill(~positive[rows], float("-inf"))
    return (torch.logsumexp(margins, dim=1) - torch.logsumexp(positive_margins, dim=1)).mean()


def grasp_losses(
    stability_logits: torch.Tensor,
    regression: torch.Tensor,
    task_log_probs: torch.Tensor,
    positive: torch.Tensor,
    regression_targets: torch.Tensor,
    task_targets: torch.Tensor,
    negative_ratio: int = DEFAULT_NEGATIVE_RATIO,
    ranking_weight: float = 0.0,
) -> dict[str, torch.Tensor]:
    """The three grasp losses over a batch of RoIs.

    Parameters
    ----------
    stability_logits : (R, K, 2) float
        Index 1 = stable.
    regression : (R, K, 5) float
        Encoded deltas (``togcrf.anchors.encode``).
    task_log_probs : (R, K, T) float
        ``log Q`` per candidate.
    positive : (R, K) bool
    regression_targets : (R, K, 5) float
    task_targets : (R, K, T) float
        Soft task labels of the positives (rows sum to 1).
    negative_ratio : int
    ranking_weight : float
        Weight of :func:`top1_ranking_loss`, added to the stability loss (0: the paper's loss).

    Returns
    -------
    dict of scalar tensors
        ``GRASP_LOSS_KEYS``: "grasp_stability", "grasp_regression", "grasp_task".
    """
    if positive.numel() == 0:
        zero = stability_logits.sum() * 0 + regression.sum() * 0 + task_log_probs.sum() * 0
        return dict.fromkeys(GRASP_LOSS_KEYS, zero)
    labels = positive.to(torch.int64)
    per_candidate = functional.cross_entropy(
        stability_logits.reshape(-1, 2).float(), labels.reshape(-1), reduction="none"
    ).reshape(labels.shape)
    selected = hard_negative_selection(per_candidate, positive, negative_ratio)
    stability = (per_candidate * selected).sum() / selected.sum().clamp(min=1)
    if ranking_weight:
        stability = stability + ranking_weight * top1_ranking_loss(stability_logits, positive)
    positives = positive.sum().clamp(min=1)
    regression_loss = functional.smooth_l1_loss(
        regression[positive].float(), regression_targets[positive].float(), reduction="sum", beta=1.0
    ) / positives
    task_per_candidate = -(task_targets * task_log_probs.float()).sum(dim=-1)
    task = (task_per_candidate * positive).sum() / positives
    return dict(zip(GRASP_LOSS_KEYS, (stability, regression_loss, task), strict=True))


def top1_task_hits(
    stability_logits: torch.Tensor,
    task_log_probs: torch.Tensor,
    positive: torch.Tensor,
    task_targets: torch.Tensor,
) -> tuple[int, int]:
    """Train Acc-T top-1 counts, measured on the fly on the training RoIs.

    Only RoIs with at least one positive candidate count, as Acc-T counts
    only objects with a ground-truth grasp: a RoI of an object without
    grasps, or one whose grasps lie outside it, cannot be a hit. Such a RoI
    counts as a hit when its candidate of highest stability is a positive
    candidate and its most probable task is one of the tasks of the
    ground-truth grasps it matches (a top-1 candidate that matches no grasp
    is a miss).

    Returns
    -------
    hits : int
    rois : int
        RoIs with at least one positive candidate.
    """
    if positive.numel() == 0:
        return 0, 0
    best = stability_logits.detach().softmax(dim=-1)[..., 1].argmax(dim=1)
    rows = torch.arange(best.shape[0], device=best.device)
    predicted_task = task_log_probs.detach()[rows, best].argmax(dim=-1)
    right = task_targets[rows, best, predicted_task] > 0
    hits = (positive[rows, best] & right).sum()
    return int(hits), int(positive.any(dim=1).sum())
