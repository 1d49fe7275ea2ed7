"""Re-rank each detection's grasp candidates at inference: does mAP-G move? (issue #15, measured, not adopted)

Runs a checkpoint once on the recipe's test split (cached in CACHE), then
scores the same detections with each RoI's 7 x 7 x 4 stability map
re-ranked as KIND says, under our protocol:

- base: the model's stability (the evaluation as `togcrf eval` does it);
- box, box0.5, box0.25: the stability mixed (weight 1, 0.5, 0.25) with its
  3 x 3 cell mean, per anchor angle;
- boxang: the 3 x 3 mean, then averaged over neighbouring angles;
- logit: the 3 x 3 mean of the logits;
- centre: the stability times a Gaussian of the cell's distance to the RoI centre.

Usage (from the repository root, with the recipe's data in data/):

    python lab/results/grasp-rerank/rerank.py CHECKPOINT CACHE KIND [KIND ...]
"""
import pickle
import sys
from dataclasses import replace

import numpy as np
import torch

from osgd.contract.samples import iter_samples, sample_shards
from togcrf.checkpoint import load_checkpoint
from togcrf.data import depth_to_tensor
from togcrf.evaluate import run_model
from togcrf.metrics import TOP_K, GroundTruth, TableTwoEvaluator

ckpt, cache = sys.argv[1], sys.argv[2]
try:
    pairs = pickle.load(open(cache, "rb"))
except FileNotFoundError:
    torch.set_num_threads(2)
    model, config = load_checkpoint(ckpt, device="cpu")
    model.eval()
    pairs = []
    for s in iter_samples("data", split="test", shards=sample_shards("data", "recipe")):
        image, scale = depth_to_tensor(s.depth, config.get("image_size"), config["depth_reference"])
        pairs.append((run_model(model, image, scale), GroundTruth.from_sample(s)))
    pickle.dump(pairs, open(cache, "wb"))

def smooth(stab, kind):
    n = stab.shape[0]
    m = stab.reshape(n, 7, 7, 4)
    if kind == "base":
        return stab
    if kind.startswith("box") and kind != "boxang":
        w = float(kind[3:]) if len(kind) > 3 else 1.0
        p = np.pad(m, ((0, 0), (1, 1), (1, 1), (0, 0)), mode="edge")
        s = sum(p[:, 1 + di:8 + di, 1 + dj:8 + dj] for di in (-1, 0, 1) for dj in (-1, 0, 1)) / 9
        return ((1 - w) * m + w * s).reshape(n, -1)
    if kind == "boxang":
        p = np.pad(m, ((0, 0), (1, 1), (1, 1), (0, 0)), mode="edge")
        s = sum(p[:, 1 + di:8 + di, 1 + dj:8 + dj] for di in (-1, 0, 1) for dj in (-1, 0, 1)) / 9
        a = (np.roll(s, 1, -1) + 2 * s + np.roll(s, -1, -1)) / 4
        return a.reshape(n, -1)
    if kind == "logit":
        logits = np.log(np.clip(m, 1e-6, 1 - 1e-6) / np.clip(1 - m, 1e-6, 1))
        p = np.pad(logits, ((0, 0), (1, 1), (1, 1), (0, 0)), mode="edge")
        s = sum(p[:, 1 + di:8 + di, 1 + dj:8 + dj] for di in (-1, 0, 1) for dj in (-1, 0, 1)) / 9
        return s.reshape(n, -1)
    if kind == "centre":  # prefer candidates near the box centre
        yy, xx = np.mgrid[0:7, 0:7]
        d = np.hypot(yy - 3, xx - 3)[None, :, :, None] / 3
        return (m * np.exp(-0.5 * d ** 2)).reshape(n, -1)
    raise ValueError(kind)

for kind in sys.argv[3:]:
    ev = TableTwoEvaluator(top_k=TOP_K, unmatched_task="nearest", protocol="ours")
    for detections, truth in pairs:
        ranked = detections
        if len(detections.grasp_stability):
            ranked = replace(detections, grasp_stability=smooth(detections.grasp_stability, kind))
        ev.add(ranked, truth)
    r = ev.result()
    columns = ("mAP", "mAP-G", "Acc-T top1", "Acc-T top5", "Acc-T top10")
    print(kind, {k: round(100 * r[k], 1) for k in columns}, flush=True)
