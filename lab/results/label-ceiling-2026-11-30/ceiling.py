"""How often could a perfect grasp detector's top-1 match the recipe's ground truth? (a diagnostic, issue #15)

Usage::

    python lab/results/label-ceiling-2026-11-30/ceiling.py OUT.json [--samples N] [--draws K]

The recipe's ground truth keeps, of an object's stable, visible, collision-free grasps, one per 1.5 cm: the
samples stage's suppression (``osgd.samples.projection.suppress``, radius ``nms_radius``) visits them from the
closing line most parallel to the image plane down. ``pipelines/recipe-dense.toml`` has the same piles and images
with every such grasp kept (``nms_radius = 0``), so on each test object the recipe's grasps are the suppression of
the dense ones (checked here: ``suppression reproduces the recipe``).

A detector that knew every valid grasp of an object exactly, but not which of them the suppression keeps, would
still have to guess. This script measures that guess on the first N (206) test samples, for each object with a
grasp in both ground truths: it redraws the suppression K (32) times with the visiting order's key, the angle
to the optical axis, perturbed (Gaussian noise of 1, 3 or 10 degrees, or a random order), and scores every dense
grasp by how often it matches (the mAP-G rule, ``togcrf.metrics.grasp_match_matrix``) one grasp kept by a draw.

- ``best``: the mean over objects of the best dense grasp's match rate: the top-1 match of a detector that
  picks the valid grasp most likely to be kept, knowing the angles up to that noise;
- ``random valid``: the mean match rate of a dense grasp drawn at random;
- ``random valid, recipe``: the share of the dense grasps that match a grasp of the recipe itself.

The detector's own top-1 matches for 61-65 % of the claimed objects (``docs/togcrf-evaluation.md``, "Where the
top-1 misses"); the goal of 40 mAP-G asks about 76-80 % at the recipe's mAP.
"""

from __future__ import annotations

import argparse
import json
from itertools import islice
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from osgd.contract.samples import Sample, iter_samples, sample_shards
from osgd.samples.projection import angle_to_optical_axis, suppress
from togcrf.metrics import grasp_match_matrix

NMS_RADIUS = 0.015  # metres: pipelines/recipe.toml's nms_radius (the samples stage's default, docs/samples.md)
NOISES = {"1 degree": np.radians(1.0), "3 degrees": np.radians(3.0), "10 degrees": np.radians(10.0),
          "random order": None}


def object_grasps(sample: Sample, row: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One object's (G, 5) rectangles, (G, 3) camera-frame centres and (G,) angles to the optical axis."""
    chosen = sample.grasp_objects == row
    closing = Rotation.from_quat(sample.grasp_quaternions[chosen]).as_matrix()[:, :, 0]
    return (sample.grasp_rectangles[chosen].astype(np.float64), sample.grasp_positions[chosen],
            angle_to_optical_axis(closing))


def match_rates(dense: tuple, noise: float | None, draws: int, rng: np.random.Generator) -> np.ndarray:
    """(G,) how often each dense grasp matches a grasp kept by a redrawn suppression."""
    rectangles, centres, angles = dense
    hits = np.zeros(len(rectangles))
    for _ in range(draws):
        keys = rng.random(len(angles)) if noise is None else angles + rng.normal(0.0, noise, len(angles))
        kept = suppress(centres, keys, NMS_RADIUS)
        hits += grasp_match_matrix(rectangles, rectangles[kept]).any(axis=1)
    return hits / draws


def tally(recipe: Sample, dense: Sample, draws: int, rng: np.random.Generator, records: dict) -> None:
    """Add one test sample's objects (with grasps in both ground truths) to ``records``."""
    dense_row = {int(index): row for row, index in enumerate(dense.object_indices)}
    for row, index in enumerate(recipe.object_indices):
        if not np.any(recipe.grasp_objects == row) or int(index) not in dense_row:
            continue
        truth = recipe.grasp_rectangles[recipe.grasp_objects == row].astype(np.float64)
        grasps = object_grasps(dense, dense_row[int(index)])
        redone = grasps[0][np.sort(suppress(grasps[1], grasps[2], NMS_RADIUS))]
        records["reproduced"].append(len(redone) == len(truth) and np.allclose(np.sort(redone, axis=0),
                                                                               np.sort(truth, axis=0), atol=1e-3))
        records["random valid, recipe"].append(grasp_match_matrix(grasps[0], truth).any(axis=1).mean())
        for name, noise in NOISES.items():
            rates = match_rates(grasps, noise, draws, rng)
            records[f"best, {name}"].append(rates.max())
            records[f"random valid, {name}"].append(rates.mean())
        records["dense grasps"].append(len(grasps[0]))
        records["recipe grasps"].append(len(truth))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("json", type=Path)
    parser.add_argument("--samples", type=int, default=206)
    parser.add_argument("--draws", type=int, default=32)
    arguments = parser.parse_args()
    rng = np.random.default_rng(0)
    records: dict[str, list] = {"reproduced": [], "random valid, recipe": [], "dense grasps": [],
                                "recipe grasps": []}
    for name in NOISES:
        records[f"best, {name}"], records[f"random valid, {name}"] = [], []
    dense = {sample.sample_id: sample for sample in islice(
        iter_samples("data", split="test", shards=sample_shards("data", "recipe-dense")), arguments.samples)}
    for recipe in islice(iter_samples("data", split="test", shards=sample_shards("data", "recipe")),
                         arguments.samples):
        tally(recipe, dense[recipe.sample_id], arguments.draws, rng, records)
    report = {"samples": arguments.samples, "draws": arguments.draws, "objects": len(records["reproduced"]),
              "suppression reproduces the recipe %": round(100.0 * np.mean(records["reproduced"]), 1),
              "grasps per object, dense / recipe": [round(float(np.mean(records["dense grasps"])), 2),
                                                    round(float(np.mean(records["recipe grasps"])), 2)]}
    report |= {f"{name} %": round(100.0 * float(np.mean(values)), 1) for name, values in records.items()
               if name.startswith(("best", "random"))}
    arguments.json.write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
