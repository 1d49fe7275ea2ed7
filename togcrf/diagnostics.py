"""Where a detector's top-1 grasp lands, under several ways of ranking its candidates.

mAP-G counts a detection only when its top-1 grasp matches one of its
object's ground-truth grasps (:mod:`togcrf.metrics`). These diagnostics run
a checkpoint (TOG, TOG-CRFs, or FCGN + Task, which skips the rankings that
read the 7 x 7 grid, ``GRID_RANKINGS``) on a split's samples and take every
detection that claims an object with grasps (same category, IoU >
``CLAIM_IOU``, best-scored detection first; :func:`claimed_objects`).

**Shares of the claimed objects** (:func:`tally`), for each ranking of a
detection's candidates (``RANKINGS``): the share whose first candidate
matches a ground-truth grasp of the object, and the share where any of the
first 5 does; beside them the share where any candidate at all does (the
ceiling of every ranking):

- ``stability``: P(stable), the detector's own ranking;
- ``smooth-cells``: P(stable) averaged over the 3 x 3 cells around each
  candidate, same anchor angle (at the grid's edges, over the cells that
  exist; :func:`neighbourhood_mean`);
- ``smooth-cells-angles``: over the 3 x 3 cells and the two neighbouring
  anchor angles;
- ``stability x task confidence``: P(stable) times the candidate's largest
  task probability;
- ``own-mask oracle``: P(stable) among the candidates whose centre lies on
  the object's own visible pixels (the sample's instance mask, which the
  model never sees): the ceiling of telling the object from its neighbours.

Where the detector's own top-1 candidate lands (``LANDINGS``): on the
object's own pixels, on another object's, or on the table; and the distance
from the top-1 to the nearest ground-truth grasp centre of its object,
apart for top-1 grasps that match and that miss.

**Table II figures** (our protocol, ``METRIC_COLUMNS``) of the same
detections, changed as each variant says (``TABLE_VARIANTS``;
:func:`table_rows`):

- ``detector``: unchanged, as ``togcrf eval`` scores them;
- ``grasp oracle``: each detection's candidates that match a ground-truth
  grasp of an object it could claim ranked first (:func:`grasp_oracle`):
  the mAP-G that a perfect ranking of the candidates reaches at the
  detector's mAP;
- ``smooth-cells ranking``: each detection's candidates ranked by the
  ``smooth-cells`` mean instead of their own P(stable);
- ``score x top-1 stability``: each detection's score multiplied by the
  P(stable) of its top-1 candidate (:func:`scored_by_top_grasp`);
- ``order oracle`` (:func:`order_oracle`, over the detections of all
  samples together): the detector's own top-1 candidates, with the scores
  of the detections that could claim an object handed out again per
  category (:func:`handed_out`), so that those whose top-1 matches a grasp
  of such an object come first (each group keeps its order; the other
  detections keep their scores, so box mAP hardly moves): the mAP-G that a
  perfect "is my top-1 grasp right" confidence gives at the detector's
  match rate.

Command line (``--views``: the detections with their candidates averaged
over test-time views, :mod:`togcrf.tta`; ``--json``: also write the shares,
distances and figures)::

    python -m togcrf.diagnostics CHECKPOINT --data data --pipeline recipe-pairs96 \\
        [--split test] [--max-samples 100] [--json out.json] [--views 8]
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import replace
from itertools import islice
from pathlib import Path
from typing import Any

import numpy as np
import torch

from osgd.contract.samples import iter_samples, sample_shards
from osgd.contract.taxonomy import CATEGORIES
from togcrf.anchors import ANCHOR_ANGLES
from togcrf.checkpoint import load_checkpoint
from togcrf.evaluate import TABLE_COLUMNS
from togcrf.metrics import Detections, GroundTruth, TableTwoEvaluator, box_iou, grasp_match_matrix
from togcrf.predict import predict_depth

#: IoU a detection needs with an object of its category to claim it (mAP's rule).
CLAIM_IOU = 0.5


def neighbourhood_mean(stability: np.ndarray, angle_radius: int) -> np.ndarray:
    """P(stable) averaged over the 3 x 3 cells (and ``angle_radius`` anchor angles, cyclic) around each candidate.

    Parameters
    ----------
    stability : (K,) float, K = 7 * 7 * 4 in candidate order

    Returns
    -------
    (K,) float
    """
    angles = len(ANCHOR_ANGLES)
    side = math.isqrt(len(stability) // angles)
    cells = stability.reshape(side, side, angles)
    padded = np.pad(cells, ((1, 1), (1, 1), (0, 0)), constant_values=np.nan)
    stacked = []
    for row in range(3):
        for column in range(3):
            window = padded[row:row + side, column:column + side]
            stacked.extend(np.roll(window, shift, axis=2) for shift in range(-angle_radius, angle_radius + 1))
    return np.nanmean(np.stack(stacked), axis=0).reshape(-1)


#: Rankings of one detection's candidates: name -> f(stability (K,), task probabilities (K, T)) -> (K,) key.
RANKINGS = {
    "stability": lambda stability, tasks: stability,
    "smooth-cells": lambda stability, tasks: neighbourhood_mean(stability, 0),
    "smooth-cells-angles": lambda stability, tasks: neighbourhood_mean(stability, 1),
    "stability x task confidence": lambda stability, tasks: stability * tasks.max(axis=-1),
}
#: The rankings that read a detection's candidates as the "roi" branch's 7 x 7 x 4 grid; FCGN + Task's
#: candidates (the most stable of the image's cells inside the box) have no such order, so they skip them.
GRID_RANKINGS = ("smooth-cells", "smooth-cells-angles")


def detect(model: torch.nn.Module, config: dict, sample: Any, views: int = 1) -> tuple[Detections, GroundTruth]:
    """A checkpoint's detections on one sample (``togcrf.predict.predict_depth``, with ``views`` test-time
    views) and the sample's truth."""
    detections = predict_depth(model, sample.depth, config.get("image_size"),
                               depth_reference=config["depth_reference"], views=views)
    return detections, GroundTruth.from_sample(sample)


