"""The Table II metrics on hand-made cases with known answers and against references."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from osgd.contract.taxonomy import CATEGORY_INDEX, TASK_INDEX, TASKS
from togcrf.geometry import angle_difference, box_iou, grasp_match_matrix, rectangle_corners, rectangle_jaccard
from togcrf.metrics import (
    Detections,
    GroundTruth,
    TableTwoEvaluator,
    average_precision,
    match_detections,
    right_tasks,
)


def rasterised_jaccard(first: np.ndarray, second: np.ndarray, step: float = 0.05) -> float:
    """Jaccard of two rectangles by counting grid points inside each (half-plane tests)."""
    corners = np.concatenate([rectangle_corners(first), rectangle_corners(second)])
    low, high = corners.min(axis=0) - 1, corners.max(axis=0) + 1
    xs, ys = np.meshgrid(np.arange(low[0], high[0], step), np.arange(low[1], high[1], step))
    points = np.stack([xs.ravel(), ys.ravel()], axis=-1)

    def inside(rectangle: np.ndarray) -> np.ndarray:
        x, y, opening, width, theta = rectangle
        offset = points - [x, y]
        along = offset @ [np.cos(theta), np.sin(theta)]
        across = offset @ [-np.sin(theta), np.cos(theta)]
        return (np.abs(along) <= opening / 2) & (np.abs(across) <= width / 2)

    a, b = inside(first), inside(second)
    return float((a & b).sum() / max((a | b).sum(), 1))


def test_corners_span_opening_along_theta() -> None:
    corners = rectangle_corners(np.array([10.0, 20.0, 8.0, 2.0, np.pi / 2]))
    # Closing direction along image y: the opening (8) spans y, the finger width (2) spans x.
    assert np.ptp(corners[:, 1]) == pytest.approx(8.0)
    assert np.ptp(corners[:, 0]) == pytest.approx(2.0)
    assert corners.mean(axis=0) == pytest.approx([10.0, 20.0])


def test_jaccard_known_cases() -> None:
    base = np.array([[0.0, 0.0, 10.0, 4.0, 0.0]])
    shifted = np.array([[5.0, 0.0, 10.0, 4.0, 0.0]])  # overlap 5 x 4 = 20, union 60
    flipped = np.array([[0.0, 0.0, 10.0, 4.0, np.pi]])
    far = np.array([[50.0, 0.0, 10.0, 4.0, 0.0]])
    assert rectangle_jaccard(base, base)[0, 0] == pytest.approx(1.0)
    assert rectangle_jaccard(base, shifted)[0, 0] == pytest.approx(1 / 3)
    assert rectangle_jaccard(base, flipped)[0, 0] == pytest.approx(1.0)
    assert rectangle_jaccard(base, far)[0, 0] == 0.0
    assert rectangle_jaccard(base, np.zeros((0, 5))).shape == (1, 0)


def test_jaccard_matches_rasterised_reference() -> None:
    rng = np.random.default_rng(3)
    first = np.column_stack([rng.uniform(0, 6, 12), rng.uniform(0, 6, 12), rng.uniform(6, 20, 12),
                             rng.uniform(2, 8, 12), rng.uniform(-np.pi / 2, np.pi / 2, 12)])
    second = np.column_stack([rng.uniform(0, 6, 12), rng.uniform(0, 6, 12), rng.uniform(6, 20, 12),
                              rng.uniform(2, 8, 12), rng.uniform(-np.pi / 2, np.pi / 2, 12)])
    exact = rectangle_jaccard(first, second)
    assert exact.shape == (12, 12)
    for index in range(12):
        reference = rasterised_jaccard(first[index], second[index])
        assert exact[index, index] == pytest.approx(reference, abs=0.01)
    assert np.any(exact[np.arange(12), np.arange(12)] > 0.1)  # the test is not all-disjoint


def test_angle_difference_wraps_at_180_degrees() -> None:
    assert angle_difference(np.deg2rad(89.0), np.deg2rad(-89.0)) == pytest.approx(np.deg2rad(2.0))
    assert angle_difference(np.deg2rad(10.0), np.deg2rad(190.0)) == pytest.approx(0.0, abs=1e-12)
    assert angle_difference(np.deg2rad(0.0), np.deg2rad(90.0)) == pytest.approx(np.pi / 2)
    assert angle_difference(np.deg2rad(-80.0), np.deg2rad(70.0)) == pytest.approx(np.deg2rad(30.0))


def test_grasp_match_across_the_angle_wrap() -> None:
    truth = np.array([[50.0, 50.0, 20.0, 8.0, np.deg2rad(-88.0)]])
    detected = np.array([[51.0, 50.0, 20.0, 8.0, np.deg2rad(87.0)]])  # 5 degrees apart modulo 180
    assert grasp_match_matrix(detected, truth)[0, 0]


def test_grasp_that_matches_by_angle_but_not_by_jaccard() -> None:
    truth = np.array([[50.0, 50.0, 20.0, 8.0, 0.3]])
    detected = np.array([[50.0, 58.0, 20.0, 8.0, 0.3]])  # same angle, moved across by a finger width
    assert rectangle_jaccard(detected, truth)[0, 0] < 0.25
    assert angle_difference(detected[0, 4], truth[0, 4]) == 0.0
    assert not grasp_match_matrix(detected, truth)[0, 0]


def test_grasp_that_matches_by_jaccard_but_not_by_angle() -> None:
    truth = np.array([[50.0, 50.0, 12.0, 12.0, 0.0]])
    detected = np.array([[50.0, 50.0, 12.0, 12.0, np.deg2rad(35.0)]])
    assert rectangle_jaccard(detected, truth)[0, 0] > 0.5
    assert not grasp_match_matrix(detected, truth)[0, 0]
    turned = detected.copy()
    turned[0, 4] = np.deg2rad(25.0)
    assert grasp_match_matrix(turned, truth)[0, 0]


def test_box_iou_known_values() -> None:
    iou = box_iou(np.array([[0, 0, 10, 10]]), np.array([[0, 0, 10, 10], [5, 0, 15, 10], [20, 20, 30, 30]]))
    assert iou[0] == pytest.approx([1.0, 1 / 3, 0.0])


def test_average_precision_hand_computed() -> None:
    # 3 objects; ranked hits: TP, FP, TP -> recall 1/3, 1/3, 2/3; precision 1, 1/2, 2/3.
    ap = average_precision(np.array([0.9, 0.8, 0.7]), np.array([True, False, True]), 3)
    assert ap == pytest.approx(1 / 3 * 1.0 + 1 / 3 * 2 / 3)
    # The envelope: a later, higher precision lifts an earlier dip.
    ap = average_precision(np.array([0.9, 0.8, 0.7, 0.6]), np.array([False, True, True, True]), 3)
    assert ap == pytest.approx(3 / 4)
    assert average_precision(np.array([0.5]), np.array([True]), 1) == pytest.approx(1.0)
    assert average_precision(np.zeros(0), np.zeros(0, dtype=bool), 2) == 0.0
    assert np.isnan(average_precision(np.array([0.5]), np.array([False]), 0))


def test_match_detections_greedy_by_score_and_class() -> None:
    truth_boxes = np.array([[0, 0, 10, 10], [20, 0, 30, 10]], dtype=float)
    truth_categories = np.array([0, 1])
    boxes = np.array([[0, 0, 10, 10], [1, 0, 10, 10], [20, 0, 30, 10], [20, 0, 30, 10]], dtype=float)
    categories = np.array([0, 0, 0, 1])
    scores = np.array([0.5, 0.9, 0.8, 0.1])
    matched = match_detections(boxes, categories, scores, truth_boxes, truth_categories)
    # The higher-scored duplicate claims object 0; the wrong class on object 1 is a false positive.
    assert matched.tolist() == [-1, 0, -1, 1]


def _two_object_scene() -> GroundTruth:
    """A knife (grasps: 'cut' on the left half, 'hand over' on the right) and a screwdriver."""
    cut, hand_over, screw = TASK_INDEX["cut"], TASK_INDEX["hand over"], TASK_INDEX["screw"]
    grasps = np.array([[20, 20, 12, 4, np.pi / 2], [30, 20, 12, 4, np.pi / 2],
                       [60, 20, 12, 4, np.pi / 2], [70, 20, 12, 4, np.pi / 2],
                       [40, 80, 12, 4, 0.0]], dtype=float)
    return GroundTruth(
        boxes=np.array([[10, 14, 80, 26], [34, 60, 46, 100]], dtype=float),
        categories=np.array([CATEGORY_INDEX["knife"], CATEGORY_INDEX["screwdriver"]]),
        grasp_rectangles=grasps, grasp_objects=np.array([0, 0, 0, 0, 1]),
        grasp_tasks=np.array([cut, cut, hand_over, hand_over, screw]))


def _one_hot(task_names: list[str]) -> np.ndarray:
    probabilities = np.full((len(task_names), len(TASKS)), 0.01)
    for row, name in enumerate(task_names):
        probabilities[row, TASK_INDEX[name]] = 0.9
    return probabilities


def test_table_two_on_a_hand_made_scene() -> None:
    truth = _two_object_scene()
    knife_candidates = np.array([[20, 20, 12, 4, np.pi / 2], [61, 20, 12, 4, np.pi / 2],
                                 [30, 20, 12, 4, np.pi / 2], [70, 20, 12, 4, np.pi / 2]], dtype=float)
    knife_tasks = _one_hot(["cut", "hand over", "cut", "cut"])  # the 4th (lowest stability) is wrong
    # The screwdriver's top grasp has the right angle but lies 10 px off: no Jaccard match.
    screw_candidates = np.array([[40, 70, 12, 4, 0.0], [40, 80, 12, 4, 0.0], [0, 0, 4, 4, 0.0],
                                 [0, 0, 4, 4, 0.0]], dtype=float)
    screw_tasks = _one_hot(["screw", "screw", "screw", "screw"])
    detections = Detections(
        boxes=truth.boxes.copy(), categories=truth.categories.copy(), scores=np.array([0.9, 0.8]),
        grasps=np.stack([knife_candidates, screw_candidates]),
        grasp_stability=np.array([[0.9, 0.8, 0.7, 0.6], [0.9, 0.5, 0.4, 0.3]]),
        grasp_task_probs=np.stack([knife_tasks, screw_tasks]))
    evaluator = TableTwoEvaluator(top_k=(1, 3, 4))
    evaluator.add(detections, truth)
    result = evaluator.result()
    assert result["mAP"] == pytest.approx(1.0)
    assert result["mAP-G"] == pytest.approx(0.5)  # knife AP-G 1, screwdriver AP-G 0
    assert result["AP-G"] == {"knife": pytest.approx(1.0), "screwdriver": pytest.approx(0.0)}
    # top1: both right; top3: both right (the screwdriver's far candidates fall back to the
    # nearest ground truth, 'screw'); top4: the knife's 4th says 'cut' on the 'hand over' half.
    assert result["Acc-T top1"] == pytest.approx(1.0)
    assert result["Acc-T top3"] == pytest.approx(1.0)
    assert result["Acc-T top4"] == pytest.approx(0.5)
    assert result["rois"] == 2

    strict = TableTwoEvaluator(top_k=(1, 3), unmatched_task="wrong")
    strict.add(detections, truth)
    # Strictly, the screwdriver's top-1 candidate matches no ground-truth grasp: wrong.
    assert strict.result()["Acc-T top1"] == pytest.approx(0.5)


def test_acc_t_by_crowding_uses_the_mask_of_the_other_objects() -> None:
    """The knife's box is a third covered by the screwdriver's pixels; the screwdriver's box not at all."""
    base = _two_object_scene()
    boxes = np.array([[10, 14, 79, 25], [34, 60, 45, 99]], dtype=float)  # inclusive ends, as the contract's
    mask = np.zeros((120, 100), dtype=np.uint8)
    mask[14:26, 10:80] = 4                      # the knife (object index 3)
    mask[14:18, 10:80] = 7                      # the screwdriver (object index 6) lying over its upper third
    mask[60:100, 34:46] = 7
    truth = GroundTruth(boxes, base.categories, base.grasp_rectangles, base.grasp_objects, base.grasp_tasks,
                        mask, np.array([4, 7]))
    assert truth.other_objects_share(0) == pytest.approx(4 / 12)
    assert truth.other_objects_share(1) == 0.0
    outside = GroundTruth(np.array([[500.0, 500.0, 510.0, 510.0]]), base.categories[:1], base.grasp_rectangles[:0],
                          base.grasp_objects[:0], base.grasp_tasks[:0], mask, np.array([4]))
    assert np.isnan(outside.other_objects_share(0))
    knife = _one_hot(["hand over"])              # wrong at the top-1: the candidate is on the 'cut' half
    screw = _one_hot(["screw"])
    detections = Detections(
        boxes=boxes + 0.5, categories=base.categories.copy(), scores=np.array([0.9, 0.8]),
        grasps=np.array([[[20, 20, 12, 4, np.pi / 2]], [[40, 80, 12, 4, 0.0]]], dtype=float),
        grasp_stability=np.array([[0.9], [0.9]]), grasp_task_probs=np.stack([knife, screw]))
    evaluator = TableTwoEvaluator(top_k=(1,))
    evaluator.add(detections, truth)
    result = evaluator.result()
    by_cover = result["Acc-T by other objects' share"]
    assert by_cover["0.00-0.05"] == {"rois": 1, "Acc-T top1": 1.0}
    assert by_cover[">=0.30"] == {"rois": 1, "Acc-T top1": 0.0}
    assert by_cover["0.05-0.15"]["rois"] == 0
    assert result["Acc-T by objects in the image"] == {"2": {"rois": 2, "Acc-T top1": 0.5}}
    without_mask = TableTwoEvaluator(top_k=(1,))
    without_mask.add(detections, GroundTruth(boxes, base.categories, base.grasp_rectangles, base.grasp_objects,
                                             base.grasp_tasks))
    assert without_mask.result()["Acc-T by other objects' share"] == {}


