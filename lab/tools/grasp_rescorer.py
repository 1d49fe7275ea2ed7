"""Can the top-1 grasp be chosen better from the depth around each candidate?

mAP-G judges a detection's top-1 grasp (``togcrf.diagnostics`` measures how
often it matches, and how often one of the top 5 does). The grasp head sees
each RoI as 7 x 7 cells pooled from stride-8 features. This harness trains
a small second-stage network that looks at the full-resolution depth around
each of a detection's top-K candidates, aligned with the gripper, and
measures whether it picks the matching one more often.

1. The checkpoint runs on the training samples; for every detection that
   claims an object with grasps (``togcrf.diagnostics.claimed_objects``), its
   top-K candidates by P(stable) are cut out of the sample's depth (height
   above the fitted table plane) as two crops rotated into the gripper's
   frame: ``LOCAL_WINDOW`` px and ``CONTEXT_WINDOW`` px wide, both
   resampled to ``CROP`` x ``CROP``, with the candidate's rectangle as a
   third channel. Label: the candidate matches a ground-truth grasp of the
   object (the mAP-G rule, ``togcrf.metrics.grasp_match_matrix``).
2. A small CNN (:class:`Rescorer`; also given the detection's category and
   the candidate's P(stable) logit and place in its box) learns that label
   for ``--minutes`` on the CPU.
3. On the test samples, each detection's top-K candidates are re-ranked by
   the network's probability; the script prints the share of claimed
   objects whose top-1 matches and the Table II figures (our protocol) of
   the detector's ranking, the re-scored one and the grasp oracle.

    python lab/tools/grasp_rescorer.py CHECKPOINT --data data --pipeline recipe --minutes 10 --json OUT.json
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from dataclasses import dataclass, replace
from itertools import islice
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import nn

from osgd.contract.samples import iter_samples, sample_shards
from osgd.contract.taxonomy import CATEGORIES
from togcrf.checkpoint import load_checkpoint
from togcrf.data import normalise_depth
from togcrf.diagnostics import claimed_objects, detect, grasp_oracle, table_figures
from togcrf.metrics import Detections, GroundTruth, grasp_match_matrix

LOG = logging.getLogger("grasp_rescorer")

#: Side of each crop fed to the network, cells.
CROP = 32
#: Side of the local crop, sample pixels (openings are 12-29 px, fingers 18 px at 320 px).
LOCAL_WINDOW = 64.0
#: Side of the context crop, sample pixels (boxes are 60-250 px).
CONTEXT_WINDOW = 192.0
#: Height unit of the crops: the network input's (``togcrf.data.DEPTH_UNIT``, 0.1 m) scaled to centimetres.
HEIGHT_SCALE = 10.0
#: Scalars per candidate: category one-hot, P(stable) logit, place in its box (2), box size (2).
SCALARS = len(CATEGORIES) + 5


def gripper_crop(height: np.ndarray, grasp: np.ndarray, window: float) -> np.ndarray:
    """``(CROP, CROP)`` float32: ``height`` around a grasp ``(x, y, w, h, theta)``, its opening axis along x."""
    x, y, _, _, theta = grasp
    scale = CROP / window
    cos, sin = np.cos(theta), np.sin(theta)
    # output (u, v) = scale * R(-theta) (p - centre) + CROP / 2
    matrix = np.array([[cos, sin, 0.0], [-sin, cos, 0.0]]) * scale
    matrix[:, 2] = CROP / 2.0 - matrix[:, :2] @ np.array([x, y])
    return cv2.warpAffine(height, matrix, (CROP, CROP), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                          borderValue=0.0)


def rectangle_crop(grasp: np.ndarray) -> np.ndarray:
    """``(CROP, CROP)`` float32: 1 inside the candidate's rectangle in the local crop's frame."""
    scale = CROP / LOCAL_WINDOW
    half_w, half_h = grasp[2] * scale / 2.0, grasp[3] * scale / 2.0
    centre = np.arange(CROP) + 0.5 - CROP / 2.0
    inside_x = np.abs(centre)[None, :] <= half_w
    inside_y = np.abs(centre)[:, None] <= half_h
    return (inside_x & inside_y).astype(np.float32)


def candidate_inputs(height: np.ndarray, detections: Detections, detection: int, order: np.ndarray,
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Crops ``(k, 3, CROP, CROP)`` and scalars ``(k, SCALARS)`` of one detection's candidates ``order``."""
    box = detections.boxes[detection]
    size = np.maximum(box[2:] - box[:2], 1.0)
    crops, scalars = [], []
    category = np.zeros(len(CATEGORIES), dtype=np.float32)
    category[int(detections.categories[detection])] = 1.0
    for candidate in order:
        grasp = detections.grasps[detection, candidate]
        crops.append(np.stack([gripper_crop(height, grasp, LOCAL_WINDOW), rectangle_crop(grasp),
                               gripper_crop(height, grasp, CONTEXT_WINDOW)]))
        stability = float(np.clip(detections.grasp_stability[detection, candidate], 1e-6, 1 - 1e-6))
        place = (grasp[:2] - box[:2]) / size
        scalars.append(np.concatenate([category, [np.log(stability / (1 - stability))], place, size / 320.0]))
    return np.asarray(crops, dtype=np.float32), np.asarray(scalars, dtype=np.float32)


