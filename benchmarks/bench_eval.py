"""Benchmark of evaluation: metric throughput and model speed (Table II's fps column).

Prints
- the metrics' throughput: images per second through ``TableTwoEvaluator``
  for synthetic detections (50 detections x 196 candidates per image, the
  size of a TOG output), i.e. the evaluation overhead beyond the model;
- the speed of freshly initialised models (batch 1, warm) at a given image
  size on the CPU (or ``--device cuda``), as ``togcrf eval`` measures it,
  with each count of test-time views of ``--views`` (``togcrf.tta``; the
  "roi" models only), so that their cost is a ratio measured in one run;
- peak resident memory of this process.

Run: ``python benchmarks/bench_eval.py [--size 480] [--models tog,tog-crfs,fcgn-task] [--views 1,8] [--device cpu]``.
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np
import torch

from osgd.contract.taxonomy import TASKS
from togcrf.metrics import Detections, GroundTruth, TableTwoEvaluator, measure_speed
from togcrf.model import build_model
from togcrf.tta import view_averaged_output


def synthetic_pair(rng: np.random.Generator, detections: int = 50, candidates: int = 196,
                   objects: int = 5, grasps_per_object: int = 40) -> tuple[Detections, GroundTruth]:
    """Detections and ground truth of TOG's output size, boxes scattered over a 640 x 480 image."""
    corner = rng.uniform(0, 500, (objects, 2))
    truth_boxes = np.column_stack([corner, corner + rng.uniform(40, 140, (objects, 2))])
    owners = np.repeat(np.arange(objects), grasps_per_object)
    centres = truth_boxes[owners, :2] + rng.uniform(0, 1, (len(owners), 2)) * (truth_boxes[owners, 2:]
                                                                              - truth_boxes[owners, :2])
    truth_grasps = np.column_stack([centres, np.full(len(owners), 30.0), np.full(len(owners), 10.0),
                                    rng.uniform(-np.pi / 2, np.pi / 2, len(owners))])
    source = rng.integers(0, objects, detections)
    boxes = truth_boxes[source] + rng.normal(0, 5, (detections, 4))
    grasps = truth_grasps[rng.integers(0, len(owners), (detections, candidates))] + rng.normal(0, 3, (1, 1, 5))
    task_probs = rng.dirichlet(np.ones(len(TASKS)), (detections, candidates))
    return (Detections(boxes, rng.integers(0, 10, detections), rng.random(detections), grasps,
                       rng.random((detections, candidates)), task_probs),
            GroundTruth(truth_boxes, rng.integers(0, 10, objects), truth_grasps, owners,
                        rng.integers(0, len(TASKS), len(owners))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=480, help="Square image side for the model speed.")
    parser.add_argument("--models", default="tog,tog-crfs,fcgn-task")
    parser.add_argument("--backbone", default="resnet18")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--images", type=int, default=30, help="Images through the metrics.")
    parser.add_argument("--views", default="1", help="Test-time view counts to time, comma-separated (1, 2, 4, 8).")
    arguments = parser.parse_args()

    rng = np.random.default_rng(0)
    pairs = [synthetic_pair(rng) for _ in range(arguments.images)]
    evaluator = TableTwoEvaluator()
    start = time.perf_counter()
    for detections, truth in pairs:
        evaluator.add(detections, truth)
    evaluator.result()
    elapsed = time.perf_counter() - start
    print(f"metrics: {arguments.images / elapsed:.1f} images/s (50 detections x 196 candidates each)")

    torch.manual_seed(0)
    image = torch.rand(1, arguments.size, arguments.size, device=arguments.device)
    for name in arguments.models.split(","):
        model = build_model(name, arguments.backbone).to(arguments.device).eval()
        for views in [int(count) for count in arguments.views.split(",")]:
            if views > 1 and model.grasp_branch != "roi":
                continue

            def run_once(batch_image: torch.Tensor, model: torch.nn.Module = model, views: int = views) -> None:
                with torch.inference_mode():
                    view_averaged_output(model, batch_image, views)

            speed = measure_speed(run_once, [image], warmup=2, repeats=5, device=arguments.device)
            print(f"{name} ({arguments.backbone}, {arguments.size} px, batch 1, {arguments.device}, "
                  f"{torch.get_num_threads()} threads, {views} view{'s' * (views > 1)}): {speed['fps']:.2f} fps")
    peak_self = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    peak_children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(f"peak memory: {peak_self:.0f} MiB (children {peak_children:.0f} MiB)")


if __name__ == "__main__":
    main()