def test_false_positive_and_missed_object_lower_map() -> None:
    truth = _two_object_scene()
    knife_only = Detections(
        boxes=np.array([[10, 14, 80, 26], [200, 200, 210, 210]], dtype=float),
        categories=np.array([CATEGORY_INDEX["knife"], CATEGORY_INDEX["knife"]]), scores=np.array([0.3, 0.9]),
        grasps=np.zeros((2, 0, 5)), grasp_stability=np.zeros((2, 0)), grasp_task_probs=np.zeros((2, 0, 12)))
    evaluator = TableTwoEvaluator()
    evaluator.add(knife_only, truth)
    result = evaluator.result()
    # knife: FP (0.9) then TP (0.3): AP 1/2; screwdriver missed: AP 0.
    assert result["AP"]["knife"] == pytest.approx(0.5)
    assert result["mAP"] == pytest.approx(0.25)
    assert result["mAP-G"] == 0.0  # no grasp candidates at all
    assert result["Acc-T top1"] == 0.0  # the matched knife RoI has no candidate


def test_right_tasks_prefers_matching_grasps_over_nearer_ones() -> None:
    object_grasps = np.array([[10, 10, 12, 4, 0.0], [14, 10, 12, 4, np.pi / 2]], dtype=float)
    tasks = np.array([TASK_INDEX["cut"], TASK_INDEX["hand over"]])
    # Nearer to the second grasp in position but matching only the first by angle and overlap.
    candidate = np.array([[13, 10, 12, 4, 0.0]])
    assert right_tasks(candidate, object_grasps, tasks) == [{TASK_INDEX["cut"]}]


