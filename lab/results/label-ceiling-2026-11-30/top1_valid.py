"""Does a checkpoint's top-1 grasp land on a valid grasp? (a diagnostic, issue #15)

Usage::

    python lab/results/label-ceiling-2026-11-30/top1_valid.py CHECKPOINT OUT.json [--samples N]

For each detection that claims an object with ground-truth grasps on the first N (206) test samples of the
``recipe`` pipeline (the rule of ``benchmarks/grasp_ranking.py``, ``claimed_objects``): whether its top-1 grasp
matches (the mAP-G rule) one of the object's grasps in the recipe's ground truth, and whether it matches one of
the object's grasps in ``recipe-dense`` (the same piles and images with every stable, visible, collision-free grasp
kept: ``pipelines/recipe-dense.toml``, which must be built). ``ceiling.py`` beside it says how often a valid grasp
matches the recipe's ground truth.
"""

from __future__ import annotations

import argparse
import json
import sys
from itertools import islice
from pathlib import Path

import torch

from osgd.contract.samples import iter_samples, sample_shards
from togcrf.checkpoint import load_checkpoint
from togcrf.metrics import grasp_match_matrix

ROOT = Path(__file__).resolve().parents[3]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("json", type=Path)
    parser.add_argument("--samples", type=int, default=206)
    arguments = parser.parse_args()
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from grasp_ranking import claimed_objects, detect, top1_grasp  # noqa: PLC0415

    torch.set_num_threads(1)
    model, config = load_checkpoint(arguments.checkpoint, device="cpu")
    model.eval()
    dense = {sample.sample_id: sample for sample in islice(
        iter_samples("data", split="test", shards=sample_shards("data", "recipe-dense")), arguments.samples)}
    claimed = recipe_hits = dense_hits = 0
    for sample in islice(iter_samples("data", split="test", shards=sample_shards("data", "recipe")),
                         arguments.samples):
        detections, truth = detect(model, config, sample)
        valid = dense[sample.sample_id]
        dense_row = {int(index): row for row, index in enumerate(valid.object_indices)}
        for detection, target in claimed_objects(detections, truth):
            top = top1_grasp(detections, detection)[None]
            grasps = truth.grasp_rectangles[truth.grasp_objects == target]
            valid_grasps = valid.grasp_rectangles[valid.grasp_objects == dense_row[int(sample.object_indices[target])]]
            claimed += 1
            recipe_hits += bool(grasp_match_matrix(top, grasps).any())
            dense_hits += bool(len(valid_grasps) and grasp_match_matrix(top, valid_grasps).any())
    report = {"checkpoint": str(arguments.checkpoint), "samples": arguments.samples, "claimed objects": claimed,
              "top-1 matches the recipe's ground truth %": round(100.0 * recipe_hits / max(claimed, 1), 1),
              "top-1 matches a valid grasp (recipe-dense) %": round(100.0 * dense_hits / max(claimed, 1), 1)}
    arguments.json.write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
