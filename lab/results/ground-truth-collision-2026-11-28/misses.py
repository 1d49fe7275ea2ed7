"""Draw each claimed object's top-1 grasp over two ground truths, on the first test samples (a diagnostic).

Usage::

    python lab/results/ground-truth-collision-2026-11-28/misses.py CHECKPOINT OUT.png [SAMPLES]

For each of the first SAMPLES (6) test samples of the ``recipe`` pipeline in ``data/``, the checkpoint's
detections with a score of at least 0.5 that claim an object with grasps (the rule of
``benchmarks/grasp_ranking.py``, ``claimed_objects``) get their most stable grasp drawn: red where it matches
one of that object's ground-truth grasps (the mAP-G rule, :func:`togcrf.metrics.grasp_match_matrix`), magenta
where it does not. Thin green: the recipe's ground truth;
thin yellow: the grasps of ``recipe-nocollide`` (the same image without the gripper-collision filter). The picture
shows the noise-free depth; the model sees the noisy one. Prints
how many objects were claimed and how many top-1 grasps match either ground truth.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from osgd.contract.samples import Sample, iter_samples
from togcrf.checkpoint import load_checkpoint
from togcrf.metrics import GroundTruth, grasp_match_matrix, rectangle_corners
from togcrf.predict import keep_confident, predict_depth

ZOOM = 1.5
GREEN, YELLOW, RED, MAGENTA, CYAN = (0, 200, 0), (0, 220, 220), (0, 0, 255), (255, 0, 255), (255, 255, 0)


def depth_picture(depth: np.ndarray) -> np.ndarray:
    """Nearer is brighter, over the 15 cm below the highest reading."""
    valid = depth > 0
    grey = np.zeros(depth.shape, np.uint8)
    grey[valid] = np.clip((depth[valid].max() - depth[valid]) / 0.15 * 255, 0, 255)
    return cv2.resize(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR), None, fx=ZOOM, fy=ZOOM, interpolation=cv2.INTER_NEAREST)


def draw(picture: np.ndarray, rectangle: np.ndarray, colour: tuple[int, int, int], thickness: int) -> None:
    corners = rectangle_corners(np.asarray(rectangle, np.float64)[None])[0] * ZOOM
    cv2.polylines(picture, [corners.astype(np.int32)], True, colour, thickness)


def tile(model: object, config: dict, sample: Sample, other: Sample, counts: np.ndarray) -> np.ndarray:
    from grasp_ranking import claimed_objects  # noqa: PLC0415 (benchmarks/, put on the path by main)

    picture = depth_picture(sample.depth_clean)
    for rectangle in other.grasp_rectangles:
        draw(picture, rectangle, YELLOW, 1)
    for rectangle in sample.grasp_rectangles:
        draw(picture, rectangle, GREEN, 2)
    detections = keep_confident(predict_depth(model, sample.depth, config["image_size"],
                                              depth_reference=config.get("depth_reference", "table")), 0.5)
    truths = (GroundTruth.from_sample(sample), GroundTruth.from_sample(other))
    for detection, claimed in claimed_objects(detections, truths[0]):
        top = detections.grasps[detection][int(np.argmax(detections.grasp_stability[detection]))][None]
        matches = [bool(grasp_match_matrix(top, truth.grasp_rectangles[truth.grasp_objects == claimed]).any())
                   for truth in truths]
        counts += [1, *matches]
        draw(picture, top[0], RED if matches[0] else MAGENTA, 3)
        x, y = (detections.boxes[detection][:2] * ZOOM).astype(int)
        cv2.putText(picture, sample.categories[claimed], (x, max(y, 12)), cv2.FONT_HERSHEY_SIMPLEX, 0.5, CYAN, 1)
    return picture


def main() -> None:
    checkpoint, out = sys.argv[1], sys.argv[2]
    sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
    count = int(sys.argv[3]) if len(sys.argv) > 3 else 6
    model, config = load_checkpoint(checkpoint)
    others = {sample.sample_id: sample for sample in iter_samples("data", "recipe-nocollide", split="test")}
    counts = np.zeros(3, int)
    tiles = []
    for sample in iter_samples("data", "recipe", split="test"):
        if len(tiles) == count:
            break
        tiles.append(tile(model, config, sample, others[sample.sample_id], counts))
    rows = [np.hstack(tiles[start:start + 3]) for start in range(0, len(tiles) - len(tiles) % 3, 3)]
    cv2.imwrite(out, np.vstack(rows))
    print(f"{counts[0]} claimed objects; top-1 matches the recipe's ground truth for {counts[1]}, "
          f"recipe-nocollide's for {counts[2]}")


if __name__ == "__main__":
    main()