@pytest.mark.skipif(importlib.util.find_spec("torchmetrics") is None
                    or importlib.util.find_spec("pycocotools") is None,
                    reason="torchmetrics and pycocotools (dev dependencies) are not installed")
def test_map_agrees_with_torchmetrics_on_random_boxes() -> None:
    import torch  # noqa: PLC0415
    from torchmetrics.detection import MeanAveragePrecision  # noqa: PLC0415

    rng = np.random.default_rng(11)
    # All-point AP equals COCO's interpolated AP in the limit of fine recall thresholds.
    reference = MeanAveragePrecision(iou_type="bbox", iou_thresholds=[0.5],
                                     rec_thresholds=np.linspace(0, 1, 20001).tolist(),
                                     max_detection_thresholds=[1, 10, 1000], backend="pycocotools")
    evaluator = TableTwoEvaluator()
    for _ in range(12):
        count = int(rng.integers(1, 6))
        corner = rng.uniform(0, 200, (count, 2))
        size = rng.uniform(20, 80, (count, 2))
        truth_boxes = np.column_stack([corner, corner + size])
        truth_categories = rng.integers(0, 4, count)
        detected_count = int(rng.integers(0, 9))
        source = rng.integers(0, count, detected_count)
        boxes = truth_boxes[source] + rng.normal(0, 8, (detected_count, 4))
        boxes[:, 2:] = np.maximum(boxes[:, 2:], boxes[:, :2] + 1)
        categories = np.where(rng.random(detected_count) < 0.8, truth_categories[source],
                              rng.integers(0, 4, detected_count))
        scores = rng.random(detected_count)
        evaluator.add(Detections(boxes, categories, scores, np.zeros((detected_count, 0, 5)),
                                 np.zeros((detected_count, 0)), np.zeros((detected_count, 0, 12))),
                      GroundTruth(truth_boxes, truth_categories, np.zeros((0, 5)), np.zeros(0, dtype=np.int64),
                                  np.zeros(0, dtype=np.int64)))
        reference.update([{"boxes": torch.tensor(boxes, dtype=torch.float64), "labels": torch.tensor(categories),
                           "scores": torch.tensor(scores, dtype=torch.float64)}],
                         [{"boxes": torch.tensor(truth_boxes, dtype=torch.float64),
                           "labels": torch.tensor(truth_categories)}])
    expected = float(reference.compute()["map_50"])
    result = evaluator.result()["mAP"]
    assert 0.05 < result < 0.99  # a non-trivial case
    assert result == pytest.approx(expected, abs=2e-3)
