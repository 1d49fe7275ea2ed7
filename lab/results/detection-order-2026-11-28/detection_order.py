"""Diagnostic (issue #15): how much mAP-G the order of the detections holds, at the detector's own top-1 grasps.

A detection whose top-1 grasp misses is a false positive of mAP-G that keeps
its box score, so it ranks among the right ones: AP-G falls with the square
of the top-1 match rate, not in proportion. This script runs a checkpoint on
the test samples and, over the detections that could claim an object (same
category, IoU > 0.5: ``benchmarks/grasp_ranking.py``'s ``claimable``), says

- how well per-detection features tell a right top-1 grasp from a wrong one
  (ROC AUC: 0.5 is chance, 1 a perfect confidence);
- the Table II figures (our protocol) when those detections' scores are
  handed out again per category, right top-1 first (the order oracle of
  ``grasp_ranking.py``), by the top-1 P(stable), or at random;
- the Table II figures when every detection's score is mixed with its top-1
  P(stable) (what a detector could do without ground truth).

    python lab/results/detection-order-2026-11-28/detection_order.py CHECKPOINT --data data --pipeline recipe \
        [--pairs-cache PAIRS.pkl]
"""

from __future__ import annotations

import pickle
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
from grasp_ranking import (
    checkpoint_parser,
    claimable,
    detect,
    handed_out,
    order_oracle,
    print_variants,
    top1_matches,
)

from osgd.contract.samples import iter_samples, sample_shards
from togcrf.checkpoint import load_checkpoint
from togcrf.metrics import Detections, GroundTruth

Pairs = list[tuple[Detections, GroundTruth]]


def detections_of(checkpoint: Path, data: Path, pipeline: str | None, cache: Path | None) -> Pairs:
    """(detections, truth) of every test sample; read from / written to ``cache`` when given."""
    if cache is not None and cache.exists():
        return pickle.loads(cache.read_bytes())
    model, config = load_checkpoint(checkpoint, device="cpu")
    model.eval()
    pairs = [detect(model, config, sample)
             for sample in iter_samples(data, split="test", shards=sample_shards(data, pipeline))]
    if cache is not None:
        cache.write_bytes(pickle.dumps(pairs))
    return pairs


def features(detections: Detections) -> dict[str, np.ndarray]:
    """(D,) per-detection features from its 196 candidates' P(stable) and its score."""
    stability = np.asarray(detections.grasp_stability, dtype=np.float64)
    ranked = -np.sort(-stability, axis=1)
    top = stability.argmax(axis=1)
    shares = stability / stability.sum(axis=1, keepdims=True)
    tasks = np.asarray(detections.grasp_task_probs)[np.arange(len(top)), top]
    return {"top-1 P(stable)": ranked[:, 0], "top-1 minus top-2": ranked[:, 0] - ranked[:, 1],
            "top-1 share of the sum": ranked[:, 0] / stability.sum(axis=1),
            "negative entropy": (shares * np.log(shares + 1e-12)).sum(axis=1),
            "top-1 task confidence": tasks.max(axis=1), "detection score": np.asarray(detections.scores)}


def roc_auc(values: np.ndarray, positive: np.ndarray) -> float:
    """Probability that a random positive has the larger value (ties unbroken)."""
    ranks = np.empty(len(values))
    ranks[np.argsort(values, kind="stable")] = np.arange(1, len(values) + 1)
    count = positive.sum()
    return float((ranks[positive].sum() - count * (count + 1) / 2) / (count * (~positive).sum()))


def claimable_rows(pairs: Pairs) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Features and "top-1 matches" of the detections that could claim an object."""
    columns: dict[str, list[float]] = {}
    right = []
    for detections, truth in pairs:
        if len(detections.scores) == 0:
            continue
        may_claim, _ = claimable(detections, truth)
        values = features(detections)
        for detection in np.nonzero(may_claim.any(axis=1))[0]:
            right.append(bool(top1_matches(detections, truth, may_claim, int(detection))))
            for name, column in values.items():
                columns.setdefault(name, []).append(float(column[detection]))
    return {name: np.asarray(column) for name, column in columns.items()}, np.asarray(right)


def rescored(pairs: Pairs, weight: float) -> Pairs:
    """Every detection scored sigmoid(logit(score) + weight * logit(top-1 P(stable)))."""
    def logit(p: np.ndarray) -> np.ndarray:
        p = np.clip(p, 1e-6, 1 - 1e-6)
        return np.log(p / (1 - p))
    out = []
    for detections, truth in pairs:
        if len(detections.scores) == 0:
            out.append((detections, truth))
            continue
        top = np.asarray(detections.grasp_stability, dtype=np.float64).max(axis=1)
        mixed = logit(np.asarray(detections.scores, dtype=np.float64)) + weight * logit(top)
        out.append((replace(detections, scores=1 / (1 + np.exp(-mixed))), truth))
    return out


def main() -> None:
    parser = checkpoint_parser(__doc__, pipeline="recipe")
    parser.add_argument("--pairs-cache", type=Path, default=None)
    arguments = parser.parse_args()
    pairs = detections_of(arguments.checkpoint, arguments.data, arguments.pipeline, arguments.pairs_cache)
    columns, right = claimable_rows(pairs)
    print(f"{len(right)} detections could claim an object; their top-1 grasp matches for {100 * right.mean():.1f} %")
    for name, values in columns.items():
        print(f"  ROC AUC of {name:24s} {roc_auc(values, right):.3f}")
    rng = np.random.default_rng(0)
    variants = {"detector": pairs, "order oracle (right top-1 first)": order_oracle(pairs),
                "claimable by top-1 P(stable)": handed_out(
                    pairs, lambda detections, truth, may_claim, i: float(np.max(detections.grasp_stability[i]))),
                "claimable at random (seed 0)": handed_out(pairs, lambda *_: float(rng.random()))}
    variants |= {f"all: logit score + {w} logit top-1": rescored(pairs, w) for w in (0.25, 0.5, 1.0)}
    print_variants(variants, 36)


if __name__ == "__main__":
    torch.set_num_threads(1)
    main()