@dataclass
class Collected:
    """Inputs and labels of the top-K candidates of claimed detections, and the detections of every image."""

    crops: list[np.ndarray]
    scalars: list[np.ndarray]
    labels: list[np.ndarray]
    images: list[tuple[Detections, GroundTruth, np.ndarray]]


def collect(model: torch.nn.Module, config: dict, samples, top_k: int, keep_images: bool) -> Collected:
    """Run the detector on ``samples`` and cut the crops of the top-K candidates of each claimed detection."""
    collected = Collected([], [], [], [])
    for index, sample in enumerate(samples):
        detections, truth = detect(model, config, sample)
        height = normalise_depth(sample.depth, config["depth_reference"]) * HEIGHT_SCALE
        for detection, target in claimed_objects(detections, truth):
            order = np.argsort(-detections.grasp_stability[detection], kind="stable")[:top_k]
            object_grasps = truth.grasp_rectangles[truth.grasp_objects == target]
            matches = grasp_match_matrix(detections.grasps[detection][order], object_grasps).any(axis=1)
            crops, scalars = candidate_inputs(height, detections, detection, order)
            collected.crops.append(crops)
            collected.scalars.append(scalars)
            collected.labels.append(matches.astype(np.float32))
        if keep_images:
            collected.images.append((detections, truth, height))
        if (index + 1) % 200 == 0:
            LOG.info("%d samples, %d claimed detections", index + 1, len(collected.labels))
    return collected


class Rescorer(nn.Module):
    """A small CNN on the 3 crop channels, its pooled features joined with the scalars, one logit."""

    def __init__(self, width: int = 32) -> None:
        super().__init__()

        def stage(inputs: int, outputs: int) -> list[nn.Module]:
            return [nn.Conv2d(inputs, outputs, 3, padding=1, bias=False), nn.GroupNorm(8, outputs), nn.ReLU(),
                    nn.Conv2d(outputs, outputs, 3, padding=1, bias=False), nn.GroupNorm(8, outputs), nn.ReLU()]

        self.features = nn.Sequential(*stage(3, width), nn.MaxPool2d(2), *stage(width, 2 * width), nn.MaxPool2d(2),
                                      *stage(2 * width, 4 * width), nn.AdaptiveAvgPool2d(1), nn.Flatten())
        self.head = nn.Sequential(nn.Linear(4 * width + SCALARS, 128), nn.ReLU(), nn.Linear(128, 1))

    def forward(self, crops: torch.Tensor, scalars: torch.Tensor) -> torch.Tensor:
        return self.head(torch.cat([self.features(crops), scalars], dim=1)).squeeze(1)


def train_rescorer(data: Collected, minutes: float, seed: int) -> Rescorer:
    """Train :class:`Rescorer` with AdamW (cosine over the time budget) on the collected candidates."""
    torch.manual_seed(seed)
    crops = torch.from_numpy(np.concatenate(data.crops))
    scalars = torch.from_numpy(np.concatenate(data.scalars))
    labels = torch.from_numpy(np.concatenate(data.labels))
    LOG.info("training on %d candidates, %.1f %% positive", len(labels), 100.0 * float(labels.mean()))
    network = Rescorer()
    optimiser = torch.optim.AdamW(network.parameters(), lr=2e-3, weight_decay=1e-4)
    generator = torch.Generator().manual_seed(seed)
    start, step, budget = time.perf_counter(), 0, 60.0 * minutes
    while (spent := time.perf_counter() - start) < budget:
        for group in optimiser.param_groups:
            group["lr"] = 2e-3 * 0.5 * (1.0 + np.cos(np.pi * spent / budget))
        batch = torch.randint(len(labels), (256,), generator=generator)
        flip = torch.rand(len(batch), generator=generator) < 0.5  # a grasp is symmetric under a half turn
        batch_crops = torch.where(flip[:, None, None, None], crops[batch].flip(-1, -2), crops[batch])
        loss = nn.functional.binary_cross_entropy_with_logits(network(batch_crops, scalars[batch]), labels[batch])
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        step += 1
        if step % 200 == 0:
            LOG.info("step %d, %.0f s, loss %.3f", step, spent, loss.item())
    return network.eval()


