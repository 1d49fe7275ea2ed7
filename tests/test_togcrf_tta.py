"""togcrf.tta: the grasp candidates averaged over flipped and turned views of the image."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from togcrf.anchors import roi_anchors
from togcrf.data import transform_angles, transform_points
from togcrf.model import build_model
from togcrf.tta import (
    VIEW_COUNTS,
    VIEWS,
    candidate_permutation,
    check_view_count,
    view_averaged_output,
    view_boxes,
    view_grasps,
    view_image,
)


@pytest.fixture(scope="module")
def model() -> torch.nn.Module:
    """An untrained TOG whose stability and task outputs vary strongly from candidate to candidate."""
    torch.manual_seed(0)
    detector = build_model("tog", "resnet18", {"grasp_head.channels": 32, "box_head.size": 128,
                                               "box_head.detections_per_image": 5, "box_head.score_threshold": 0.0})
    for layer in (detector.grasp_head.stability, detector.grasp_head.task):
        torch.nn.init.normal_(layer.weight, std=0.5)
    return detector.eval()


def test_views_are_distinct_and_each_count_is_a_group() -> None:
    assert len(set(VIEWS)) == 8 and VIEWS[0].flip_x is VIEWS[0].flip_y is False and VIEWS[0].quarter_turns == 0
    cells = np.array([[1.0, 2.0]])
    for count in VIEW_COUNTS:
        # composing two views of the first `count` gives a view among them (else the average is not symmetric)
        images = {tuple(np.rint(transform_points(transform_points(cells, (7, 7), first, 1.0), (7, 7), second, 1.0))
                        .ravel()) for first in VIEWS[:count] for second in VIEWS[:count]}
        assert len(images) == count


@pytest.mark.parametrize("view", VIEWS)
def test_a_pixel_of_the_image_moves_as_the_points_of_the_augmentation(view) -> None:
    image = torch.zeros(1, 8, 10)
    image[0, 5, 3] = 1.0  # row 5, column 3: the point x = 3, y = 5
    seen = view_image(image, view)[0]
    row, column = divmod(int(seen.argmax()), seen.shape[1])
    assert [column, row] == transform_points(np.array([[3.0, 5.0]]), (8, 10), view, 1.0).round().ravel().tolist()


@pytest.mark.parametrize("view", VIEWS)
def test_boxes_are_carried_by_their_edges(view) -> None:
    """The whole image stays the whole image; a box on the left edge lands on the right edge when mirrored."""
    whole = view_boxes(torch.tensor([[0.0, 0.0, 100.0, 80.0]]), (80, 100), view)
    assert whole.tolist() == [[0.0, 0.0, 80.0, 100.0] if view.quarter_turns % 2 else [0.0, 0.0, 100.0, 80.0]]
    left = view_boxes(torch.tensor([[0.0, 10.0, 30.0, 20.0]]), (80, 100), view)[0]
    if view == VIEWS[1]:
        assert left.tolist() == [70.0, 10.0, 100.0, 20.0]


@pytest.mark.parametrize("grid", [7, 14])
@pytest.mark.parametrize("view", VIEWS)
def test_candidates_land_on_the_anchors_of_the_carried_box(view, grid) -> None:
    """Candidate c of a box is, moved into the view, anchor perm[c] of the box carried into the view (on the
    paper's 7 x 7 cells and on a finer grid)."""
    shape = (80, 100)  # not square, so that a turn matters
    box = torch.tensor([[10.0, 20.0, 61.0, 45.0]])
    anchors = roi_anchors(box, 10.0, grid)[0].double().numpy()
    moved_anchors = roi_anchors(view_boxes(box, shape, view), 10.0, grid)[0].double().numpy()
    order = candidate_permutation(view, grid).numpy()
    assert len(order) == grid * grid * 4 and sorted(order) == list(range(len(anchors)))  # a permutation
    centres = transform_points(anchors[:, :2], (shape[0] + 1, shape[1] + 1), view, 1.0)  # edges: W - x
    np.testing.assert_allclose(moved_anchors[order, :2], centres, atol=1e-4)
    gap = np.remainder(moved_anchors[order, 4] - transform_angles(anchors[:, 4], view) + math.pi / 2, math.pi)
    np.testing.assert_allclose(gap - math.pi / 2, 0.0, atol=1e-6)
    if view.quarter_turns % 2 == 0:  # a turn swaps the rectangle's sides with the box's
        np.testing.assert_allclose(moved_anchors[order, 2:4], anchors[:, 2:4], atol=1e-4)


def test_the_average_over_all_views_does_not_depend_on_the_view_given(model) -> None:
    """The average over a group of views, of an image and of its mirror, agree candidate by candidate."""
    torch.manual_seed(1)
    image = torch.rand(1, 64, 64)
    boxes = torch.tensor([[5.0, 8.0, 40.0, 30.0], [20.0, 22.0, 60.0, 63.0]])

    def average(picture: torch.Tensor, rois: torch.Tensor) -> torch.Tensor:
        with torch.inference_mode():
            return torch.stack([view_grasps(model, picture, rois, view)[0] for view in VIEWS]).mean(dim=0)

    given = average(image, boxes)
    for view in VIEWS[1:]:
        seen = average(view_image(image, view), view_boxes(boxes, (64, 64), view))
        torch.testing.assert_close(seen[:, candidate_permutation(view)], given, atol=2e-6, rtol=0)
    assert given.std() > 0.05  # the candidates differ, so a wrong order would show


def test_averaged_output_keeps_the_boxes_and_averages_the_candidates(model) -> None:
    torch.manual_seed(2)
    image = torch.rand(1, 64, 64)
    with torch.inference_mode():
        plain = model([image])[0]
        assert len(plain["boxes"]) > 0
        one = view_averaged_output(model, image, 1)
        two = view_averaged_output(model, image, 2)
        mirrored, mirrored_tasks = view_grasps(model, image, plain["boxes"], VIEWS[1])
        identity, _ = view_grasps(model, image, plain["boxes"], VIEWS[0])
    for key in ("boxes", "scores", "labels", "grasps", "grasp_stability"):
        torch.testing.assert_close(one[key], plain[key])
    for key in ("boxes", "scores", "labels", "grasps"):
        torch.testing.assert_close(two[key], plain[key])
    torch.testing.assert_close(identity, plain["grasp_stability"])
    torch.testing.assert_close(two["grasp_stability"], (plain["grasp_stability"] + mirrored) / 2)
    torch.testing.assert_close(two["grasp_task_probs"], (plain["grasp_task_probs"] + mirrored_tasks) / 2)
    assert not torch.allclose(two["grasp_stability"], plain["grasp_stability"])


def test_views_are_checked() -> None:
    for count in (0, 3, 16):
        with pytest.raises(ValueError, match="expected one of 1, 2, 4, 8"):
            check_view_count(count)
    fcgn = build_model("fcgn-task", "resnet18").eval()
    with pytest.raises(ValueError, match="roi"), torch.inference_mode():
        view_averaged_output(fcgn, torch.rand(1, 64, 64), 2)
