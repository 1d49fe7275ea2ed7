"""Where a RoI's top-1 grasp candidate lies, in cells, from its object's annotated grasps (issue #15 diagnostic).

The model runs in train mode (no gradients) on test samples, so its RoIs are
the training RoIs (ground-truth boxes and proposals with IoU >= 0.5, each with
its object's grasps). For each RoI with a positive anchor, the top-1 candidate
by P(stable) falls in one of four classes:

- ``positive``: its cell holds an annotated grasp within 22.5 degrees (what the
  stability loss calls positive, ``togcrf.anchors.match``);
- ``same cell``: not positive, but its cell holds a grasp within 45 degrees;
- ``one cell``: not the above, but a grasp within 45 degrees lies within one
  cell (``togcrf.anchors.near_ground_truth`` with radius 1);
- ``farther``: everything else.

For each class: its share of the RoIs and how often the decoded top-1
rectangle matches a grasp of the RoI's object as mAP-G judges it (Jaccard >
0.25, angle within 30 degrees; ``togcrf.metrics.grasp_match_matrix``). It also
gives where the hard negatives of the stability loss lie.

    python lab/results/regression-radius-2026-11-29/top1_cells.py CHECKPOINT [--batches 52] [--split test]
"""

from __future__ import annotations

import argparse
from collections import Counter

import torch
from torch.nn import functional
from torch.utils.data import DataLoader

import togcrf.model
from togcrf.anchors import decode, near_ground_truth
from togcrf.checkpoint import load_checkpoint
from togcrf.data import SamplesDataset, collate
from togcrf.losses import DEFAULT_NEGATIVE_RATIO, hard_negative_selection
from togcrf.metrics import grasp_match_matrix

CLASSES = ("positive", "same cell", "one cell", "farther")


def capture(model: torch.nn.Module) -> dict:
    """Keep the arguments of ``togcrf.model.match`` and the grasp outputs and targets of each forward pass."""
    seen: dict = {}
    match, grasp_losses = togcrf.model.match, model._grasp_losses

    def keep_match(anchors, rois, grasps, valid, *arguments, **keywords):
        seen["match"] = (anchors, rois, grasps, valid)
        return match(anchors, rois, grasps, valid, *arguments, **keywords)

    def keep_losses(outputs, targets):
        seen["outputs"], seen["targets"] = outputs, targets
        return grasp_losses(outputs, targets)

    togcrf.model.match = keep_match
    model._grasp_losses = keep_losses
    return seen


def count_batch(seen: dict, rois: Counter, matches: Counter, negatives: Counter) -> None:
    """Add one batch's RoIs by class, their matches and the hard negatives by distance to a grasp."""
    anchors, boxes, grasps, valid = seen["match"]
    positive, stability = seen["targets"].positive, seen["outputs"].stability.float()
    same_cell = near_ground_truth(anchors, boxes, grasps, valid, 0.0)
    one_cell = near_ground_truth(anchors, boxes, grasps, valid, 1.0)
    losses = functional.cross_entropy(stability.reshape(-1, 2), positive.long().reshape(-1),
                                      reduction="none").reshape(positive.shape)
    hard = hard_negative_selection(losses, positive, DEFAULT_NEGATIVE_RATIO) & ~positive
    negatives.update({"all": int(hard.sum()), "same cell": int((hard & same_cell).sum()),
                      "one cell": int((hard & one_cell).sum())})
    top = (stability[..., 1] - stability[..., 0]).argmax(dim=1)
    rows = torch.arange(len(top))
    rectangles = decode(seen["outputs"].regression.float()[rows, top], anchors[rows, top]).numpy()
    for roi in positive.any(dim=1).nonzero().flatten().tolist():
        candidate = int(top[roi])
        kind = next(name for name, near in zip(CLASSES, (positive, same_cell, one_cell, None), strict=True)
                    if near is None or bool(near[roi, candidate]))
        truth = grasps[roi][valid[roi]].numpy()
        rois[kind] += 1
        matches[kind] += int(grasp_match_matrix(rectangles[roi:roi + 1], truth).any())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--data", default="data")
    parser.add_argument("--pipeline", default="recipe")
    parser.add_argument("--split", default="test")
    parser.add_argument("--batches", type=int, default=52, help="batches of 4 samples (52: the 206 test samples)")
    arguments = parser.parse_args()
    torch.manual_seed(0)
    model, config = load_checkpoint(arguments.checkpoint)
    dataset = SamplesDataset(arguments.data, pipeline=arguments.pipeline, split=arguments.split,
                             image_size=config["image_size"])
    loader = DataLoader(dataset, batch_size=4, collate_fn=collate)
    seen = capture(model)
    model.train()
    rois, matches, negatives = Counter(), Counter(), Counter()
    with torch.no_grad():
        for index, (images, targets, _) in enumerate(loader):
            if index == arguments.batches:
                break
            model(images, targets)
            count_batch(seen, rois, matches, negatives)
    total = sum(rois.values())
    print(f"{arguments.checkpoint}: {total} RoIs with a positive anchor, {arguments.split} split")
    for kind in CLASSES:
        print(f"  top-1 {kind:9s}: {100 * rois[kind] / total:5.1f} % of the RoIs, "
              f"{100 * matches[kind] / max(rois[kind], 1):5.1f} % of them match")
    print(f"  top-1 matches: {100 * sum(matches.values()) / total:.1f} %")
    print(f"  hard negatives: {100 * negatives['same cell'] / negatives['all']:.1f} % in a grasp's cell, "
          f"{100 * negatives['one cell'] / negatives['all']:.1f} % within one cell (angle within 45 degrees)")


if __name__ == "__main__":
    main()