def claimable(detections: Detections, truth: GroundTruth) -> tuple[np.ndarray, np.ndarray]:
    """(D, N) bool: which objects each detection may claim (same category, IoU > ``CLAIM_IOU``); and the (D, N) IoU."""
    iou = box_iou(detections.boxes, truth.boxes)
    return (truth.categories[None, :] == np.asarray(detections.categories)[:, None]) & (iou > CLAIM_IOU), iou


def claimed_objects(detections: Detections, truth: GroundTruth) -> list[tuple[int, int]]:
    """(detection, object) pairs: each object with grasps claimed by its best-scored overlapping detection."""
    may_claim, iou = claimable(detections, truth)
    pairs, taken = [], set()
    for detection in np.argsort(-detections.scores, kind="stable"):
        same = may_claim[detection]
        free = [index for index in np.nonzero(same)[0] if index not in taken]
        if not free:
            continue
        target = max(free, key=lambda index: iou[detection, index])
        taken.add(target)
        if np.any(truth.grasp_objects == target):
            pairs.append((int(detection), int(target)))
    return pairs


#: Where a candidate's centre lies in the instance mask, by the name counted.
LANDINGS = ("top-1 on own object", "top-1 on another object", "top-1 on the table")


def landing(mask: np.ndarray, centres: np.ndarray, own_value: int) -> np.ndarray:
    """0 own object, 1 another object, 2 table, for (n, 2) pixel centres (clipped to the image)."""
    height, width = mask.shape
    values = mask[np.clip(np.round(centres[:, 1]).astype(int), 0, height - 1),
                  np.clip(np.round(centres[:, 0]).astype(int), 0, width - 1)]
    return np.where(values == own_value, 0, np.where(values == 0, 2, 1))


