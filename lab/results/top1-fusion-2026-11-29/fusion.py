"""The top-1 grasp moved to the stability-weighted centre of its neighbours (a diagnostic, issue #15).

Usage::

    python lab/results/top1-fusion-2026-11-29/fusion.py CHECKPOINT [--data data] [--pipeline recipe] \
        [--samples 206] [--json OUT.json]

A sixth of the claimed objects get a top-1 grasp beside one of their annotated grasps, shifted along the
tool by about half a finger width, often at the end of a row of grasps (docs/togcrf-evaluation.md, "Where
the top-1 misses"). This script runs a checkpoint on the first N test samples once and scores the same
detections (our protocol, Table II figures) with each detection's top-1 rectangle moved to the
P(stable)-weighted mean centre of the candidates around it, as weighted box fusion replaces a detection
by the mean of its overlapping boxes; its size, angle, tasks and score stay. The neighbours of a top-1
are the candidates within ``ring`` cells of its cell (a square of 2 ring + 1 cells per side) at its anchor
angle (or also the ``angles`` neighbouring anchor angles), and of those the ones whose P(stable) is at
least ``floor`` times the top-1's. Only the top-1's centre moves, so mAP, the other candidates and Acc-T
top-5 / top-10 stay as they were; mAP-G and Acc-T top-1 (whose top-1 rectangle is matched) may move.
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import replace
from itertools import islice
from pathlib import Path

import numpy as np
import torch

from osgd.contract.samples import iter_samples, sample_shards
from togcrf.anchors import ANCHOR_ANGLES
from togcrf.checkpoint import load_checkpoint
from togcrf.metrics import Detections

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
from grasp_ranking import checkpoint_parser, detect, table_line, table_rows

#: The variants: name -> (ring in cells, neighbouring anchor angles, floor as a share of the top-1's P(stable)).
FUSIONS = {
    "3 x 3 cells": (1, 0, 0.0),
    "3 x 3 cells, P >= 0.5 top": (1, 0, 0.5),
    "3 x 3 cells, P >= 0.8 top": (1, 0, 0.8),
    "3 x 3 cells +- 1 angle, P >= 0.5 top": (1, 1, 0.5),
    "5 x 5 cells, P >= 0.5 top": (2, 0, 0.5),
}


def neighbours(top: int, side: int, ring: int, angles: int) -> np.ndarray:
    """Candidate indices within ``ring`` cells and ``angles`` anchor angles (cyclic) of candidate ``top``."""
    count = len(ANCHOR_ANGLES)
    row, column, angle = np.unravel_index(top, (side, side, count))
    rows = np.arange(max(row - ring, 0), min(row + ring, side - 1) + 1)
    columns = np.arange(max(column - ring, 0), min(column + ring, side - 1) + 1)
    turns = (angle + np.arange(-angles, angles + 1)) % count
    grid = np.stack(np.meshgrid(rows, columns, turns, indexing="ij")).reshape(3, -1)
    return np.ravel_multi_index(tuple(grid), (side, side, count))


def fused(detections: Detections, ring: int, angles: int, floor: float) -> Detections:
    """The detections with each top-1 centre moved to the P(stable)-weighted centre of its neighbours."""
    if len(detections.grasp_stability) == 0 or np.size(detections.grasp_stability) == 0:
        return detections
    grasps = np.array(detections.grasps, dtype=np.float64, copy=True)
    side = math.isqrt(grasps.shape[1] // len(ANCHOR_ANGLES))
    for detection, stability in enumerate(np.asarray(detections.grasp_stability, dtype=np.float64)):
        top = int(np.argmax(stability))
        around = neighbours(top, side, ring, angles)
        weights = np.where(stability[around] >= floor * stability[top], stability[around], 0.0)
        grasps[detection, top, :2] = (weights[:, None] * grasps[detection, around, :2]).sum(axis=0) / weights.sum()
    return replace(detections, grasps=grasps)


def main() -> None:
    parser = checkpoint_parser(__doc__, pipeline="recipe")
    parser.add_argument("--samples", type=int, default=206)
    parser.add_argument("--json", type=Path, default=None)
    arguments = parser.parse_args()
    torch.set_num_threads(1)
    model, config = load_checkpoint(arguments.checkpoint, device="cpu")
    model.eval()
    samples = iter_samples(arguments.data, split="test", shards=sample_shards(arguments.data, arguments.pipeline))
    pairs = [detect(model, config, sample) for sample in islice(samples, arguments.samples)]
    variants = {"detector": lambda detections, truth: detections} | {
        name: (lambda detections, truth, values=values: fused(detections, *values)) for name, values in FUSIONS.items()}
    rows = table_rows(pairs, variants)
    print(f"Table II figures of {len(pairs)} test samples (percent, our protocol), {arguments.checkpoint}:")
    for name, row in rows.items():
        print(table_line(name, row, 38))
    if arguments.json:
        arguments.json.write_text(json.dumps({"checkpoint": str(arguments.checkpoint), "samples": len(pairs),
                                              "fusions": FUSIONS, "table_percent": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
