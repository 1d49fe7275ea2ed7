"""The metrics of the paper's Table II: mAP, mAP-G, Acc-T top-k and speed.

Every metric is defined here once, on numpy arrays in a sample's pixel frame
(the model's outputs divided by the input scale, see
:func:`togcrf.evaluate.prediction_to_numpy`).

Definitions (paper section V-B; REFERENCE.md sections 1 and 3)
----------------------------------------------------------------
Grasp rectangle
    ``(x, y, h, w, theta)``: centre in pixels, ``h`` the gripper opening
    along the closing direction, ``w`` the finger width across it, ``theta``
    the angle of the closing direction to the image x axis in radians. A
    rectangle and the same one turned by 180 degrees are the same grasp.
Grasp match
    A detected grasp matches a ground-truth grasp when the Jaccard index of
    the two rotated rectangles is larger than 0.25 and their angle
    difference, taken modulo 180 degrees, is smaller than 30 degrees (the
    Cornell "rectangle metric", used by ROI-GD and by the paper).
Detection matching (mAP)
    Per image and category, detections are visited by decreasing score
    (ties: the model's order); each claims the unclaimed ground-truth box of
    its category with the highest IoU, if that IoU is larger than 0.5;
    otherwise it is a false positive. This is the greedy rule of COCO
    (pycocotools follows it, so the two agree). It is *not* the rule of
    ROI-GD and the TOG paper's lab: see Protocols below.
Average precision
    All-point interpolated (PASCAL VOC 2010 and later): the area under the
    precision-recall curve after replacing each precision by the largest
    precision at any higher recall. mAP is the mean over the categories
    that have at least one ground-truth object in the evaluated images.
mAP-G
    As mAP, but a detection may only claim a ground-truth box whose object
    also has a ground-truth grasp that the detection's top-1 stability grasp
    matches (so a detection with a bad grasp is a false positive, and the
    object stays available to a lower-scored detection).
Acc-T top-k
    Over the detections that are true positives of mAP, whose object has at
    least one ground-truth grasp: the fraction whose k candidates of highest
    stability all carry the right task label (arg-max of P(task | stable)).
    The *right* label of a candidate is the task of the ground-truth grasp of
    the matched object nearest to it (centre distance) among those it
    matches by the grasp criterion; when it matches none, the task of the
    nearest ground-truth grasp of that object (``unmatched_task="nearest"``,
    the default: Acc-T measures task classification apart from grasp
    quality, as the paper intends) or no label at all
    (``unmatched_task="wrong"``: such a candidate counts as wrong). Ties in
    distance (one rectangle annotated with several tasks) accept any of the
    tied tasks. A detection with fewer than k candidates is judged on all
    of them; one with none is a negative.
Acc-T by crowding
    Acc-T top-k of the same detections in strata: by the share of the
    matched object's ground-truth box whose pixels show other objects (the
    sample's instance mask: neither the table nor the object itself; bins
    :data:`COVER_BINS`), where the paper says the CRF acts, and by the
    number of annotated objects in the image. The strata are of the
    objects, not of the detections, so two models are compared on the same
    objects in each. Only for ground truth that
    carries the mask (:meth:`GroundTruth.from_sample`).
Speed
    Frames per second of the full model on one image at a time (batch 1),
    after warm-up runs, on a stated device; see :func:`measure_speed`.

Protocols
---------
``"ours"`` (the default) is the set of rules above. ``"lab"`` reproduces the
public evaluator of the paper's lab (ZhangHanbo/Visual-Manipulation-
Relationship-Network-Pytorch: ``datasets/voc_eval.py`` with
``use_07_metric=True`` for mAP, ``datasets/vmrd.py``
``evaluate_multigrasp_MRFPPI`` for mAP-G), which ROI-GD used:

- Box IoU with the +1-pixel convention (widths ``x2 - x1 + 1``).
- mAP: by decreasing score, a detection looks only at the ground-truth box
  of its category of highest IoU in its image; it is a true positive if
  that IoU is > 0.5 and that box is unclaimed, else a false positive (it
  may not fall back to its second-best box). AP is VOC07's 11-point
  average: the largest precision at recall >= t for t in
  ``np.arange(0, 1.1, 0.1)``, averaged (the thresholds are numpy's, so a
  recall of exactly 0.3, 0.6 or 0.7 falls just short of its threshold, as
  in the lab's code).
- mAP-G: per image and category, the ground-truth objects of the category
  are counted (recall's denominator) only if the image has a detection of
  that category. The objects, in annotation order, each take the
  highest-scored free detection of their category whose box IoU is > 0.5
  and whose top-1 grasp matches one of the object's grasps. AP is
  all-point, as ours. A category with no detection at all scores 0; one
  whose detections all lie in images without its ground truth has nothing
  counted and is left out of the mean (the lab's NaN).
- Both means run over the categories with ground truth in the evaluated
  images (the lab's code averages over every class of its dataset; where
  every class has objects in the evaluated images the two coincide).
- Acc-T and speed are the same under both protocols (the lab's evaluator
  has no Acc-T); Acc-T keeps our matching.

Not reproduced: the lab writes detection files with scores rounded to 3
decimals and boxes to 0.1 pixel, and breaks score ties with numpy's
unstable sort; here ties keep the model's order. Its mAP-G code also marks
a true positive at the detection's sorted position in the unsorted array,
which is the detection meant whenever each category's detections come in
decreasing score order, as after NMS; here the detection meant is marked.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Any, Literal

import numpy as np

from osgd.contract.taxonomy import CATEGORIES
from togcrf.geometry import box_iou, grasp_match_matrix

log = logging.getLogger(__name__)

#: Box IoU above which a detection can be a true positive (paper V-B).
BOX_IOU_THRESHOLD = 0.5
#: The k of Acc-T top-k reported in Table II.
TOP_K = (1, 5, 10)
#: The evaluation protocols (see the module docstring): ours, the default, and the lab's.
PROTOCOLS = ("ours", "lab")
Protocol = Literal["ours", "lab"]
#: Lower edges of the strata of Acc-T by the share of an object's box on other objects.
COVER_BINS = (0.0, 0.05, 0.15, 0.3)

#: The names, in :meth:`TableTwoEvaluator.result`, of Acc-T by other objects' share of the box and by the
#: number of objects in the image.
COVER_STRATUM = "Acc-T by other objects' share"
PILE_STRATUM = "Acc-T by objects in the image"
#: Recall thresholds of VOC07's 11-point AP, computed as the lab's code does (0.3 is 0.30000000000000004).
ELEVEN_POINT_RECALLS = np.arange(0.0, 1.1, 0.1)


# --------------------------------------------------------------------------- average precision


def _trivial_average_precision(scores: np.ndarray, ground_truth_count: int) -> float | None:
    """NaN without ground truth, 0 without detections, else None (the curve decides)."""
    if ground_truth_count <= 0:
        return float("nan")
    if len(scores) == 0:
        return 0.0
    return None


def average_precision(scores: np.ndarray, true_positive: np.ndarray, ground_truth_count: int) -> float:
    """All-point interpolated average precision of one category.

    Parameters
    ----------
    scores : (D,) array
        Detection scores over all images.
    true_positive : (D,) bool array
    ground_truth_count : int
        Ground-truth objects of the category over all images.

    Returns
    -------
    float
        In [0, 1]; NaN when there is no ground truth.
    """
    trivial = _trivial_average_precision(scores, ground_truth_count)
    if trivial is not None:
        return trivial
    recall, precision = precision_recall(scores, true_positive, ground_truth_count)
    recall = np.concatenate([[0.0], recall, [recall[-1]]])
    precision = np.concatenate([[0.0], precision, [0.0]])
    envelope = np.maximum.accumulate(precision[::-1])[::-1]
    steps = np.nonzero(recall[1:] != recall[:-1])[0]
    return float(np.sum((recall[steps + 1] - recall[steps]) * envelope[steps + 1]))


def precision_recall(scores: np.ndarray, true_positive: np.ndarray,
                     ground_truth_count: int) -> tuple[np.ndarray, np.ndarray]:
    """Recall and precision after each detection, by decreasing score (ties: given order).

    Parameters
    ----------
    scores : (D,) array
    true_positive : (D,) bool array
    ground_truth_count : int
        Positive.

    Returns
    -------
    recall, precision : (D,) float64 arrays
    """
    order = np.argsort(-np.asarray(scores, dtype=np.float64), kind="stable")
    hits = np.asarray(true_positive, dtype=bool)[order]
    true_cumulative = np.cumsum(hits)
    recall = true_cumulative / ground_truth_count
    return recall, true_cumulative / np.arange(1, len(hits) + 1)


def average_precision_11_point(scores: np.ndarray, true_positive: np.ndarray, ground_truth_count: int) -> float:
    """VOC07's 11-point interpolated average precision of one category (the lab's mAP).

    The mean over the recall thresholds :data:`ELEVEN_POINT_RECALLS` of the
    largest precision at a recall >= the threshold (0 where none reaches it).

    Parameters
    ----------
    scores : (D,) array
    true_positive : (D,) bool array
    ground_truth_count : int

    Returns
    -------
    float
        In [0, 1]; NaN when there is no ground truth.
    """
    trivial = _trivial_average_precision(scores, ground_truth_count)
    if trivial is not None:
        return trivial
    recall, precision = precision_recall(scores, true_positive, ground_truth_count)
    return float(sum(precision[recall >= threshold].max(initial=0.0) for threshold in ELEVEN_POINT_RECALLS) / 11)


def match_detections(
    boxes: np.ndarray,
    categories: np.ndarray,
    scores: np.ndarray,
    ground_truth_boxes: np.ndarray,
    ground_truth_categories: np.ndarray,
    *,
    allowed: np.ndarray | None = None,
    iou_threshold: float = BOX_IOU_THRESHOLD,
) -> np.ndarray:
    """Greedy matching of one image's detections to its ground-truth objects.

    Parameters
    ----------
    boxes : (D, 4) array
    categories : (D,) int array
        Category index (index into the vocabulary's categories, no background offset).
    scores : (D,) array
    ground_truth_boxes : (N, 4) array
    ground_truth_categories : (N,) int array
    allowed : (D, N) bool array, optional
        Extra condition for a detection to claim an object (mAP-G: its grasp
        matches one of the object's grasps).
    iou_threshold : float

    Returns
    -------
    (D,) int64 array
        Row of the claimed ground-truth object, -1 for a false positive.
    """
    boxes = np.asarray(boxes).reshape(-1, 4)
    matched = np.full(len(boxes), -1, dtype=np.int64)
    if len(boxes) == 0 or len(ground_truth_boxes) == 0:
        return matched
    iou = box_iou(boxes, ground_truth_boxes)
    eligible = (np.asarray(categories)[:, None] == np.asarray(ground_truth_categories)[None, :]) & (iou > iou_threshold)
    if allowed is not None:
        eligible &= allowed
    claimed = np.zeros(len(ground_truth_boxes), dtype=bool)
    for detection in np.argsort(-np.asarray(scores, dtype=np.float64), kind="stable"):
        candidates = eligible[detection] & ~claimed
        if candidates.any():
            best = int(np.argmax(np.where(candidates, iou[detection], -1.0)))
            claimed[best] = True
            matched[detection] = best
    return matched


def match_detections_voc(
    boxes: np.ndarray,
    categories: np.ndarray,
    scores: np.ndarray,
    ground_truth_boxes: np.ndarray,
    ground_truth_categories: np.ndarray,
    *,
    iou_threshold: float = BOX_IOU_THRESHOLD,
) -> np.ndarray:
    """The VOC rule of one image (the lab's mAP): no fall-back to a second-best object.

    By decreasing score, each detection looks at the ground-truth box of its
    category of highest +1-pixel IoU (the first of equals); it claims it if
    that IoU is larger than ``iou_threshold`` and the box is unclaimed.

    Parameters
    ----------
    boxes, categories, scores, ground_truth_boxes, ground_truth_categories
        As :func:`match_detections`.
    iou_threshold : float

    Returns
    -------
    (D,) int64 array
        Row of the claimed ground-truth object, -1 for a false positive.
    """
    boxes = np.asarray(boxes).reshape(-1, 4)
    matched = np.full(len(boxes), -1, dtype=np.int64)
    same = np.asarray(categories).reshape(-1, 1) == np.asarray(ground_truth_categories).reshape(1, -1)
    iou = np.where(same, box_iou(boxes, ground_truth_boxes, plus_one=True), -1.0)
    claimed = np.zeros(same.shape[1], dtype=bool)
    for detection in np.argsort(-np.asarray(scores, dtype=np.float64), kind="stable"):
        if not same[detection].any():
            continue
        best = int(np.argmax(iou[detection]))
        if iou[detection, best] > iou_threshold and not claimed[best]:
            claimed[best] = True
            matched[detection] = best
    return matched


def match_objects_in_order(
    boxes: np.ndarray,
    categories: np.ndarray,
    scores: np.ndarray,
    ground_truth_boxes: np.ndarray,
    ground_truth_categories: np.ndarray,
    allowed: np.ndarray,
    *,
    iou_threshold: float = BOX_IOU_THRESHOLD,
) -> np.ndarray:
    """The lab's mAP-G matching of one image: object by object, in annotation order.

    Each ground-truth object takes the highest-scored free detection of its
    category whose +1-pixel IoU with it is larger than ``iou_threshold``
    and for which ``allowed`` holds (its top-1 grasp matches one of the
    object's grasps).

    Parameters
    ----------
    boxes, categories, scores, ground_truth_boxes, ground_truth_categories
        As :func:`match_detections`.
    allowed : (D, N) bool array
    iou_threshold : float

    Returns
    -------
    (D,) int64 array
        Row of the object that took the detection, -1 for a false positive.
    """
    boxes = np.asarray(boxes).reshape(-1, 4)
    matched = np.full(len(boxes), -1, dtype=np.int64)
    same = np.asarray(categories).reshape(-1, 1) == np.asarray(ground_truth_categories).reshape(1, -1)
    eligible = same & (box_iou(boxes, ground_truth_boxes, plus_one=True) > iou_threshold) & allowed
    order = np.argsort(-np.asarray(scores, dtype=np.float64), kind="stable")
    for row in range(eligible.shape[1]):
        free = order[eligible[order, row] & (matched[order] < 0)]
        if len(free):
            matched[free[0]] = row
    return matched


# --------------------------------------------------------------------------- Table II


@dataclass(frozen=True)
class GroundTruth:
    """One image's annotations in its pixel frame (see ``osgd.contract.samples.Sample``).

    Attributes
    ----------
    boxes : (N, 4) float array, pixels
    categories : (N,) int array, index into the vocabulary's categories
    grasp_rectangles : (G, 5) float array
    grasp_objects : (G,) int array, row of ``boxes``
    grasp_tasks : (G,) int array, index into the vocabulary's tasks
    mask : (H, W) int array or None
        Instance mask: 0 background, ``mask_values[i]`` on object ``i``'s visible pixels (Acc-T by crowding).
    mask_values : (N,) int array or None
    """

    boxes: np.ndarray
    categories: np.ndarray
    grasp_rectangles: np.ndarray
    grasp_objects: np.ndarray
    grasp_tasks: np.ndarray
    mask: np.ndarray | None = None
    mask_values: np.ndarray | None = None

    @classmethod
    def from_sample(cls, sample: Any) -> GroundTruth:
        """From an ``osgd.contract.samples.Sample`` (its mask holds ``object_index + 1``)."""
        return cls(sample.boxes, sample.category_labels, sample.grasp_rectangles, sample.grasp_objects,
                   sample.grasp_tasks, sample.mask, np.asarray(sample.object_indices, dtype=np.int64) + 1)

    def other_objects_share(self, row: int) -> float:
        """Share of object ``row``'s box that shows other objects (NaN without a mask).

        The box is the ground truth's (inclusive pixel ends, as the samples stage writes it), so the share
        of an object is the same whichever model is scored.
        """
        if self.mask is None or self.mask_values is None:
            return float("nan")
        height, width = self.mask.shape
        x1, y1, x2, y2 = (int(np.floor(value)) for value in np.asarray(self.boxes[row], dtype=np.float64))
        window = self.mask[max(y1, 0):min(y2 + 1, height), max(x1, 0):min(x2 + 1, width)]
        if window.size == 0:
            return float("nan")
        return float(np.count_nonzero((window != 0) & (window != self.mask_values[row])) / window.size)


@dataclass(frozen=True)
class Detections:
    """One image's detections in its pixel frame (the contract's eval output, as numpy).

    Attributes
    ----------
    boxes : (D, 4) float array, pixels
    categories : (D,) int array, index into the vocabulary's categories (model label - 1)
    scores : (D,) float array
    grasps : (D, K, 5) float array, grasp candidates of each detection
    grasp_stability : (D, K) float array, P(stable)
    grasp_task_probs : (D, K, T) float array, P(task | stable) over the vocabulary's T tasks
    """

    boxes: np.ndarray
    categories: np.ndarray
    scores: np.ndarray
    grasps: np.ndarray
    grasp_stability: np.ndarray
    grasp_task_probs: np.ndarray

    def top_grasp(self, detection: int) -> np.ndarray | None:
        """The ``(5,)`` rectangle of highest stability of a detection, None when it has none."""
        stability = self.grasp_stability[detection]
        if len(stability) == 0:
            return None
        return self.grasps[detection, int(np.argmax(stability))]


def right_tasks(candidates: np.ndarray, object_grasps: np.ndarray, object_tasks: np.ndarray,
                unmatched_task: Literal["nearest", "wrong"] = "nearest") -> list[set[int]]:
    """The task labels counted as right for grasp candidates of a matched object.

    Parameters
    ----------
    candidates : (C, 5) array
        Detected grasp rectangles.
    object_grasps : (G, 5) array
        Ground-truth grasps of the matched object (G >= 1).
    object_tasks : (G,) int array
    unmatched_task : {"nearest", "wrong"}
        What a candidate that matches no ground-truth grasp is judged
        against (see the module docstring).

    Returns
    -------
    list of set of int
        Per candidate, the task indices that are right (empty: none is).
    """
    matches = grasp_match_matrix(candidates, object_grasps)
    distance = np.linalg.norm(np.asarray(candidates, dtype=np.float64)[:, None, :2]
                              - np.asarray(object_grasps, dtype=np.float64)[None, :, :2], axis=-1)
    result = []
    for row in range(len(candidates)):
        pool = matches[row]
        if not pool.any():
            if unmatched_task == "wrong":
                result.append(set())
                continue
            pool = np.ones(len(object_grasps), dtype=bool)
        pooled_distance = np.where(pool, distance[row], np.inf)
        nearest = pooled_distance <= pooled_distance.min() + 1e-6
        result.append({int(task) for task in np.asarray(object_tasks)[nearest]})
    return result


def grasp_allowed(detections: Detections, truth: GroundTruth) -> np.ndarray:
    """Which detections may claim which objects for mAP-G: the top-1 grasp matches one of the object's.

    Parameters
    ----------
    detections : Detections
    truth : GroundTruth

    Returns
    -------
    (D, N) bool array
        Detections by objects; category and box overlap are not looked at.
    """
    count = len(np.asarray(detections.categories).reshape(-1))
    grasp_objects = np.asarray(truth.grasp_objects, dtype=np.int64).reshape(-1)
    truth_grasps = np.asarray(truth.grasp_rectangles, dtype=np.float64).reshape(-1, 5)
    allowed = np.zeros((count, len(np.asarray(truth.categories).reshape(-1))), dtype=bool)
    tops = [(detection, detections.top_grasp(detection)) for detection in range(count)]
    tops = [(detection, top) for detection, top in tops if top is not None]
    if tops and len(truth_grasps):
        # One (detections x grasps) match, then per detection the objects owning a matched grasp.
        matches = grasp_match_matrix(np.stack([top for _, top in tops]), truth_grasps)
        rows, columns = np.nonzero(matches)
        allowed[np.array([detection for detection, _ in tops])[rows], grasp_objects[columns]] = True
    return allowed


def _mean_ignoring_nan(values: Mapping[str, float]) -> float:
    kept = [value for value in values.values() if not np.isnan(value)]
    return float(np.mean(kept)) if kept else float("nan")


@dataclass
class TableTwoEvaluator:
    """Accumulates detections over images and computes the row of Table II.

    Parameters
    ----------
    top_k : sequence of int
        The k of Acc-T top-k.
    unmatched_task : {"nearest", "wrong"}
        See the module docstring (Acc-T).
    protocol : {"ours", "lab"}
        The rules of mAP and mAP-G (module docstring, Protocols).
    categories : sequence of str
        The vocabulary's categories, which the detections' and the ground truth's category indices index
        (default Table I's); AP and AP-G are reported by these names.

    Raises
    ------
    ValueError
        If the protocol is not one of :data:`PROTOCOLS`.

    Examples
    --------
    >>> evaluator = TableTwoEvaluator()                          # doctest: +SKIP
    >>> for detections, truth in pairs:                          # doctest: +SKIP
    ...     evaluator.add(detections, truth)
    >>> evaluator.result()["mAP"]                                # doctest: +SKIP
    """

    top_k: Sequence[int] = TOP_K
    unmatched_task: Literal["nearest", "wrong"] = "nearest"
    protocol: Protocol = "ours"
    categories: Sequence[str] = CATEGORIES
    _scores: list[np.ndarray] = field(default_factory=list)
    _categories: list[np.ndarray] = field(default_factory=list)
    _box_hits: list[np.ndarray] = field(default_factory=list)
    _grasp_hits: list[np.ndarray] = field(default_factory=list)
    _ground_truth_counts: np.ndarray = field(init=False)
    _grasp_ground_truth_counts: np.ndarray = field(init=False)
    _task_hits: dict[int, list[bool]] = field(default_factory=dict)
    _roi_cover: list[float] = field(default_factory=list)
    _roi_pile: list[int] = field(default_factory=list)
    images: int = 0

    def __post_init__(self) -> None:
        if self.protocol not in PROTOCOLS:
            raise ValueError(f"unknown protocol {self.protocol!r}: expected one of {', '.join(PROTOCOLS)}")
        self._ground_truth_counts = np.zeros(len(self.categories), dtype=np.int64)
        self._grasp_ground_truth_counts = np.zeros(len(self.categories), dtype=np.int64)

    def add(self, detections: Detections, truth: GroundTruth) -> None:
        """Add one image's detections and ground truth."""
        self.images += 1
        categories = np.asarray(detections.categories, dtype=np.int64).reshape(-1)
        truth_categories = np.asarray(truth.categories, dtype=np.int64).reshape(-1)
        np.add.at(self._ground_truth_counts, truth_categories, 1)
        box_match = match_detections(detections.boxes, categories, detections.scores, truth.boxes,
                                     truth_categories)
        box_hits, grasp_hits, counted = self._protocol_hits(detections, truth, categories, truth_categories,
                                                            box_match)
        np.add.at(self._grasp_ground_truth_counts, counted, 1)
        self._scores.append(np.asarray(detections.scores, dtype=np.float64).reshape(-1))
        self._categories.append(categories)
        self._box_hits.append(box_hits)
        self._grasp_hits.append(grasp_hits)
        # Acc-T: our matching under either protocol.
        grasp_objects = np.asarray(truth.grasp_objects, dtype=np.int64).reshape(-1)
        truth_grasps = np.asarray(truth.grasp_rectangles, dtype=np.float64).reshape(-1, 5)
        truth_tasks = np.asarray(truth.grasp_tasks, dtype=np.int64).reshape(-1)
        for detection in np.nonzero(box_match >= 0)[0]:
            of_object = grasp_objects == box_match[detection]
            if not of_object.any():
                continue
            self._judge_tasks(detections, int(detection), truth_grasps[of_object], truth_tasks[of_object])
            self._roi_cover.append(truth.other_objects_share(int(box_match[detection])))
            self._roi_pile.append(len(truth_categories))

    def _protocol_hits(self, detections: Detections, truth: GroundTruth, categories: np.ndarray,
                       truth_categories: np.ndarray,
                       box_match: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One image's mAP hits, mAP-G hits and the categories of its objects that mAP-G counts."""
        allowed = grasp_allowed(detections, truth)
        if self.protocol == "lab":
            box_match = match_detections_voc(detections.boxes, categories, detections.scores, truth.boxes,
                                             truth_categories)
            grasp_match = match_objects_in_order(detections.boxes, categories, detections.scores, truth.boxes,
                                                 truth_categories, allowed)
            counted = truth_categories[np.isin(truth_categories, categories)]
        else:
            grasp_match = match_detections(detections.boxes, categories, detections.scores, truth.boxes,
                                           truth_categories, allowed=allowed)
            counted = truth_categories
        return box_match >= 0, grasp_match >= 0, counted

    def _judge_tasks(self, detections: Detections, detection: int, object_grasps: np.ndarray,
                     object_tasks: np.ndarray) -> None:
        stability = np.asarray(detections.grasp_stability[detection], dtype=np.float64).reshape(-1)
        order = np.argsort(-stability, kind="stable")[:max(self.top_k)]
        candidates = np.asarray(detections.grasps[detection], dtype=np.float64).reshape(-1, 5)[order]
        task_probs = np.asarray(detections.grasp_task_probs[detection])
        predicted = np.argmax(task_probs.reshape(-1, task_probs.shape[-1])[order], axis=-1)
        allowed = right_tasks(candidates, object_grasps, object_tasks, self.unmatched_task)
        correct = np.array([int(task) in right for task, right in zip(predicted, allowed, strict=True)], dtype=bool)
        for k in self.top_k:
            self._task_hits.setdefault(k, []).append(bool(len(correct) > 0 and correct[:k].all()))

    def result(self) -> dict[str, Any]:
        """The metrics, as fractions in [0, 1] (NaN where undefined).

        Returns
        -------
        dict
            ``protocol``, ``mAP``, ``mAP-G``, ``Acc-T top<k>`` for each k,
            ``images``, ``rois`` (detections judged for Acc-T), ``AP`` and
            ``AP-G`` per category name (only the categories with ground
            truth; under the lab's protocol an AP-G can be NaN, left out
            of mAP-G).
        """
        scores = np.concatenate(self._scores) if self._scores else np.zeros(0)
        categories = np.concatenate(self._categories) if self._categories else np.zeros(0, dtype=np.int64)
        box_hits = np.concatenate(self._box_hits) if self._box_hits else np.zeros(0, dtype=bool)
        grasp_hits = np.concatenate(self._grasp_hits) if self._grasp_hits else np.zeros(0, dtype=bool)
        box_ap = average_precision_11_point if self.protocol == "lab" else average_precision
        per_category, per_category_grasp = {}, {}
        for index, name in enumerate(self.categories):
            count = int(self._ground_truth_counts[index])
            if count == 0:
                continue
            chosen = categories == index
            per_category[name] = box_ap(scores[chosen], box_hits[chosen], count)
            # No detection: 0, even where the lab's rule counted no ground truth.
            per_category_grasp[name] = average_precision(
                scores[chosen], grasp_hits[chosen], int(self._grasp_ground_truth_counts[index])
            ) if chosen.any() else 0.0
        result: dict[str, Any] = {"protocol": self.protocol, "mAP": _mean_ignoring_nan(per_category),
                                  "mAP-G": _mean_ignoring_nan(per_category_grasp)}
        rois = 0
        for k in self.top_k:
            hits = self._task_hits.get(k, [])
            rois = len(hits)
            result[f"Acc-T top{k}"] = float(np.mean(hits)) if hits else float("nan")
        result.update({"images": self.images, "rois": rois, "AP": per_category, "AP-G": per_category_grasp})
        result.update(self._crowding_strata())
        return result

    def _crowding_strata(self) -> dict[str, Any]:
        """Acc-T by other objects' share of the box and by objects in the image (module docstring)."""
        cover = np.asarray(self._roi_cover, dtype=np.float64)
        pile = np.asarray(self._roi_pile, dtype=np.int64)
        hits = {k: np.asarray(self._task_hits.get(k, []), dtype=bool) for k in self.top_k}

        def stratum(chosen: np.ndarray) -> dict[str, Any]:
            return {"rois": int(chosen.sum()),
                    **{f"Acc-T top{k}": float(hits[k][chosen].mean()) if chosen.any() else float("nan")
                       for k in self.top_k}}

        edges = (*COVER_BINS, np.inf)
        by_cover = {f"{low:.2f}-{high:.2f}" if np.isfinite(high) else f">={low:.2f}":
                    stratum((cover >= low) & (cover < high)) for low, high in pairwise(edges)}
        by_pile = {str(count): stratum(pile == count) for count in sorted(set(pile.tolist()))}
        return {COVER_STRATUM: by_cover if np.isfinite(cover).any() else {}, PILE_STRATUM: by_pile}


# --------------------------------------------------------------------------- speed


def measure_speed(run_once: Any, inputs: Sequence[Any], warmup: int = 2, repeats: int | None = None,
                  device: str = "cpu") -> Mapping[str, Any]:
    """Frames per second of a model on one input at a time.

    Parameters
    ----------
    run_once : callable
        Called with one input (e.g. ``lambda image: model([image])``); must
        return once the result is computed (synchronises CUDA itself when
        ``device`` is a CUDA device).
    inputs : sequence
        Inputs cycled through; the first ``warmup`` calls are not timed.
    warmup : int
    repeats : int, optional
        Timed calls; default one per input.
    device : str
        Named in the result, and synchronised when it is a CUDA device.

    Returns
    -------
    dict
        ``fps``, ``seconds_per_image``, ``images`` (timed), ``device``.
    """
    if not inputs:
        raise ValueError("measure_speed needs at least one input")
    synchronise = None
    if device.startswith("cuda"):
        import torch  # noqa: PLC0415 - optional dependency: the metrics run on numpy alone; torch times CUDA

        synchronise = torch.cuda.synchronize
    for index in range(warmup):
        run_once(inputs[index % len(inputs)])
    if synchronise:
        synchronise()
    repeats = len(inputs) if repeats is None else repeats
    start = time.perf_counter()
    for index in range(repeats):
        run_once(inputs[index % len(inputs)])
    if synchronise:
        synchronise()
    elapsed = time.perf_counter() - start
    seconds = elapsed / max(repeats, 1)
    return {"fps": 1.0 / seconds if seconds > 0 else float("inf"), "seconds_per_image": seconds,
            "images": repeats, "device": device}