def tally(detections: Detections, truth: GroundTruth, mask: np.ndarray, object_indices: np.ndarray,
          counts: dict[str, int], distances: dict[str, list[float]], rankings: dict = RANKINGS) -> None:
    """Add one image's hits of each of ``rankings``, and where the top-1 lands, to ``counts``; the top-1's
    distance (px) to the nearest ground-truth grasp centre of its object to ``distances["match"]`` or
    ``["miss"]``."""
    for detection, target in claimed_objects(detections, truth):
        object_grasps = truth.grasp_rectangles[truth.grasp_objects == target]
        matches = grasp_match_matrix(detections.grasps[detection], object_grasps).any(axis=1)
        stability = detections.grasp_stability[detection]
        top = detections.grasps[detection][np.argmax(stability)]
        distances["match" if matches[np.argmax(stability)] else "miss"].append(
            float(np.linalg.norm(object_grasps[:, :2] - top[:2], axis=1).min()))
        where = landing(mask, detections.grasps[detection][:, :2], int(object_indices[target]) + 1)
        counts["objects"] += 1
        counts["any candidate"] += int(matches.any())
        for name, rank in rankings.items():
            order = np.argsort(-rank(stability, detections.grasp_task_probs[detection]), kind="stable")
            counts[name] += int(matches[order[0]])
            counts[f"{name} top5"] += int(matches[order[:5]].any())
        counts["own-mask oracle"] += int(matches[np.argmax(np.where(where == 0, stability, -1.0))])
        counts[LANDINGS[where[np.argmax(stability)]]] += 1


def matching_candidates(detections: Detections, truth: GroundTruth, may_claim: np.ndarray,
                        detection: int) -> np.ndarray:
    """(K,) bool: the candidates of a detection that match a grasp of an object it may claim (``claimable``)."""
    of_claimable = np.isin(truth.grasp_objects, np.nonzero(may_claim[detection])[0])
    if not of_claimable.any():
        return np.zeros(len(detections.grasps[detection]), dtype=bool)
    return grasp_match_matrix(detections.grasps[detection], truth.grasp_rectangles[of_claimable]).any(axis=1)


def grasp_oracle(detections: Detections, truth: GroundTruth) -> Detections:
    """The detections with the candidates that match a grasp of a claimable object ranked first (stability + 1)."""
    stability = np.array(detections.grasp_stability, dtype=np.float64, copy=True)
    may_claim, _ = claimable(detections, truth)
    for detection in range(len(stability)):
        stability[detection] += matching_candidates(detections, truth, may_claim, detection)
    return replace(detections, grasp_stability=stability)


def scored_by_top_grasp(detections: Detections, truth: GroundTruth) -> Detections:
    """The detections with each score multiplied by the P(stable) of its top-1 candidate."""
    stability = np.asarray(detections.grasp_stability, dtype=np.float64)
    if stability.size == 0:
        return detections
    return replace(detections, scores=np.asarray(detections.scores) * stability.max(axis=1))


#: A key of ``handed_out``: (detections, truth, their ``claimable`` matrix, detection) -> larger ranks first.
DetectionKey = Callable[[Detections, GroundTruth, np.ndarray, int], float]


def handed_out(pairs: list[tuple[Detections, GroundTruth]], key: DetectionKey,
               ) -> list[tuple[Detections, GroundTruth]]:
    """The pairs with the scores of the detections that may claim an object handed out again.

    Per category over all pairs, those detections take their own scores back
    in the order of ``key`` (ties: the detector's order); the other
    detections keep theirs.
    """
    scores = [np.array(detections.scores, dtype=np.float64, copy=True) for detections, _ in pairs]
    groups: dict[int, list[tuple[float, float, int, int]]] = {}
    for image, (detections, truth) in enumerate(pairs):
        may_claim, _ = claimable(detections, truth)
        for detection in np.nonzero(may_claim.any(axis=1))[0]:
            groups.setdefault(int(detections.categories[detection]), []).append(
                (key(detections, truth, may_claim, int(detection)), float(scores[image][detection]), image,
                 int(detection)))
    for group in groups.values():
        values = sorted((score for _, score, _, _ in group), reverse=True)
        for value, (_, _, image, detection) in zip(values, sorted(group, key=lambda e: (-e[0], -e[1])), strict=True):
            scores[image][detection] = value
    return [(replace(detections, scores=new), truth) for (detections, truth), new in zip(pairs, scores, strict=True)]


