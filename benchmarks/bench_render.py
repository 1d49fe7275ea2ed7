"""Rendering and samples-stage throughput.

Prints frames per second per available backend (depth + instance mask of a
three-tool scene at the Kinect v2 resolution, 512 x 424), samples per second
for the whole stage (render, noise, boxes, grasp filters, PNG encoding) on
the test fixtures, and peak memory.

    python benchmarks/bench_render.py [--frames 20] [--samples 12]
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from helpers import fixture_models
from test_samples_fixtures import scene_row, write_fixture_inputs

from osgd.camera import KINECT_V2
from osgd.samples.renderer import RenderObject, available_backends, make_renderer
from osgd.samples.stage import SamplesStage, SamplesStageParams
from osgd.samples.viewpoint import draw_camera_pose
from osgd.stage import WorkItem
from osgd.store import ShardStore


def peak_memory_mib() -> tuple[float, float]:
    """Peak resident memory of this process and of its children, MiB."""
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    return own, children


def bench_backends(frames: int) -> None:
    hammer, screwdriver, block = fixture_models()
    scene = scene_row(0, [(hammer, [0.0, 0.0], 0.3), (screwdriver, [0.05, 0.12], -0.4), (block, [-0.06, -0.13], 1.2)])
    models = {row["model_id"]: row for row in (hammer, screwdriver, block)}
    objects = [RenderObject(obj["model_id"], np.asarray(models[obj["model_id"]]["vertices"]),
                            np.asarray(models[obj["model_id"]]["faces"]), np.asarray(obj["position"]),
                            np.asarray(obj["quaternion"])) for obj in scene["objects"]]
    rng = np.random.default_rng(0)
    poses = [draw_camera_pose(rng, np.zeros(3), 0.75, 0.17, 0.26) for _ in range(frames)]
    for backend in available_backends():
        renderer = make_renderer(backend)
        renderer.render(objects, KINECT_V2, poses[0])  # warm up: uploads, plugin
        start = time.perf_counter()
        for pose in poses:
            renderer.render(objects, KINECT_V2, pose)
        elapsed = time.perf_counter() - start
        print(f"render {backend:6s}: {frames / elapsed:6.1f} frames/s ({1000 * elapsed / frames:.1f} ms/frame, "
              f"{KINECT_V2.width}x{KINECT_V2.height}, depth + mask)")


def bench_stage(samples: int, renderer: str) -> None:
    hammer, screwdriver, block = fixture_models()
    scenes = [scene_row(index, [(hammer, [0.0, 0.0], 0.3 * index), (screwdriver, [0.05, 0.12], -0.4),
                                (block, [-0.06, -0.13], 1.2 + index)]) for index in range(samples)]
    with tempfile.TemporaryDirectory() as folder:
        store = ShardStore(folder)
        keys = write_fixture_inputs(store, scenes)
        params = SamplesStageParams(renderer=renderer)
        item = WorkItem("bench", {"params": params.key_dict(), "seed": 0, "scenes_item": "bench"},
                        {table: tuple(values) for table, values in keys.items()})
        stage = SamplesStage()
        stage.build(WorkItem("warm", item.payload, item.inputs), store)  # renderer start-up, imports
        start = time.perf_counter()
        result = stage.build(item, store)
        elapsed = time.perf_counter() - start
    grasps = sum(len(row) for row in result.table["grasps"].to_pylist())
    print(f"stage  {renderer:6s}: {samples / elapsed:6.2f} samples/s ({1000 * elapsed / samples:.0f} ms/sample, "
          f"{grasps / samples:.1f} grasps/sample, one process)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--samples", type=int, default=12)
    arguments = parser.parse_args()
    bench_backends(arguments.frames)
    for renderer in available_backends():
        bench_stage(arguments.samples, renderer)
    own, children = peak_memory_mib()
    print(f"peak memory: {own:.0f} MiB (this process), {children:.0f} MiB (children: the EGL probe)")


if __name__ == "__main__":
    main()
