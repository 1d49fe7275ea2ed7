"""The lab's evaluation protocol (``--protocol lab``) beside ours, on hand-made cases that separate them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from osgd.contract.taxonomy import CATEGORY_INDEX, TASK_INDEX, TASKS
from togcrf.cli import app
from togcrf.geometry import box_iou
from togcrf.metrics import (
    Detections,
    GroundTruth,
    TableTwoEvaluator,
    average_precision,
    average_precision_11_point,
    match_detections,
    match_detections_voc,
    match_objects_in_order,
)

KNIFE, SCREWDRIVER = CATEGORY_INDEX["knife"], CATEGORY_INDEX["screwdriver"]
#: A grasp rectangle ``x y h w theta`` at the centre of the 100 px boxes below.
CENTRE_GRASP = np.array([50.0, 50.0, 30.0, 10.0, 0.0])
#: One on the left of them, far from the centre one (no Jaccard overlap).
LEFT_GRASP = np.array([20.0, 50.0, 30.0, 10.0, 0.0])


def detections(boxes: list[list[float]], categories: list[int], scores: list[float],
               top_grasps: list[np.ndarray] | None = None) -> Detections:
    """Detections with one grasp candidate each (or none), every task probability uniform."""
    count = len(boxes)
    grasps = np.zeros((count, 0, 5)) if top_grasps is None else np.stack(top_grasps)[:, None, :]
    width = grasps.shape[1]
    return Detections(boxes=np.array(boxes, dtype=float).reshape(-1, 4), categories=np.array(categories),
                      scores=np.array(scores, dtype=float), grasps=grasps,
                      grasp_stability=np.ones((count, width)),
                      grasp_task_probs=np.full((count, width, len(TASKS)), 1 / len(TASKS)))


def truth(boxes: list[list[float]], categories: list[int], grasps: list[np.ndarray] | None = None,
          grasp_objects: list[int] | None = None) -> GroundTruth:
    """Ground truth with the given grasps (all 'cut'), or none."""
    rectangles = np.zeros((0, 5)) if not grasps else np.stack(grasps)
    return GroundTruth(boxes=np.array(boxes, dtype=float).reshape(-1, 4), categories=np.array(categories),
                       grasp_rectangles=rectangles, grasp_objects=np.array(grasp_objects or [], dtype=np.int64),
                       grasp_tasks=np.full(len(rectangles), TASK_INDEX["cut"]))


def evaluate_both(pairs: list[tuple[Detections, GroundTruth]]) -> dict[str, dict]:
    """The result of each protocol on the same images."""
    results = {}
    for protocol in ("ours", "lab"):
        evaluator = TableTwoEvaluator(protocol=protocol)
        for image_detections, image_truth in pairs:
            evaluator.add(image_detections, image_truth)
        results[protocol] = evaluator.result()
    return results


# --------------------------------------------------------------------------- mAP


def test_plus_one_pixel_iou() -> None:
    # Continuous: 50 / 100 = 0.5, not above the threshold; +1 pixel: 11 x 6 / 11 x 11 = 0.545.
    ground, half = np.array([[0, 0, 10, 10]]), np.array([[0, 0, 10, 5]])
    assert box_iou(half, ground)[0, 0] == pytest.approx(0.5)
    assert box_iou(half, ground, plus_one=True)[0, 0] == pytest.approx(6 / 11)


def test_voc_rule_does_not_fall_back_to_the_second_best_object() -> None:
    # Two knives side by side; the second detection overlaps both, the first (claimed) one best.
    ground = [[0, 0, 100, 100], [20, 0, 120, 100]]
    boxes = [[0, 0, 100, 100], [5, 0, 105, 100]]  # IoU with the objects: 1, 0.67 / 0.9, 0.74
    scores = [0.9, 0.8]
    assert match_detections(np.array(boxes), np.array([KNIFE] * 2), np.array(scores), np.array(ground),
                            np.array([KNIFE] * 2)).tolist() == [0, 1]
    assert match_detections_voc(np.array(boxes), np.array([KNIFE] * 2), np.array(scores), np.array(ground),
                                np.array([KNIFE] * 2)).tolist() == [0, -1]
    results = evaluate_both([(detections(boxes, [KNIFE] * 2, scores), truth(ground, [KNIFE] * 2))])
    assert results["ours"]["mAP"] == pytest.approx(1.0)
    # Lab: TP then FP of 2 objects: precision 1 up to recall 0.5, i.e. 6 of the 11 recall points.
    assert results["lab"]["mAP"] == pytest.approx(6 / 11)
    assert results["ours"]["protocol"] == "ours" and results["lab"]["protocol"] == "lab"


def test_eleven_point_against_all_point_on_a_small_curve() -> None:
    # 3 objects; TP, FP, TP: recall 1/3, 1/3, 2/3; precision 1, 1/2, 2/3.
    scores, hits = np.array([0.9, 0.8, 0.7]), np.array([True, False, True])
    assert average_precision(scores, hits, 3) == pytest.approx(5 / 9)
    # Recall points 0-0.3 see precision 1, 0.4-0.6 see 2/3, 0.7-1 nothing.
    assert average_precision_11_point(scores, hits, 3) == pytest.approx((4 + 3 * 2 / 3) / 11)
    assert average_precision_11_point(np.zeros(0), np.zeros(0, dtype=bool), 2) == 0.0
    assert np.isnan(average_precision_11_point(scores, hits, 0))


def test_eleven_point_thresholds_are_numpys() -> None:
    # Recall 3/10 = 0.3 falls short of np.arange's 0.30000000000000004, as in the lab's voc_ap.
    scores, hits = np.array([0.9, 0.8, 0.7]), np.ones(3, dtype=bool)
    assert average_precision_11_point(scores, hits, 10) == pytest.approx(3 / 11)
    assert average_precision_11_point(scores, hits, 7) == pytest.approx(5 / 11)  # 3/7 = 0.43


# --------------------------------------------------------------------------- mAP-G


def test_lab_counts_ground_truth_only_where_its_category_was_detected() -> None:
    box = [[0, 0, 100, 100]]
    hit = (detections(box, [KNIFE], [0.9], [CENTRE_GRASP]), truth(box, [KNIFE], [CENTRE_GRASP], [0]))
    missed = (detections([], [], []), truth(box, [KNIFE], [CENTRE_GRASP], [0]))
    results = evaluate_both([hit, missed])
    assert results["ours"]["mAP-G"] == pytest.approx(0.5)  # one of two knives
    assert results["lab"]["mAP-G"] == pytest.approx(1.0)  # the missed image's knife is not counted
    # mAP counts both knives under both protocols: 0.5 all-point, 6/11 with 11 points.
    assert results["ours"]["mAP"] == pytest.approx(0.5)
    assert results["lab"]["mAP"] == pytest.approx(6 / 11)


def test_lab_leaves_out_a_category_detected_only_where_it_is_absent() -> None:
    box = [[0, 0, 100, 100]]
    knife_image = (detections(box, [KNIFE], [0.9], [CENTRE_GRASP]),
                   truth([*box, [200, 0, 300, 100]], [KNIFE, SCREWDRIVER], [CENTRE_GRASP], [0]))
    stray_screwdriver = (detections([[0, 200, 100, 300]], [SCREWDRIVER], [0.5], [CENTRE_GRASP]),
                         truth([], []))
    results = evaluate_both([knife_image, stray_screwdriver])
    assert results["ours"]["AP-G"] == {"knife": pytest.approx(1.0), "screwdriver": 0.0}
    assert results["ours"]["mAP-G"] == pytest.approx(0.5)
    assert np.isnan(results["lab"]["AP-G"]["screwdriver"])  # no screwdriver counted: the lab's NaN
    assert results["lab"]["mAP-G"] == pytest.approx(1.0)
    # Never detected at all: 0 under both.
    results = evaluate_both([knife_image])
    assert results["lab"]["AP-G"]["screwdriver"] == 0.0 and results["lab"]["mAP-G"] == pytest.approx(0.5)


def test_lab_matches_objects_in_annotation_order() -> None:
    # Object 0 (annotated first) has grasps at the centre and on the left; object 1 only at the centre.
    ground = [[0, 0, 100, 100], [10, 0, 110, 100]]
    image_truth = truth(ground, [KNIFE] * 2, [CENTRE_GRASP, LEFT_GRASP, CENTRE_GRASP], [0, 0, 1])
    # Detection 0 suits both objects (IoU 0.85 / 0.96); detection 1 (IoU 1 / 0.82) only object 0 by its grasp.
    boxes = [[8, 0, 108, 100], [0, 0, 100, 100]]
    image_detections = detections(boxes, [KNIFE] * 2, [0.9, 0.8], [CENTRE_GRASP, LEFT_GRASP])
    allowed = np.array([[True, True], [True, False]])
    arguments = (np.array(boxes, dtype=float), np.array([KNIFE] * 2), np.array([0.9, 0.8]), np.array(ground),
                 np.array([KNIFE] * 2))
    # Ours: the best detection takes its best object (1), the other one object 0.
    assert match_detections(*arguments, allowed=allowed).tolist() == [1, 0]
    # Lab: object 0 first takes the best detection; object 1 is left with none that suits it.
    assert match_objects_in_order(*arguments, allowed).tolist() == [0, -1]
    results = evaluate_both([(image_detections, image_truth)])
    assert results["ours"]["mAP-G"] == pytest.approx(1.0)
    assert results["lab"]["mAP-G"] == pytest.approx(0.5)
    assert results["ours"]["mAP"] == pytest.approx(1.0) and results["lab"]["mAP"] == pytest.approx(1.0)


def test_unknown_protocol_is_refused() -> None:
    with pytest.raises(ValueError, match="protocol"):
        TableTwoEvaluator(protocol="coco")  # type: ignore[arg-type]


# --------------------------------------------------------------------------- commands


def write_evaluation(path: Path, model: str, protocol: str | None) -> Path:
    """A minimal evaluation JSON (``protocol`` None: one written before protocols existed)."""
    row = {"mAP": 50.0, "mAP-G": 25.0, "Acc-T top1": 10.0, "Acc-T top5": 5.0, "Acc-T top10": 1.0, "fps": 2.0}
    document = {"model": model, "row": row, "metrics": {}}
    if protocol is not None:
        document["protocol"] = protocol
    path.write_text(json.dumps(document))
    return path


def test_table_names_its_protocol_and_refuses_a_mix(tmp_path: Path) -> None:
    lab_a = write_evaluation(tmp_path / "a.json", "tog", "lab")
    lab_b = write_evaluation(tmp_path / "b.json", "tog-crfs", "lab")
    old = write_evaluation(tmp_path / "old.json", "tog-crfs", None)
    result = CliRunner().invoke(app, ["table", str(lab_a), str(lab_b)])
    assert result.exit_code == 0, result.output
    assert result.output.splitlines()[0].startswith("Algorithm [protocol: lab]")

    result = CliRunner().invoke(app, ["table", str(lab_a), str(old)])
    assert result.exit_code == 1 and "mix protocols" in result.output and "old.json: ours" in result.output

    out = tmp_path / "table.json"
    result = CliRunner().invoke(app, ["table", str(lab_a), str(old), "--mixed", "--out", str(out)])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[0].startswith("Algorithm [protocol: mixed]")
    assert lines[2].startswith("TOG [lab]") and lines[3].startswith("TOG-CRFs [ours]")
    table = json.loads(out.read_text())
    assert table["protocol"] == "mixed" and [row["protocol"] for row in table["rows"]] == ["lab", "ours"]


def test_eval_refuses_an_unknown_protocol(tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["eval", str(tmp_path / "checkpoint.pt"), "--data", str(tmp_path),
                                      "--protocol", "voc"])
    assert result.exit_code == 1 and "protocol" in result.output