def top1_grasp(detections: Detections, detection: int) -> np.ndarray:
    """The detection's most stable candidate (the one mAP-G judges): its rectangle ``(x, y, h, w, theta)``, (5,)
    float64."""
    top = int(np.argmax(detections.grasp_stability[detection]))
    return np.asarray(detections.grasps[detection], np.float64)[top]


def top1_matches(detections: Detections, truth: GroundTruth, may_claim: np.ndarray, detection: int) -> float:
    """1.0 if the top-1 candidate matches a grasp of an object the detection may claim; else (or with none) 0.0."""
    if len(detections.grasp_stability[detection]) == 0:
        return 0.0
    top = int(np.argmax(detections.grasp_stability[detection]))
    return float(matching_candidates(detections, truth, may_claim, detection)[top])


def order_oracle(pairs: list[tuple[Detections, GroundTruth]]) -> list[tuple[Detections, GroundTruth]]:
    """The pairs with the claimable detections whose top-1 matches ranked first (module doc)."""
    return handed_out(pairs, top1_matches)


def ranked_by(name: str) -> Callable[[Detections, GroundTruth], Detections]:
    """A variant whose detections carry the key of ``RANKINGS[name]`` as their P(stable) (their top-1 moves)."""
    rank = RANKINGS[name]

    def variant(detections: Detections, truth: GroundTruth) -> Detections:
        keys = [rank(np.asarray(stability, dtype=np.float64), tasks)
                for stability, tasks in zip(detections.grasp_stability, detections.grasp_task_probs, strict=True)]
        return replace(detections, grasp_stability=np.asarray(keys).reshape(np.shape(detections.grasp_stability)))

    variant.ranking = name  # read by for_branch
    return variant


#: The variants of the Table II figures: the same detections, as scored by ``togcrf eval`` or changed.
TABLE_VARIANTS = {
    "detector": lambda detections, truth: detections,
    "grasp oracle": grasp_oracle,
    "smooth-cells ranking": ranked_by("smooth-cells"),
    "score x top-1 stability": scored_by_top_grasp,
}
#: The metric columns of Table II (``togcrf.evaluate``'s, without the speed).
METRIC_COLUMNS = TABLE_COLUMNS[:-1]


def table_figures(pairs: list[tuple[Detections, GroundTruth]], categories: Sequence[str] = CATEGORIES,
                  ) -> dict[str, float]:
    """Table II figures (percent, our protocol, ``METRIC_COLUMNS``) of the (detections, truth) pairs, whose
    category indices index ``categories`` (the model's)."""
    evaluator = TableTwoEvaluator(categories=categories)
    for detections, truth in pairs:
        evaluator.add(detections, truth)
    result = evaluator.result()
    return {column: round(100.0 * float(result[column]), 1) for column in METRIC_COLUMNS}


def table_rows(pairs: list[tuple[Detections, GroundTruth]], variants: dict = TABLE_VARIANTS,
               categories: Sequence[str] = CATEGORIES) -> dict[str, dict[str, float]]:
    """Table II figures of each of ``variants`` over the (detections, truth) pairs."""
    return {name: table_figures([(variant(detections, truth), truth) for detections, truth in pairs], categories)
            for name, variant in variants.items()}


def for_branch(grasp_branch: str) -> tuple[dict, dict]:
    """The ``RANKINGS`` and ``TABLE_VARIANTS`` that apply to a model's grasp branch ("roi" or "image").

    The "image" branch (FCGN + Task) skips ``GRID_RANKINGS`` and the variants ranked by them (``ranked_by``).
    """
    if grasp_branch == "roi":
        return RANKINGS, TABLE_VARIANTS
    rankings = {name: rank for name, rank in RANKINGS.items() if name not in GRID_RANKINGS}
    variants = {name: variant for name, variant in TABLE_VARIANTS.items()
                if getattr(variant, "ranking", None) not in GRID_RANKINGS}
    return rankings, variants


