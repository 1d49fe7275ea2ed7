"""Grasp losses: hard negative mining and the on-the-fly train Acc-T."""

from __future__ import annotations

import torch

from togcrf.losses import grasp_losses, hard_negative_selection, top1_task_hits


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


def test_mining_never_takes_an_ignored_candidate_as_a_negative():
    generator = torch.Generator().manual_seed(1)
    losses = torch.rand((2, 40), generator=generator)
    positive = torch.zeros((2, 40), dtype=torch.bool)
    positive[:, 0] = True
    ignored = torch.zeros((2, 40), dtype=torch.bool)
    ignored[0] = (losses[0] > losses[0].median()) & ~positive[0]  # the hardest half of row 0
    selected = hard_negative_selection(losses, positive, ratio=3, ignored=ignored)
    assert not (selected & ignored).any()
    assert (selected.sum(dim=1) == 4).all()  # the positive and 3 negatives in each row
    negatives = selected[0] & ~positive[0]
    assert losses[0][negatives].min() >= losses[0][~selected[0] & ~ignored[0] & ~positive[0]].max()


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
