"""Rendering and samples-stage throughput.

Prints frames per second per available backend (depth + instance mask of a
three-tool scene at the Kinect v2 resolution, 512 x 424), samples per second
for the whole stage (render, noise, boxes, grasp filters, PNG encoding) on
the test fixtures, and peak memory.

With ``--osgd-models DIR`` (the paper authors' models, e.g.
../shared/osgd-models) it also builds a small pipeline of those models
(``--per-category`` models of each category, ``--scenes`` piles; kept in
``--data-dir`` for the next run) and times the samples stage on its piles,
each in a fresh process of one core, in the same run: the stage of an
older commit (``--before``, unpacked from git, with EGL, the renderer
``auto`` picked at that commit) against today's with EGL and with the
embree renderer, each after a warm-up item (a worker builds many items);
then where today's path spends its time.

    python benchmarks/bench_render.py [--frames 20] [--samples 12]
    python benchmarks/bench_render.py --osgd-models ../shared/osgd-models [--per-category 2] [--scenes 75]
    python benchmarks/bench_render.py --built DATA_DIR --before COMMIT [--items 12]

With ``--built DATA_DIR`` (a whole build of ``pipelines/osgd.toml`` as it
was at commit ``--before``) it only times ``--items`` samples items of that
build in fresh one-core processes: commit ``--before`` against the working
tree, both with that commit's config.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from helpers import fixture_models
from test_samples_fixtures import scene_row, write_fixture_inputs

from osgd.camera import KINECT_V2
from osgd.pipeline import load_pipeline, plan_pipeline
from osgd.samples.renderer import RenderObject, available_backends, make_renderer
from osgd.samples.stage import SamplesStage, SamplesStageParams, sample_payload
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
        item = WorkItem("bench", sample_payload(params.key_dict(), 0, "bench"),
                        {table: tuple(values) for table, values in keys.items()})
        stage = SamplesStage()
        stage.build(WorkItem("warm", item.payload, item.inputs), store)  # renderer start-up, imports
        start = time.perf_counter()
        result = stage.build(item, store)
        elapsed = time.perf_counter() - start
    grasps = sum(len(row) for row in result.table["grasps"].to_pylist())
    print(f"stage  {renderer:6s}: {samples / elapsed:6.2f} samples/s ({1000 * elapsed / samples:.0f} ms/sample, "
          f"{grasps / samples:.1f} grasps/sample, one process)")


ROOT = Path(__file__).resolve().parents[1]

#: Functions whose cumulative time the profile of today's path reports, by label.
PROFILED = {
    "read and decode models": "model_rows",
    "read grasps and checks": "load_stable_grasps",
    "render (depth + mask)": "render",
    "silhouettes (visible fraction)": "count",
    "gripper-collision pile (bodies)": "create_object_body",
    "gripper-collision queries": "collides",
    "grasp suppression (NMS)": "suppress",
    "noise": "add_noise",
    "PNG encoding": "encode_depth",
}


def osgd_pipeline(models_dir: Path, data_dir: Path, per_category: int, scenes: int, workers: int) -> list[str]:
    """Build models, grasps, checks and scenes of a subset of the authors' models; the config overrides."""
    subset = data_dir / "osgd-models-subset"
    subset.mkdir(parents=True, exist_ok=True)
    per_seen: dict[str, int] = {}
    for folder in sorted(path for path in models_dir.iterdir() if (path / "model").is_dir()):
        category = folder.name.rsplit("_", 1)[0]
        if per_seen.get(category, 0) < per_category:
            per_seen[category] = per_seen.get(category, 0) + 1
            link = subset / folder.name
            if not link.exists():
                link.symlink_to(folder.resolve(), target_is_directory=True)
    overrides = [f"models.osgd_dir={subset}", f"scenes.count={scenes}"]
    for command in ("annotate", "check", "stack"):
        arguments = [sys.executable, "-m", "osgd", "--data-dir", str(data_dir), "--workers", str(workers), command,
                     "-c", str(ROOT / "pipelines" / "osgd.toml")]
        for override in overrides:
            arguments += ["-s", override]
        print(f"  osgd {command} ({sum(per_seen.values())} models, {scenes} scenes) ...", flush=True)
        result = subprocess.run(arguments, capture_output=True, text=True, check=False,
                                env={**os.environ, "PYTHONHASHSEED": "0"})
        if result.returncode:
            raise SystemExit(f"osgd {command} failed:\n{result.stdout}{result.stderr}")
    return overrides


#: The default "before" of the comparison (``--before``): a commit whose samples stage runs on the same data dir.
BEFORE = "ed5ac77"


def time_items(source: Path, data_dir: Path, overrides: list[str], items: int,
               config: Path = ROOT / "pipelines" / "osgd.toml", stage: str = "samples", summary: bool = False) -> float:
    """Seconds per row of a stage's items of the osgd checkout at ``source``, in a fresh process.

    With ``summary``, the seconds of the stage's summary of all its planned
    shards instead (``benchmarks/time_stage_items.py``).
    """
    arguments = [sys.executable, str(ROOT / "benchmarks" / "time_stage_items.py"), str(data_dir),
                 str(config), "--stage", stage, "--items", str(items)] + (["--summary"] if summary else [])
    for override in overrides:
        arguments += ["-s", override]
    environment = {**os.environ, "PYTHONPATH": str(source), "PYTHONHASHSEED": "0"}
    result = subprocess.run(arguments, check=True, capture_output=True, text=True, env=environment, cwd=source)
    answer = json.loads(result.stdout.strip().splitlines()[-1])
    return float(answer["seconds"] if summary else answer["seconds_per_row"])


