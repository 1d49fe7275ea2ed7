"""Grasp losses: hard negative mining and the on-the-fly train Acc-T."""

from __future__ import annotations

import math

import torch

from togcrf.losses import grasp_losses, hard_negative_selection, top1_ranking_loss, top1_task_hits


def test_mining_keeps_every_positive_and_the_hardest_negatives_of_each_row():
    generator = torch.Generator().manual_seed(0)
    losses = torch.rand((3, 40), generator=generator)
    positive = torch.zeros((3, 40), dtype=torch.bool)
    positive[0, [2, 7]] = True  # 2 positives -> 6 negatives
    positive[1, 5] = True  # 1 positive -> 3 negatives; row 2 has none -> 3 negatives
    selected = hard_negative_selection(losses, positive, ratio=3)
    assert (selected & positive).sum() == 3
    for row, wanted in enumerate((6, 3, 3)):
        negatives = selected[row] & ~positive[row]
        assert int(negatives.sum()) == wanted
        kept = losses[row][negatives]
        dropped = losses[row][~selected[row]]
        assert kept.min() >= dropped.max()


def test_train_acc_t_counts_only_rois_that_have_a_positive_candidate():
    task_count = 4
    stability = torch.zeros((3, 6, 2))
    task_log_probs = torch.full((3, 6, task_count), -5.0)
    positive = torch.zeros((3, 6), dtype=torch.bool)
    task_targets = torch.zeros((3, 6, task_count))
    # RoI 0: its most stable candidate (1) is a positive of task 2, and task 2 is its most probable: a hit
    stability[0, 1, 1] = 3.0
    positive[0, 1] = True
    task_targets[0, 1, 2] = 1.0
    task_log_probs[0, 1, 2] = 0.0
    # RoI 1: a positive (4), but its most stable candidate (0) is a negative: a miss
    stability[1, 0, 1] = 3.0
    positive[1, 4] = True
    task_targets[1, 4, 1] = 1.0
    # RoI 2: no positive candidate (an object without grasps): not counted
    stability[2, 3, 1] = 3.0
    assert top1_task_hits(stability, task_log_probs, positive, task_targets) == (1, 2)
    # the right place with the wrong most probable task is a miss
    task_log_probs[0, 1, 2] = -9.0
    assert top1_task_hits(stability, task_log_probs, positive, task_targets) == (0, 2)


def test_grasp_losses_average_over_positives_and_vanish_when_fitted():
    positive = torch.zeros((2, 8), dtype=torch.bool)
    positive[0, [1, 3]] = True
    targets = torch.randn((2, 8, 5), generator=torch.Generator().manual_seed(1))
    task_targets = torch.zeros((2, 8, 3))
    task_targets[0, 1, 0] = task_targets[0, 3, 2] = 1.0
    fitted_stability = torch.where(positive[..., None], torch.tensor([-20.0, 20.0]), torch.tensor([20.0, -20.0]))
    fitted_tasks = torch.log(task_targets.clamp(min=1e-12))
    fitted = grasp_losses(fitted_stability, targets, fitted_tasks, positive, targets, task_targets)
    assert all(float(value) < 1e-6 for value in fitted.values()), fitted
    # a regression off by 0.5 on one component of both positives costs smooth-L1(0.5) = 0.125 per positive
    shifted = targets.clone()
    shifted[..., 0] += 0.5
    off = grasp_losses(fitted_stability, shifted, fitted_tasks, positive, targets, task_targets)
    assert abs(float(off["grasp_regression"]) - 0.125) < 1e-6


def _margins_as_logits(margins: list[list[float]]) -> torch.Tensor:
    """(R, K, 2) stability logits whose stable-minus-unstable margins are ``margins``."""
    margin = torch.tensor(margins)
    return torch.stack([torch.zeros_like(margin), margin], dim=-1)


def test_top1_ranking_loss_is_the_cross_entropy_of_a_softmax_over_each_rois_candidates():
    positive = torch.tensor([[False, True, False, False], [False, False, False, False], [True, False, True, False]])
    uniform = top1_ranking_loss(_margins_as_logits([[0.0] * 4] * 3), positive)
    # equal margins: -log(1/4) for the RoI with one positive, -log(2/4) for the one with two; the RoI
    # without a positive does not count
    assert abs(float(uniform) - (math.log(4) + math.log(2)) / 2) < 1e-6
    first = top1_ranking_loss(_margins_as_logits([[0.0, 9.0, 0.0, 0.0], [0.0] * 4, [9.0, 0.0, 0.0, 0.0]]), positive)
    beaten = top1_ranking_loss(_margins_as_logits([[9.0, 0.0, 0.0, 0.0], [0.0] * 4, [0.0, 9.0, 0.0, 0.0]]),
                               positive)
    assert float(first) < 0.01
    assert float(beaten) > 5.0
    # the gradient raises the positive's margin and lowers the negative that outranks it
    logits = _margins_as_logits([[3.0, 1.0, -2.0, -2.0]]).requires_grad_()
    top1_ranking_loss(logits, positive[:1]).backward()
    margin_gradient = logits.grad[0, :, 1] - logits.grad[0, :, 0]
    assert margin_gradient[1] < 0 < margin_gradient[0]
    nothing = top1_ranking_loss(_margins_as_logits([[1.0, 2.0]]), torch.zeros((1, 2), dtype=torch.bool))
    assert float(nothing) == 0.0


def test_grasp_losses_add_the_weighted_ranking_term_to_the_stability_loss_only():
    generator = torch.Generator().manual_seed(2)
    positive = torch.zeros((3, 6), dtype=torch.bool)
    positive[0, 2] = positive[2, [0, 5]] = True
    stability = torch.randn((3, 6, 2), generator=generator)
    regression = torch.randn((3, 6, 5), generator=generator)
    task_log_probs = torch.randn((3, 6, 4), generator=generator).log_softmax(dim=-1)
    task_targets = torch.zeros((3, 6, 4))
    task_targets[..., 1] = 1.0
    arguments = (stability, regression, task_log_probs, positive, torch.zeros_like(regression), task_targets)
    plain = grasp_losses(*arguments)
    ranked = grasp_losses(*arguments, ranking_weight=0.5)
    expected = plain["grasp_stability"] + 0.5 * top1_ranking_loss(stability, positive)
    assert abs(float(ranked["grasp_stability"]) - float(expected)) < 1e-6
    assert float(ranked["grasp_stability"]) > float(plain["grasp_stability"])
    for key in ("grasp_regression", "grasp_task"):
        assert float(ranked[key]) == float(plain[key])
