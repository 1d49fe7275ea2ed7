"""Where mAP-G is lost, category by category (a diagnostic, issue #15).

Usage::

    python lab/results/top1-categories-2026-11-30/categories.py CHECKPOINT EVAL.json OUT.json [--samples N]

For each category of the first N (206) test samples of the ``recipe`` pipeline in ``data/``: its test objects,
the share of them without a ground-truth grasp (no detection can claim those for mAP-G), the objects with grasps
that a detection claims (the rule of ``benchmarks/grasp_ranking.py``, ``claimed_objects``) and how their top-1
grasp lands (``match``, ``near``, ``far``: ``lab/results/top1-misses-2026-11-29/misses.py``), beside the
category's AP and AP-G from ``EVAL.json`` (``togcrf eval`` of the same checkpoint).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from itertools import islice
from pathlib import Path

import numpy as np
import torch

from osgd.contract.samples import iter_samples, sample_shards
from osgd.contract.taxonomy import CATEGORIES
from togcrf.checkpoint import load_checkpoint

ROOT = Path(__file__).resolve().parents[3]
GROUPS = ("match", "near", "far")


def tally(detections, truth, counts: dict[str, Counter]) -> None:
    """Add one sample's objects and its claimed objects' top-1 groups to ``counts`` (per category)."""
    from grasp_ranking import claimed_objects, top1_grasp  # noqa: PLC0415 (benchmarks/, put on the path by main)
    from misses import group_of  # noqa: PLC0415 (lab/results/top1-misses-2026-11-29/, the same)

    for index, category in enumerate(truth.categories):
        name = CATEGORIES[int(category)]
        counts[name]["objects"] += 1
        counts[name]["without a grasp"] += int(not np.any(truth.grasp_objects == index))
    for detection, target in claimed_objects(detections, truth):
        grasps = truth.grasp_rectangles[truth.grasp_objects == target]
        counts[CATEGORIES[int(truth.categories[target])]][group_of(top1_grasp(detections, detection), grasps)] += 1


def report(counts: dict[str, Counter], evaluation: dict) -> dict:
    """Per category and in all: the counts of ``tally`` as shares, with AP and AP-G (percent)."""
    rows = {}
    for name in [*CATEGORIES, "all"]:
        count = sum(counts.values(), Counter()) if name == "all" else counts.get(name, Counter())
        if not count["objects"]:
            continue
        claimed = sum(count[group] for group in GROUPS)
        metrics = evaluation["metrics"]
        rows[name] = {
            "objects": count["objects"],
            "without a grasp %": round(100.0 * count["without a grasp"] / count["objects"], 1),
            "claimed with grasps": claimed,
            **{f"{group} %": round(100.0 * count[group] / max(claimed, 1), 1) for group in GROUPS},
            "AP": round(100.0 * (metrics["mAP"] if name == "all" else metrics["AP"][name]), 1),
            "AP-G": round(100.0 * (metrics["mAP-G"] if name == "all" else metrics["AP-G"][name]), 1),
        }
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("evaluation", type=Path)
    parser.add_argument("json", type=Path)
    parser.add_argument("--samples", type=int, default=206)
    arguments = parser.parse_args()
    sys.path[:0] = [str(ROOT / "benchmarks"), str(ROOT / "docs" / "results" / "top1-misses-2026-11-29")]
    from grasp_ranking import detect  # noqa: PLC0415

    torch.set_num_threads(1)
    model, config = load_checkpoint(arguments.checkpoint, device="cpu")
    model.eval()
    counts: dict[str, Counter] = {}
    samples = iter_samples("data", split="test", shards=sample_shards("data", "recipe"))
    for sample in islice(samples, arguments.samples):
        detections, truth = detect(model, config, sample)
        for category in truth.categories:
            counts.setdefault(CATEGORIES[int(category)], Counter())
        tally(detections, truth, counts)
    rows = report(counts, json.loads(arguments.evaluation.read_text()))
    arguments.json.write_text(json.dumps({"checkpoint": str(arguments.checkpoint), "samples": arguments.samples,
                                          "categories": rows}, indent=1) + "\n")
    header = ["category", *next(iter(rows.values())).keys()]
    print(" | ".join(header))
    for name, row in rows.items():
        print(" | ".join([name, *map(str, row.values())]))


if __name__ == "__main__":
    main()