def checkout(ref: str, folder: Path) -> Path:
    """The ``osgd`` package of commit ``ref``, unpacked under ``folder``."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", ref, "osgd"], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    return folder


def profile_today(data_dir: Path, overrides: list[str], items: int) -> None:
    """Where today's samples stage spends its time, in this process (cProfile, after a warm-up item)."""
    config = load_pipeline(ROOT / "pipelines" / "osgd.toml", overrides)
    planned = [shard.item for shard in plan_pipeline(config)["samples"]][:items]
    store, stage, profile = ShardStore(data_dir), SamplesStage(), cProfile.Profile()
    stage.build(planned[0], store)
    profile.enable()
    for item in planned[1:]:
        stage.build(item, store)
    profile.disable()
    stats = pstats.Stats(profile).stats
    total = sum(entry[2] for entry in stats.values())  # the own time of every function: the whole
    print("  where today's path spends its time (cumulative, nested calls overlap):")
    for label, name in PROFILED.items():
        seconds = sum(entry[3] for (_, _, function), entry in stats.items() if function == name)
        print(f"    {label:34s} {100 * seconds / total:5.1f} %")


def bench_osgd(models_dir: Path, data_dir: Path, per_category: int, scenes: int, workers: int, before: str) -> None:
    print(f"samples stage on the authors' models ({models_dir}), data in {data_dir}, one process per line:")
    overrides = osgd_pipeline(models_dir, data_dir, per_category, scenes, workers)
    items = max(2, (scenes + 24) // 25)
    with tempfile.TemporaryDirectory() as folder:
        old = checkout(before, Path(folder))
        baseline = time_items(old, data_dir, [*overrides, "samples.renderer=egl"], items)
        print(f"  {before} (before), egl: {baseline * 1000:6.0f} ms/sample ({1 / baseline:5.2f} samples/s)")
        for renderer in ("egl", "embree"):
            seconds = time_items(ROOT, data_dir, [*overrides, f"samples.renderer={renderer}"], items)
            print(f"  today, {renderer:6s}: {seconds * 1000:6.0f} ms/sample ({1 / seconds:5.2f} samples/s), "
                  f"{baseline / seconds:.2f}x")
    profile_today(data_dir, overrides, items)


def bench_built(data_dir: Path, items: int, before: str) -> None:
    """Today's samples stage against commit ``before`` on ``items`` items of a whole build of ``osgd.toml``.

    All 75 of the authors' models and thousands of piles show what a small
    pipeline does not: the per-item reading of every models, grasps and
    checks shard, an embree cache smaller than the models, and a collision
    world that fills with bodies pile after pile.
    """
    print(f"samples stage on {items} items of the build of pipelines/osgd.toml in {data_dir}, one process each:")
    with tempfile.TemporaryDirectory() as folder:
        # Both read the config of ``before``, which names the scenes shards the data dir holds; copied out of
        # pipelines/, its models folder must come from the environment.
        os.environ.setdefault("OSGD_MODELS_DIR", str((ROOT / "pipelines" / "../../shared/osgd-models").resolve()))
        config = Path(folder) / "osgd.toml"
        config.write_bytes(subprocess.run(["git", "-C", str(ROOT), "show", f"{before}:pipelines/osgd.toml"],
                                          check=True, capture_output=True).stdout)
        seconds = {"before": time_items(checkout(before, Path(folder)), data_dir, [], items, config),
                   "today": time_items(ROOT, data_dir, [], items, config)}
    for label, value in seconds.items():
        print(f"  {label:6s} ({before if label == 'before' else 'working tree'}): {value * 1000:6.0f} ms/sample "
              f"({1 / value:5.2f} samples/s)")
    print(f"  ratio: {seconds['before'] / seconds['today']:.2f}x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--samples", type=int, default=12)
    parser.add_argument("--osgd-models", type=Path, default=None, help="the authors' models (OSGD layout)")
    parser.add_argument("--data-dir", type=Path, default=ROOT / ".bench" / "osgd-render",
                        help="where the authors' models' pipeline is built and kept")
    parser.add_argument("--per-category", type=int, default=2, help="authors' models per category")
    parser.add_argument("--scenes", type=int, default=75, help="piles of the authors' models (25 per item)")
    parser.add_argument("--workers", type=int, default=2, help="workers that build the authors' pipeline")
    parser.add_argument("--before", default=BEFORE, help="the commit to compare today's samples stage with")
    parser.add_argument("--built", type=Path, default=None,
                        help="a data dir where `osgd run pipelines/osgd.toml` built the stages before samples: "
                             "time --items of its samples items with --before and today (skips the rest)")
    parser.add_argument("--items", type=int, default=12, help="samples items timed with --built (the first warms up)")
    arguments = parser.parse_args()
    if arguments.built is not None:
        bench_built(arguments.built, arguments.items, arguments.before)
        return
    bench_backends(arguments.frames)
    for renderer in available_backends():
        bench_stage(arguments.samples, renderer)
    if arguments.osgd_models is not None:
        bench_osgd(arguments.osgd_models, arguments.data_dir, arguments.per_category, arguments.scenes,
                   arguments.workers, arguments.before)
    own, children = peak_memory_mib()
    print(f"peak memory: {own:.0f} MiB (this process), {children:.0f} MiB (children: the EGL probe)")


if __name__ == "__main__":
    main()
