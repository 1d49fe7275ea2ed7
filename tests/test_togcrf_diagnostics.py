"""The order oracle of :mod:`togcrf.diagnostics` on a hand-made case (the docs quote its figures)."""

from __future__ import annotations

import numpy as np
import pytest

from osgd.contract.taxonomy import CATEGORY_INDEX, TASK_INDEX, TASKS
from togcrf import diagnostics
from togcrf.metrics import Detections, GroundTruth, TableTwoEvaluator

KNIFE = CATEGORY_INDEX["knife"]
GRASP = [20.0, 20.0, 12.0, 4.0, np.pi / 2]


def _one_knife() -> GroundTruth:
    return GroundTruth(boxes=np.array([[10.0, 14.0, 80.0, 26.0]]), categories=np.array([KNIFE]),
                       grasp_rectangles=np.array([GRASP]), grasp_objects=np.array([0]),
                       grasp_tasks=np.array([TASK_INDEX["cut"]]))


def _detections(boxes: list[list[float]], scores: list[float], top_grasps: list[list[float]]) -> Detections:
    """One candidate per detection (its top-1)."""
    count = len(boxes)
    return Detections(boxes=np.array(boxes), categories=np.full(count, KNIFE), scores=np.array(scores),
                      grasps=np.array(top_grasps)[:, None, :], grasp_stability=np.full((count, 1), 0.9),
                      grasp_task_probs=np.full((count, 1, len(TASKS)), 1.0 / len(TASKS)))


def _pairs() -> list[tuple[Detections, GroundTruth]]:
    """Image 1: the knife found at 0.9 with its top-1 grasp 40 px off, and a false box at 0.7.
    Image 2: the knife found at 0.5 with its top-1 on the annotated grasp."""
    miss = [60.0, 20.0, 12.0, 4.0, np.pi / 2]
    first = _detections([[10, 14, 80, 26], [200, 200, 260, 212]], [0.9, 0.7], [miss, GRASP])
    second = _detections([[10, 14, 80, 26]], [0.5], [GRASP])
    return [(first, _one_knife()), (second, _one_knife())]


def _result(pairs: list[tuple[Detections, GroundTruth]]) -> dict:
    evaluator = TableTwoEvaluator()
    for detections, truth in pairs:
        evaluator.add(detections, truth)
    return evaluator.result()


def test_order_oracle_ranks_the_right_top1_first_and_keeps_other_scores() -> None:
    pairs = _pairs()
    before = _result(pairs)
    # detector: 0.9 grasp miss (FP), 0.7 false box (FP), 0.5 right: recall 1/2 at precision 1/3
    assert before["mAP-G"] == pytest.approx(0.5 / 3)
    oracle = diagnostics.order_oracle(pairs)
    assert oracle[0][0].scores.tolist() == [0.5, 0.7]  # the miss takes the lower score, the false box keeps its own
    assert oracle[1][0].scores.tolist() == [0.9]
    after = _result(oracle)
    assert after["mAP-G"] == pytest.approx(0.5)
    assert after["mAP"] == pytest.approx(before["mAP"])  # box TP, FP, TP in both orders


def test_handed_out_follows_any_key() -> None:
    reversed_order = diagnostics.handed_out(
        _pairs(), lambda detections, truth, may_claim, detection: -detections.scores[detection])
    assert reversed_order[0][0].scores.tolist() == [0.5, 0.7]
    assert reversed_order[1][0].scores.tolist() == [0.9]
