"""Why the top-1 grasp of a claimed object misses: near and far misses, cells and the regression (a diagnostic).

Usage::

    python lab/results/top1-misses-2026-11-29/misses.py CHECKPOINT OUT.json [OUT.png] [--samples N]

For each detection that claims an object with ground-truth grasps on the first N (206) test samples of the
``recipe`` pipeline in ``data/`` (the rule of ``benchmarks/grasp_ranking.py``, ``claimed_objects``), its most
stable candidate (the top-1) is sorted into:

- ``match``: it matches one of the object's grasps (the mAP-G rule, ``togcrf.metrics.grasp_match_matrix``);
- ``near``: it misses, but overlaps a grasp of the object within the angle tolerance (Jaccard in (0, 0.25]);
- ``far``: it overlaps none of them at that angle.

For each group it reports the size of the detection's cells (7 x 7, or the model's ``grasp_grid``), how far
the regression moved the top-1's centre from its anchor (the cell centre), and the Chebyshev distance, in
cells, from the top-1's cell to the nearest cell that holds a ground-truth grasp centre of the object (0: the
same cell). Then, for every ground-truth grasp of a claimed object, the candidate at its cell and anchor angle
(its positive anchor): how well that candidate's predicted centre offset from the cell centre follows the
grasp's own (slope and correlation per image axis) and how often it matches the grasp, against the anchor left
at the cell centre.

The picture (optional) shows up to six objects of each group (rows: near, far, match), cropped around the
detection on the noise-free depth: the cells (grey), the object's ground-truth grasps (green), the
next four candidates (blue) and the top-1 (red where it matches, magenta where not).
"""

from __future__ import annotations

import argparse
import json
import sys
from itertools import islice
from pathlib import Path

import cv2
import numpy as np
import torch

from osgd.contract.samples import Sample, iter_samples, sample_shards
from togcrf.anchors import ANCHOR_ANGLES
from togcrf.checkpoint import load_checkpoint
from togcrf.metrics import (
    GRASP_ANGLE_TOLERANCE,
    Detections,
    GroundTruth,
    angle_difference,
    grasp_match_matrix,
    rectangle_corners,
    rectangle_jaccard,
)

GROUPS = ("match", "near", "far")
TILE = 200
GREY, GREEN, BLUE = (90, 90, 90), (0, 200, 0), (255, 200, 0)
RED, MAGENTA, CYAN = (0, 0, 255), (255, 0, 255), (255, 255, 0)


def group_of(top: np.ndarray, grasps: np.ndarray) -> str:
    """``match``, ``near`` or ``far`` for one top-1 rectangle against its object's (M, 5) grasps."""
    if grasp_match_matrix(top[None], grasps).any():
        return "match"
    close = angle_difference(top[4], grasps[:, 4]) < GRASP_ANGLE_TOLERANCE
    return "near" if (close & (rectangle_jaccard(top[None], grasps)[0] > 0)).any() else "far"


def cells(box: np.ndarray, points: np.ndarray, grid: int) -> tuple[np.ndarray, np.ndarray]:
    """(row, column) of the grid x grid cell of each (n, 2) point in ``box``, and the cell size (x, y)."""
    size = (box[2:] - box[:2]) / grid
    return np.floor((points - box[:2]) / size).astype(int)[:, ::-1], size


