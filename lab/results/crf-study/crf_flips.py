"""What the mean field does to the unary potentials of a TOG-CRFs checkpoint, RoI by RoI, by crowding.

For every detection that Acc-T judges (matched to an object with grasps, as togcrf.metrics matches them), the
most stable candidate's task is read twice from the same forward pass's logits: from the unary potentials alone
(softmax of the task logits: the CRF's mean field switched off) and from the CRF's marginals (as trained). Per
stratum of the share of the object's box that other objects cover (togcrf.metrics.COVER_BINS), it counts the
RoIs, how often the CRF changes the top-1 task, how many of those changes make it right or wrong, and the mean
confidence (largest probability) of the unary and of the CRF's output. Writes JSON. Run from the repository root:

    .venv/bin/python lab/results/crf-study/crf_flips.py OUT.json DATA CHECKPOINT... --set seen=default
    .venv/bin/python lab/results/crf-study/crf_flips.py --summarise ALL.json OUT.json...
"""

from __future__ import annotations

import argparse
import json
import sys
from itertools import islice, pairwise
from pathlib import Path

import numpy as np

from osgd.contract.samples import iter_samples
from togcrf.checkpoint import load_checkpoint
from togcrf.evaluate import check_test_sets, parse_test_sets
from togcrf.metrics import COVER_BINS, GroundTruth, match_detections, right_tasks
from togcrf.predict import predict_depth


def stratum_of(share: float) -> str:
    edges = (*COVER_BINS, np.inf)
    for low, high in pairwise(edges):
        if low <= share < high:
            return f"{low:.2f}-{high:.2f}" if np.isfinite(high) else f">={low:.2f}"
    return "unknown"


def judged_rois(model, config, sample):
    """(share of the box on other objects, unary top-1 right, CRF top-1 right, unary top-1, CRF top-1, unary
    confidence, CRF confidence) of each judged detection of one sample."""
    outputs = {}
    for name, iterations in (("unary", 0), ("crf", model.crf.iterations)):
        trained, model.crf.iterations = model.crf.iterations, iterations
        try:
            outputs[name] = predict_depth(model, sample.depth, config.get("image_size"),
                                          depth_reference=config["depth_reference"])
        finally:
            model.crf.iterations = trained
    unary, crf = outputs["unary"], outputs["crf"]
    truth = GroundTruth.from_sample(sample)
    matched = match_detections(crf.boxes, crf.categories, crf.scores, truth.boxes, truth.categories)
    rows = []
    for detection in np.nonzero(matched >= 0)[0]:
        of_object = truth.grasp_objects == matched[detection]
        if not of_object.any():
            continue
        best = int(np.argmax(crf.grasp_stability[detection]))
        allowed = right_tasks(crf.grasps[detection][best:best + 1], truth.grasp_rectangles[of_object],
                              truth.grasp_tasks[of_object])[0]
        p_unary, p_crf = unary.grasp_task_probs[detection, best], crf.grasp_task_probs[detection, best]
        rows.append((truth.other_objects_share(int(matched[detection])), int(np.argmax(p_unary)) in allowed,
                     int(np.argmax(p_crf)) in allowed, int(np.argmax(p_unary)), int(np.argmax(p_crf)),
                     float(p_unary.max()), float(p_crf.max())))
    return rows


def tally(rows) -> dict:
    strata: dict[str, list] = {}
    for row in rows:
        strata.setdefault(stratum_of(row[0]), []).append(row)
        strata.setdefault("all", []).append(row)
    result = {}
    for name, members in strata.items():
        unary_right = np.array([row[1] for row in members])
        crf_right = np.array([row[2] for row in members])
        changed = np.array([row[3] != row[4] for row in members])
        result[name] = {"rois": len(members), "unary Acc-T top1": float(unary_right.mean()),
                        "CRF Acc-T top1": float(crf_right.mean()), "changed": int(changed.sum()),
                        "changed to right": int((changed & crf_right & ~unary_right).sum()),
                        "changed to wrong": int((changed & ~crf_right & unary_right).sum()),
                        "unary confidence": float(np.mean([row[5] for row in members])),
                        "CRF confidence": float(np.mean([row[6] for row in members]))}
    return dict(sorted(result.items()))


def merged(paths: list[Path]) -> dict:
    """The documents of several runs of this script as one."""
    document: dict = {"checkpoints": [], "test_sets": {}}
    for path in paths:
        part = json.loads(path.read_text())
        document["checkpoints"] += part["checkpoints"]
        for name, by_checkpoint in part["test_sets"].items():
            document["test_sets"].setdefault(name, {}).update(by_checkpoint)
    return document


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("out", type=Path)
    parser.add_argument("data", type=Path)
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--set", action="append", required=True, help="NAME=PIPELINE")
    parser.add_argument("--max-samples", type=int, default=None)
    if sys.argv[1:2] == ["--summarise"]:  # --summarise OUT.json PART.json...: merge the parts, print the table
        document = merged([Path(path) for path in sys.argv[3:]])
        Path(sys.argv[2]).write_text(json.dumps(document, indent=1))
        print(summary(document))
        return
    arguments = parser.parse_args()
    sets = parse_test_sets(arguments.set)
    document = {"checkpoints": arguments.checkpoints, "test_sets": {}}
    for checkpoint in arguments.checkpoints:
        model, config = load_checkpoint(checkpoint)
        shards = check_test_sets(arguments.data, sets, config["vocabulary"])
        for name in sets:
            samples = islice(iter_samples(arguments.data, split="test", shards=shards[name]), arguments.max_samples)
            rows = [row for sample in samples for row in judged_rois(model, config, sample)]
            document["test_sets"].setdefault(name, {})[checkpoint] = tally(rows)
    arguments.out.write_text(json.dumps(document, indent=1))
    print(summary(document))


def summary(document: dict) -> str:
    """Per test set and stratum, pooled over the checkpoints: RoIs, Acc-T top-1 of the unary and of the CRF,
    the top-1 tasks the CRF changed (to right / to wrong), and the mean confidences."""
    lines = [f"{'set':<7}{'stratum':<11}{'RoIs':>6}{'unary':>8}{'CRF':>7}{'changed':>9}{'to right':>10}"
             f"{'to wrong':>10}{'conf. unary':>13}{'conf. CRF':>11}"]
    for name, by_checkpoint in document["test_sets"].items():
        strata = sorted({stratum for tallies in by_checkpoint.values() for stratum in tallies})
        for stratum in strata:
            cells = [tallies[stratum] for tallies in by_checkpoint.values() if stratum in tallies]
            rois = sum(cell["rois"] for cell in cells)
            def pooled(key: str, cells: list = cells, rois: int = rois) -> float:
                return sum(cell[key] * cell["rois"] for cell in cells) / rois
            lines.append(f"{name:<7}{stratum:<11}{rois:>6}{100 * pooled('unary Acc-T top1'):>8.1f}"
                         f"{100 * pooled('CRF Acc-T top1'):>7.1f}{sum(cell['changed'] for cell in cells):>9}"
                         f"{sum(cell['changed to right'] for cell in cells):>10}"
                         f"{sum(cell['changed to wrong'] for cell in cells):>10}"
                         f"{pooled('unary confidence'):>13.3f}{pooled('CRF confidence'):>11.3f}")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