def checkpoint_parser(doc: str, pipeline: str | None = None) -> argparse.ArgumentParser:
    """The arguments of this command line and of the tools that import it: a checkpoint, ``--data``, ``--pipeline``."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n", maxsplit=1)[0])
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("--data", type=Path, default=Path("data"))
    parser.add_argument("--pipeline", default=pipeline)
    return parser


def table_line(name: str, row: dict[str, float], width: int = 34) -> str:
    """One printed line of Table II figures (percent): the variant's name, then each column and its value."""
    return f"  {name:{width}s} " + "  ".join(f"{column} {value:5.1f}" for column, value in row.items())


def print_variants(variants: dict[str, list[tuple[Detections, GroundTruth]]], width: int) -> None:
    """Print the Table II figures (our protocol) of each variant of the same test samples' detections."""
    print(f"Table II figures of {len(next(iter(variants.values())))} test samples (percent, our protocol):")
    for name, pairs in variants.items():
        print(table_line(name, table_figures(pairs), width))


def main() -> None:
    parser = checkpoint_parser(__doc__)
    parser.add_argument("--split", default="test")
    parser.add_argument("--max-samples", type=int, default=100)
    parser.add_argument("--json", type=Path, default=None, help="also write the shares here")
    parser.add_argument("--views", type=int, default=1, help="test-time views (togcrf.tta): 1, 2, 4 or 8")
    arguments = parser.parse_args()
    model, config = load_checkpoint(arguments.checkpoint, device="cpu")
    model.eval()
    rankings, variants = for_branch(model.grasp_branch)
    counts: dict[str, int] = {"objects": 0, "any candidate": 0} | {
        key: 0 for name in rankings for key in (name, f"{name} top5")} | dict.fromkeys(
        ("own-mask oracle", *LANDINGS), 0)
    distances: dict[str, list[float]] = {"match": [], "miss": []}
    pairs = []
    samples = iter_samples(arguments.data, split=arguments.split,
                           shards=sample_shards(arguments.data, arguments.pipeline))
    for sample in islice(samples, arguments.max_samples):
        pairs.append(detect(model, config, sample, arguments.views))
        tally(*pairs[-1], sample.mask, sample.object_indices, counts, distances, rankings)
    objects = max(counts["objects"], 1)
    shares = {name: round(100.0 * value / objects, 1) for name, value in counts.items() if name != "objects"}
    print(f"{counts['objects']} claimed objects with grasps; share whose top-1 (top-5) grasp matches one of theirs, "
          "and where the top-1 lands:")
    for name, share in shares.items():
        print(f"  {name:34s} {share:5.1f} %")
    quartiles = {outcome: [round(float(value), 1) for value in np.percentile(values, (25, 50, 75))] if values else []
                 for outcome, values in distances.items()}
    for outcome, values in quartiles.items():
        print(f"  top-1 {outcome}es ({len(distances[outcome])}): distance to the nearest ground-truth grasp centre, "
              f"quartiles {values} px")
    categories = model.vocabulary["categories"]
    rows = table_rows(pairs, variants, categories) | {"order oracle": table_figures(order_oracle(pairs), categories)}
    print(f"Table II figures of these {len(pairs)} samples (percent, our protocol):")
    for name, row in rows.items():
        print(table_line(name, row))
    if arguments.json:
        arguments.json.write_text(json.dumps({"checkpoint": str(arguments.checkpoint), "views": arguments.views,
                                              "objects": counts["objects"],
                                              "shares_percent": shares,
                                              "top1_distance_quartiles_px": quartiles,
                                              "table_percent": rows}, indent=1) + "\n")


if __name__ == "__main__":
    torch.set_num_threads(1)
    main()