def crop(sample: Sample, detections: Detections, detection: int, target: int, grasps: np.ndarray,
         group: str, grid: int) -> np.ndarray:
    """One tile of the picture (module doc)."""
    depth = sample.depth_clean
    grey = np.zeros(depth.shape, np.uint8)
    valid = depth > 0
    grey[valid] = np.clip((depth[valid].max() - depth[valid]) / 0.15 * 255, 0, 255)
    box = np.asarray(detections.boxes[detection], np.float64)
    side = max(box[2] - box[0], box[3] - box[1]) * 1.2 + 8
    origin = (box[:2] + box[2:]) / 2 - side / 2
    zoom = TILE / side
    affine = np.array([[zoom, 0, -origin[0] * zoom], [0, zoom, -origin[1] * zoom]])
    tile = cv2.cvtColor(cv2.warpAffine(grey, affine, (TILE, TILE), flags=cv2.INTER_NEAREST), cv2.COLOR_GRAY2BGR)

    def to_tile(points: np.ndarray) -> np.ndarray:
        return ((points - origin) * zoom).astype(np.int32)

    for step in range(grid + 1):
        x, y = box[:2] + step * (box[2:] - box[:2]) / grid
        cv2.line(tile, *map(tuple, to_tile(np.array([[x, box[1]], [x, box[3]]]))), GREY, 1)
        cv2.line(tile, *map(tuple, to_tile(np.array([[box[0], y], [box[2], y]]))), GREY, 1)
    order = np.argsort(-np.asarray(detections.grasp_stability[detection]), kind="stable")
    for rectangle, colour, width in ([(grasp, GREEN, 2) for grasp in grasps]
                                     + [(detections.grasps[detection][k], BLUE, 1) for k in order[1:5]]
                                     + [(detections.grasps[detection][order[0]],
                                         RED if group == "match" else MAGENTA, 2)]):
        cv2.polylines(tile, [to_tile(rectangle_corners(np.asarray(rectangle, np.float64)[None])[0])], True,
                      colour, width)
    cv2.putText(tile, f"{group}: {sample.categories[target]}", (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.45, CYAN, 1)
    return tile


def tally(detections: Detections, truth: GroundTruth, sample: Sample, records: dict, tiles: dict,
          grid: int) -> None:
    """Add one sample's claimed objects to ``records`` (per group: cell size, centre shift, cell distance) and
    its positive-anchor candidates to ``records["positive"]``; up to six tiles per group to ``tiles``."""
    from grasp_ranking import claimed_objects  # noqa: PLC0415 (benchmarks/, put on the path by main)

    angles = np.asarray(ANCHOR_ANGLES)
    for detection, target in claimed_objects(detections, truth):
        grasps = truth.grasp_rectangles[truth.grasp_objects == target]
        box = np.asarray(detections.boxes[detection], np.float64)
        candidates = np.asarray(detections.grasps[detection], np.float64)
        top_index = int(np.argmax(detections.grasp_stability[detection]))
        top = candidates[top_index]
        group = group_of(top, grasps)
        top_cell = np.array(divmod(top_index // len(angles), grid))
        grasp_cells, size = cells(box, grasps[:, :2], grid)
        distance = np.abs(grasp_cells - top_cell).max(axis=1).min()
        shift = np.linalg.norm(top[:2] - (box[:2] + (top_cell[::-1] + 0.5) * size))
        records[group].append((float(size.mean()), float(shift), int(distance)))
        if len(tiles[group]) < 6:
            tiles[group].append(crop(sample, detections, detection, target, grasps, group, grid))
        inside = ((grasp_cells >= 0) & (grasp_cells < grid)).all(axis=1)
        for grasp, (row, column) in zip(grasps[inside], grasp_cells[inside], strict=True):
            anchor = (row * grid + column) * len(angles) + int(np.argmin(angle_difference(grasp[4], angles)))
            predicted = candidates[anchor]
            cell_centre = box[:2] + (np.array([column, row]) + 0.5) * size
            unmoved = predicted.copy()
            unmoved[:2] = cell_centre
            records["positive"].append((*(predicted[:2] - cell_centre), *(grasp[:2] - cell_centre),
                                        bool(grasp_match_matrix(predicted[None], grasp[None])[0, 0]),
                                        bool(grasp_match_matrix(unmoved[None], grasp[None])[0, 0])))


def summary(records: dict) -> dict:
    """The report of ``tally``'s records (module doc)."""
    objects = sum(len(records[group]) for group in GROUPS)
    report: dict = {"claimed objects with grasps": objects}
    for group in GROUPS:
        values = np.asarray(records[group], np.float64).reshape(-1, 3)
        report[group] = {
            "objects": len(values), "share_percent": round(100.0 * len(values) / max(objects, 1), 1),
            "cell_size_px_median": round(float(np.median(values[:, 0])), 1) if len(values) else None,
            "centre_shift_px_quartiles": np.percentile(values[:, 1], (25, 50, 75)).round(1).tolist()
            if len(values) else [],
            "cells_to_nearest_grasp_cell": np.bincount(np.minimum(values[:, 2], 3).astype(int),
                                                       minlength=4).tolist(),
        }
    positive = np.asarray(records["positive"], np.float64).reshape(-1, 6)
    axes = {}
    for axis, name in enumerate("xy"):
        predicted, truth = positive[:, axis], positive[:, 2 + axis]
        axes[name] = {"slope": round(float(predicted @ truth / (truth @ truth)), 3),
                      "correlation": round(float(np.corrcoef(predicted, truth)[0, 1]), 3)}
    report["positive anchors"] = {
        "grasps": len(positive), "centre_offset_vs_grasp_offset": axes,
        "mean_abs_offset_px": {"predicted": round(float(np.abs(positive[:, :2]).mean()), 2),
                               "grasp": round(float(np.abs(positive[:, 2:4]).mean()), 2)},
        "match_percent": round(100.0 * positive[:, 4].mean(), 1),
        "match_percent_centre_unmoved": round(100.0 * positive[:, 5].mean(), 1),
    }
    return report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("json", type=Path)
    parser.add_argument("picture", type=Path, nargs="?")
    parser.add_argument("--samples", type=int, default=206)
    arguments = parser.parse_args()
    sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
    from grasp_ranking import detect  # noqa: PLC0415

    torch.set_num_threads(1)
    model, config = load_checkpoint(arguments.checkpoint, device="cpu")
    model.eval()
    records: dict = {group: [] for group in (*GROUPS, "positive")}
    tiles: dict = {group: [] for group in GROUPS}
    samples = iter_samples("data", split="test", shards=sample_shards("data", "recipe"))
    for sample in islice(samples, arguments.samples):
        tally(*detect(model, config, sample), sample, records, tiles, model.options.grasp_grid)
    report = {"checkpoint": str(arguments.checkpoint), "samples": arguments.samples} | summary(records)
    arguments.json.write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps(report, indent=1))
    if arguments.picture:
        blank = np.zeros((TILE, TILE, 3), np.uint8)
        rows = []
        for group in ("near", "far", "match"):
            rows.append(np.hstack(tiles[group] + [blank] * (6 - len(tiles[group]))))
        cv2.imwrite(str(arguments.picture), np.vstack(rows))


if __name__ == "__main__":
    main()