def rescored(network: Rescorer, detections: Detections, height: np.ndarray, top_k: int, blend: float) -> Detections:
    """The detections with each one's top-K candidates ranked by the network (above every other candidate).

    ``blend`` mixes in the detector's own P(stable): key = sigmoid(network logit + blend * stability logit).
    """
    stability = np.array(detections.grasp_stability, dtype=np.float64, copy=True)
    for detection in range(len(stability)):
        order = np.argsort(-stability[detection], kind="stable")[:top_k]
        crops, scalars = candidate_inputs(height, detections, detection, order)
        with torch.inference_mode():
            logits = network(torch.from_numpy(crops), torch.from_numpy(scalars)).double().numpy()
        logits = logits + blend * scalars[:, len(CATEGORIES)]
        stability[detection, order] = 1.0 + 1.0 / (1.0 + np.exp(-logits))
    return replace(detections, grasp_stability=stability)


def top1_share(pairs: list[tuple[Detections, GroundTruth]]) -> float:
    """Percent of claimed objects with grasps whose top-1 candidate matches one of theirs."""
    hits = objects = 0
    for detections, truth in pairs:
        for detection, target in claimed_objects(detections, truth):
            top = detections.top_grasp(detection)
            hits += int(grasp_match_matrix(top[None], truth.grasp_rectangles[truth.grasp_objects == target]).any())
            objects += 1
    return 100.0 * hits / max(objects, 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("--data", type=Path, default=Path("data"))
    parser.add_argument("--pipeline", default=None)
    parser.add_argument("--train-samples", type=int, default=100_000, help="training samples to collect from")
    parser.add_argument("--test-samples", type=int, default=1000)
    parser.add_argument("--top-k", type=int, default=12, help="candidates per detection re-scored")
    parser.add_argument("--minutes", type=float, default=10.0, help="training time of the re-scorer")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None)
    arguments = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    model, config = load_checkpoint(arguments.checkpoint, device="cpu")
    model.eval()
    shards = sample_shards(arguments.data, arguments.pipeline)
    started = time.perf_counter()
    train = collect(model, config, islice(iter_samples(arguments.data, split="train", shards=shards),
                                          arguments.train_samples), arguments.top_k, keep_images=False)
    collect_seconds = time.perf_counter() - started
    network = train_rescorer(train, arguments.minutes, arguments.seed)
    test = collect(model, config, islice(iter_samples(arguments.data, split="test", shards=shards),
                                         arguments.test_samples), arguments.top_k, keep_images=True)
    variants = {
        "detector": lambda detections, truth, height: detections,
        "re-scored": lambda detections, truth, height: rescored(network, detections, height, arguments.top_k, 0.0),
        "re-scored + P(stable)": lambda detections, truth, height: rescored(
            network, detections, height, arguments.top_k, 1.0),
        "grasp oracle": lambda detections, truth, height: grasp_oracle(detections, truth),
    }
    report = {"checkpoint": str(arguments.checkpoint), "command": " ".join(sys.argv),
              "train_candidates": int(sum(len(labels) for labels in train.labels)),
              "train_positive_percent": round(100.0 * float(np.concatenate(train.labels).mean()), 1),
              "collect_seconds": round(collect_seconds, 1), "minutes": arguments.minutes, "top_k": arguments.top_k,
              "test_candidates_top_k_any_match_percent": round(100.0 * float(np.mean(
                  [labels.any() for labels in test.labels])), 1),
              "top1_match_percent": {}, "table_percent": {}}
    for name, variant in variants.items():
        pairs = [(variant(detections, truth, height), truth) for detections, truth, height in test.images]
        report["top1_match_percent"][name] = round(top1_share(pairs), 1)
        report["table_percent"][name] = table_figures(pairs)
        LOG.info("%-24s top-1 match %5.1f %%  %s", name, report["top1_match_percent"][name],
                 "  ".join(f"{key} {value:5.1f}" for key, value in report["table_percent"][name].items()))
    if arguments.json:
        arguments.json.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    torch.set_num_threads(2)
    main()
