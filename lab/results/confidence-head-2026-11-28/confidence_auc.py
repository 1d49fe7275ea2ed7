"""Diagnostic (issue #15): what the "is my top-1 grasp right" head (``ModelOptions.grasp_confidence``) knows.

Runs a checkpoint with the head on the test samples and, over the detections
that could claim an object (same category, IoU > 0.5), gives the ROC AUC of
the head's probability and of the top-1 P(stable) for telling a right top-1
grasp from a wrong one (``detection_order.py``'s measure), then the Table II
figures (our protocol) of the same detections scored several ways: by the class
score alone (the detector without the head), by class score x the head's
probability (what ``togcrf eval`` reads), by class score x the probability to
a power below 1 (a softer mix), with the scores of the detections that could
claim an object handed out again by the head's probability (the ceiling of
this confidence where it would not touch the false positives), and by the
order oracle.

    python lab/results/confidence-head-2026-11-28/confidence_auc.py CHECKPOINT --data data --pipeline recipe
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "detection-order-2026-11-28"))
from detection_order import claimable_rows, roc_auc
from grasp_ranking import checkpoint_parser, handed_out, order_oracle, print_variants

from osgd.contract.samples import iter_samples, sample_shards
from togcrf.checkpoint import load_checkpoint
from togcrf.data import depth_to_tensor
from togcrf.evaluate import prediction_to_numpy
from togcrf.metrics import GroundTruth


def main() -> None:
    arguments = checkpoint_parser(__doc__, pipeline="recipe").parse_args()
    model, config = load_checkpoint(arguments.checkpoint, device="cpu")
    model.eval()
    rescored, plain = [], []
    for sample in iter_samples(arguments.data, split="test", shards=sample_shards(arguments.data, arguments.pipeline)):
        image, scale = depth_to_tensor(sample.depth, config.get("image_size"), config["depth_reference"])
        with torch.inference_mode():
            output = model([image])[0]
        detections, truth = prediction_to_numpy(output, scale), GroundTruth.from_sample(sample)
        rescored.append((detections, truth))
        plain.append((replace(detections, scores=output["class_scores"].double().numpy()), truth))
    columns, right = claimable_rows(plain)
    product, _ = claimable_rows(rescored)
    print(f"{len(right)} detections could claim an object; their top-1 grasp matches for {100 * right.mean():.1f} %")
    head = product["detection score"] / columns["detection score"]
    for name, values in {"head's P(top-1 right)": head, "top-1 P(stable)": columns["top-1 P(stable)"],
                         "class score": columns["detection score"]}.items():
        print(f"  ROC AUC of {name:24s} {roc_auc(values, right):.3f}")
    head_of = {id(detections): rescored_detections.scores / detections.scores
               for (detections, _), (rescored_detections, _) in zip(plain, rescored, strict=True)}
    variants = {"class score (no head)": plain, "class score x head": rescored}
    variants |= {f"class score x head ^ {power}": [
        (replace(detections, scores=detections.scores * head_of[id(detections)] ** power), truth)
        for detections, truth in plain] for power in (0.25, 0.5)}
    variants |= {"claimable by head": handed_out(plain, lambda detections, truth, may_claim, index: float(
        head_of[id(detections)][index])), "order oracle": order_oracle(plain)}
    print_variants(variants, 24)


if __name__ == "__main__":
    torch.set_num_threads(1)
    main()
