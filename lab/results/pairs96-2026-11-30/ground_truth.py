"""How twice the sampled grasps per tool change the test ground truth (a diagnostic, issue #15).

Usage::

    python lab/results/pairs96-2026-11-30/ground_truth.py OUT.json [--data data] [--split test]

``recipe`` and ``recipe-pairs96`` share their piles and depth images; only the grasps stage's
``sampler_max_pairs`` differs (48 and 96). For the samples of one split, read side by side, this counts the
annotated objects, those with at least one ground-truth grasp, the grasps per such object, and, object by object,
the share of one pipeline's ground-truth grasps that match one of the other's (the mAP-G rule,
``togcrf.metrics.grasp_match_matrix``): how much of the old ground truth the new one keeps, and how much it adds.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np

from osgd.contract.samples import iter_samples
from togcrf.metrics import grasp_match_matrix

PIPELINES = ("recipe", "recipe-pairs96")


def object_grasps(sample) -> dict[int, np.ndarray]:
    """The ground-truth rectangles of each annotated object of a sample, by its index in the scene."""
    return {int(index): sample.grasp_rectangles[sample.grasp_objects == row]
            for row, index in enumerate(sample.object_indices)}


def compare(data: Path, split: str) -> dict:
    """The counts of the module's docstring over every sample of ``split``."""
    counts: Counter = Counter()
    samples = zip(*(iter_samples(data, pipeline, split=split) for pipeline in PIPELINES), strict=True)
    for old, new in samples:
        if old.sample_id != new.sample_id:
            raise SystemExit(f"the pipelines' samples differ: {old.sample_id} against {new.sample_id}")
        old_grasps, new_grasps = object_grasps(old), object_grasps(new)
        for pipeline, per_object in zip(PIPELINES, (old_grasps, new_grasps), strict=True):
            counts[pipeline, "objects"] += len(per_object)
            counts[pipeline, "with grasps"] += sum(len(rectangles) > 0 for rectangles in per_object.values())
            counts[pipeline, "grasps"] += sum(len(rectangles) for rectangles in per_object.values())
        for index, old_rectangles in old_grasps.items():
            match = grasp_match_matrix(old_rectangles, new_grasps[index])
            counts["recipe", "matched"] += int(match.any(axis=1).sum())
            counts["recipe-pairs96", "matched"] += int(match.any(axis=0).sum())

    def share(pipeline: str) -> float:
        return round(100.0 * counts[pipeline, "matched"] / max(counts[pipeline, "grasps"], 1), 1)

    def totals(pipeline: str) -> dict:
        with_grasps = counts[pipeline, "with grasps"]
        return {"objects": counts[pipeline, "objects"], "objects with grasps": with_grasps,
                "grasps per object with grasps": round(counts[pipeline, "grasps"] / max(with_grasps, 1), 2)}

    return {"split": split, **{pipeline: totals(pipeline) for pipeline in PIPELINES},
            "recipe grasps matching a recipe-pairs96 grasp": share("recipe"),
            "recipe-pairs96 grasps matching a recipe grasp": share("recipe-pairs96")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("json", type=Path)
    parser.add_argument("--data", type=Path, default=Path("data"))
    parser.add_argument("--split", default="test")
    arguments = parser.parse_args()
    report = compare(arguments.data, arguments.split)
    arguments.json.write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
