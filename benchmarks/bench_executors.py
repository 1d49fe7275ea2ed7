"""Executor benchmark: items/s per stage through the process pool and Ray, and a projection to a cluster.

Builds one pipeline (default: the golden pipeline with 40 scenes in 8
shards) from scratch once per executor and worker count, in the same run:
serially in this process, through the process pool (``--workers N``) and
through Ray (a local instance with N CPUs, started before the clock runs),
and prints per stage the items, seconds, items/s and seconds per item per
worker. Every build must give the same manifest (checked).

Ray's overhead per item is measured twice: on tasks that do nothing (the
cost of submitting a task and fetching its result, per item), and as the
difference of Ray's and the process pool's stage times per item.

From the per-core figures (the CPU seconds of each stage in the serial
build: what the work takes on a core of its own, even on a machine other work
shares) it projects the wall time of 8,000 and 100,000 scenes on 16, 64 and
256 cores: the models stage for ``--models`` models, the grasps and checks
stages for ``--grasps-per-model`` grasps each (their figures are per grasp:
the golden pipeline draws fewer grasps than the default), then the scenes and
samples stages in shards of ``--scenes-per-shard`` scenes; each stage in
rounds of as many items as there are cores, plus Ray's overhead for every
item counted serially (the driver submits and collects every task): the
larger of a no-op task's wall time and the driver's CPU time per item in the
widest Ray build. That is perfect scaling but for the last round of each
stage; it leaves out the shared folder's bandwidth (the bytes written per
scene are printed), starting the cluster and the driver's planning.

Usage::

    python benchmarks/bench_executors.py                       # golden pipeline, 40 scenes, workers 1 and 2
    python benchmarks/bench_executors.py --workers 1 2 4 --set scenes.count=80
    python benchmarks/bench_executors.py --json bench.json
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from osgd.kernels import pin_kernels

pin_kernels()  # before anything imports numpy: the bytes `osgd` builds
os.environ.setdefault("PYTHONHASHSEED", "0")

from osgd.executor import Executor, ProcessPoolExecutor, RayExecutor, SerialExecutor  # noqa: E402
from osgd.pipeline import load_pipeline, run_stages, stages  # noqa: E402
from osgd.store import ShardStore  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: The projection's scene counts and core counts.
SCENE_COUNTS = (8_000, 100_000)
CORE_COUNTS = (16, 64, 256)


@dataclass
class StageTiming:
    """One stage of one build: items, wall seconds from its start to its last item, and
    this process's CPU seconds meanwhile (all of the work in a serial build; the driver's otherwise)."""

    items: int = 0
    seconds: float = 0.0
    cpu_seconds: float = 0.0

    @property
    def rate(self) -> float:
        return self.items / self.seconds if self.seconds > 0 else float("nan")


@dataclass
class Build:
    """One build of the pipeline by one executor."""

    label: str
    backend: str
    workers: int
    stages: dict[str, StageTiming] = field(default_factory=dict)
    manifest: str = ""
    bytes_per_table: dict[str, int] = field(default_factory=dict)


class _Clock:
    """``on_stage`` / ``on_item`` callbacks that time each stage."""

    def __init__(self) -> None:
        self.timings: dict[str, StageTiming] = {}
        self._started: dict[str, tuple[float, float]] = {}

    def on_stage(self, name: str, total: int) -> None:
        self._started[name] = (time.perf_counter(), time.process_time())
        self.timings[name] = StageTiming(total)

    def on_item(self, name: str, item: str, status: str) -> None:
        wall, cpu = self._started[name]
        self.timings[name].seconds = time.perf_counter() - wall
        self.timings[name].cpu_seconds = time.process_time() - cpu


def _bytes_per_table(data_dir: Path) -> dict[str, int]:
    return {stage.table: sum(path.stat().st_size for path in (data_dir / stage.table).glob("*.parquet"))
            for stage in stages()}


def timed_build(label: str, backend: str, workers: int, executor: Executor, overrides: Sequence[str],
                pipeline: Path) -> Build:
    """Build ``pipeline`` from scratch in a temporary data dir; the stage timings."""
    config = load_pipeline(pipeline, overrides)
    data_dir = Path(tempfile.mkdtemp(prefix="osgd-bench-executors-"))
    try:
        clock = _Clock()
        names = tuple(stage.name for stage in stages())
        reports = run_stages(config, ShardStore(data_dir), executor, names,
                             on_stage=clock.on_stage, on_item=clock.on_item)
        failed = [failure.item_id for report in reports for failure in report.failures]
        if failed:
            raise SystemExit(f"{label}: items failed: {failed}")
        manifest = (data_dir / "manifests" / f"{config.pipeline.name}.json").read_text()
        return Build(label, backend, workers, clock.timings, manifest, _bytes_per_table(data_dir))
    finally:
        shutil.rmtree(data_dir, ignore_errors=True)


def noop_seconds_per_item(executor: Executor, count: int) -> float:
    """Wall seconds per task of ``count`` tasks that do nothing (``abs``)."""
    start = time.perf_counter()
    for _ in executor.map_unordered(abs, list(range(count))):
        pass
    return (time.perf_counter() - start) / count


def _ray_build(workers: int, overrides: Sequence[str], pipeline: Path, noop: int) -> tuple[Build, float, float]:
    """A build through a fresh local Ray instance of ``workers`` CPUs; also its start time and no-op overhead."""
    executor = RayExecutor(workers=workers)
    start = time.perf_counter()
    executor.connect()
    started = time.perf_counter() - start
    try:
        noop_seconds_per_item(executor, workers * 4)  # start the worker processes
        build = timed_build(f"ray, {workers} worker(s)", "ray", workers, executor, overrides, pipeline)
        overhead = noop_seconds_per_item(executor, noop)
    finally:
        executor.close()
    return build, started, overhead


def run_builds(worker_counts: Sequence[int], overrides: Sequence[str], pipeline: Path, noop: int) -> dict:
    """Every build, Ray's start times and the no-op overheads per item."""
    builds = [timed_build("serial (this process)", "serial", 1, SerialExecutor(), overrides, pipeline)]
    overheads: dict[str, float] = {"serial": noop_seconds_per_item(SerialExecutor(), noop)}
    ray_starts: dict[int, float] = {}
    for workers in worker_counts:
        pool = ProcessPoolExecutor(workers)
        builds.append(timed_build(f"process pool, {workers} worker(s)", "process", workers, pool, overrides,
                                  pipeline))
        overheads[f"process pool, {workers}"] = noop_seconds_per_item(pool, noop)
        build, ray_starts[workers], overheads[f"ray, {workers}"] = _ray_build(workers, overrides, pipeline, noop)
        builds.append(build)
    return {"builds": builds, "ray_starts": ray_starts, "noop": overheads}


# -- printing ------------------------------------------------------------------------------


def print_stage_table(builds: Sequence[Build]) -> None:
    """Items/s per stage and build; seconds per item per worker in brackets."""
    names = list(builds[0].stages)
    print("items/s per stage (seconds per item per worker):")
    print(f"  {'build':28s}" + "".join(f"{name:>20s}" for name in names) + f"{'total s':>10s}")
    for build in builds:
        cells = []
        for name in names:
            timing = build.stages[name]
            cells.append(f"{timing.rate:8.2f} ({timing.seconds * build.workers / timing.items:6.2f}s)")
        total = sum(timing.seconds for timing in build.stages.values())
        print(f"  {build.label:28s}" + "".join(f"{cell:>20s}" for cell in cells) + f"{total:10.1f}")


def ray_overhead_per_item(builds: Sequence[Build]) -> dict[int, float]:
    """Per worker count: (Ray's stage seconds - the pool's) summed over stages, per item."""
    result = {}
    for ray_build in (build for build in builds if build.backend == "ray"):
        pool = next(build for build in builds if build.backend == "process" and build.workers == ray_build.workers)
        items = sum(timing.items for timing in ray_build.stages.values())
        difference = sum(ray_build.stages[name].seconds - pool.stages[name].seconds for name in ray_build.stages)
        result[ray_build.workers] = difference * ray_build.workers / items
    return result


def driver_cpu_per_item(build: Build) -> float:
    """The driver's own CPU seconds per item (submitting, collecting, verifying) of a parallel build."""
    items = sum(timing.items for timing in build.stages.values())
    return sum(timing.cpu_seconds for timing in build.stages.values()) / items


def print_driver_cpu(builds: Sequence[Build]) -> None:
    print("driver CPU ms per item: " + ", ".join(f"{build.label} {driver_cpu_per_item(build) * 1000:.1f}"
                                                 for build in builds[1:]))


# -- projecting ----------------------------------------------------------------------------


@dataclass(frozen=True)
class PerCore:
    """CPU seconds of one core per unit of work of each stage."""

    per_model: float  # the models stage, per model
    per_grasp: dict[str, float]  # grasps and checks, per grasp (a grasp is a row of both tables)
    per_scene: dict[str, float]  # scenes and samples, per scene (one view)
    overhead_per_item: float


def per_core_figures(build: Build, scene_count: int, overhead: float) -> PerCore:
    """Per-model, per-grasp and per-scene core seconds of a serial build of ``scene_count`` scenes.

    CPU seconds, not wall seconds: on a machine that other work shares, a
    process's CPU time is what it would take on a core of its own.
    """
    rows = {name: entry["rows"] for name, entry in json.loads(build.manifest)["stages"].items()}
    models = build.stages["models"]
    per_grasp = {name: build.stages[name].cpu_seconds / rows[name] for name in ("grasps", "checks")}
    per_scene = {name: build.stages[name].cpu_seconds / scene_count for name in ("scenes", "samples")}
    return PerCore(models.cpu_seconds / models.items, per_grasp, per_scene, overhead)


@dataclass(frozen=True)
class Scale:
    """What is projected: models, grasps per model, scenes per shard."""

    models: int
    grasps_per_model: int
    scenes_per_shard: int


def projected_seconds(figures: PerCore, scenes: int, cores: int, scale: Scale) -> float:
    """Wall seconds: each stage in rounds of ``cores`` items, plus the driver's overhead for every item."""

    def stage(items: int, seconds_per_item: float) -> float:
        return math.ceil(items / cores) * seconds_per_item + items * figures.overhead_per_item

    shards = math.ceil(scenes / scale.scenes_per_shard)
    total = stage(scale.models, figures.per_model)
    total += sum(stage(scale.models, seconds * scale.grasps_per_model) for seconds in figures.per_grasp.values())
    total += sum(stage(shards, seconds * scale.scenes_per_shard) for seconds in figures.per_scene.values())
    return total


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def print_projection(figures: PerCore, scale: Scale, bytes_per_scene: float) -> list[dict]:
    """The projection table; its rows."""
    rows = []
    print(f"\nprojected wall time ({scale.models} models of {scale.grasps_per_model} grasps; shards of "
          f"{scale.scenes_per_shard} scenes; {figures.overhead_per_item * 1000:.1f} ms Ray overhead per item):")
    print(f"  {'scenes':>8s}" + "".join(f"{f'{cores} cores':>12s}" for cores in CORE_COUNTS)
          + f"{'core-hours':>12s}{'written':>10s}")
    for scenes in SCENE_COUNTS:
        times = [projected_seconds(figures, scenes, cores, scale) for cores in CORE_COUNTS]
        core_hours = projected_seconds(figures, scenes, 1, scale) / 3600
        written = bytes_per_scene * scenes / 1e9
        print(f"  {scenes:8,d}" + "".join(f"{_duration(seconds):>12s}" for seconds in times)
              + f"{core_hours:12.1f}{written:8.1f} GB")
        rows.append({"scenes": scenes, "seconds": dict(zip(CORE_COUNTS, times, strict=True)),
                     "core_hours": core_hours, "gigabytes": written})
    return rows


def _arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pipeline", type=Path, default=ROOT / "pipelines" / "golden.toml")
    parser.add_argument("--set", dest="overrides", action="append",
                        default=["scenes.count=40", "scenes.scenes_per_shard=5"],
                        help="config overrides (repeatable); default: 40 scenes in shards of 5")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--noop", type=int, default=400, help="no-op tasks for the overhead per item")
    parser.add_argument("--models", type=int, default=100, help="models in the projection (pipelines/default.toml)")
    parser.add_argument("--grasps-per-model", type=int, default=119,
                        help="grasps per model in the projection (default.toml's record: 11,900 of 100 models)")
    parser.add_argument("--scenes-per-shard", type=int, default=25, help="the projection's shard size")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    arguments = parser.parse_args()
    return arguments


def _check_same_manifests(builds: Sequence[Build]) -> None:
    differing = [build.label for build in builds if build.manifest != builds[0].manifest]
    if differing:
        raise SystemExit(f"manifests differ from the serial build's: {differing}")
    print(f"every build gave the same manifest ({len(builds)} builds)")


def print_measured(builds: Sequence[Build], measured: dict) -> None:
    """The stage table, Ray's start, the no-op overheads, Ray against the pool, the driver's CPU."""
    print_stage_table(builds)
    print("Ray start (local instance): " + ", ".join(f"{workers} CPU(s) {seconds:.1f} s"
                                                    for workers, seconds in measured["ray_starts"].items()))
    print("no-op task, wall ms per item: " + ", ".join(f"{label} {seconds * 1000:.2f}"
                                                       for label, seconds in measured["noop"].items()))
    differences = ray_overhead_per_item(builds)
    print("Ray - process pool, stage seconds per item per worker: "
          + ", ".join(f"{workers} worker(s) {seconds:+.3f} s" for workers, seconds in differences.items()))
    print_driver_cpu(builds)


def main() -> int:
    arguments = _arguments()
    if importlib.util.find_spec("ray") is None:
        print("Ray is not installed (pip install -e '.[ray]'): nothing to compare; skipped")
        return 0
    scene_count = load_pipeline(arguments.pipeline, arguments.overrides).params["scenes"].count
    print(f"{arguments.pipeline.name} with {arguments.overrides}: {scene_count} scenes; "
          f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}")
    measured = run_builds(arguments.workers, arguments.overrides, arguments.pipeline, arguments.noop)
    builds: list[Build] = measured["builds"]
    _check_same_manifests(builds)
    print_measured(builds, measured)
    serial, widest = builds[0], max(arguments.workers)
    ray_widest = next(build for build in builds if build.backend == "ray" and build.workers == widest)
    overhead = max(measured["noop"][f"ray, {widest}"], driver_cpu_per_item(ray_widest))
    figures = per_core_figures(serial, scene_count, overhead)
    print(f"per core (serial CPU seconds): models {figures.per_model:.3f} s per model, "
          + ", ".join(f"{name} {seconds * 1000:.1f} ms per grasp" for name, seconds in figures.per_grasp.items())
          + ", " + ", ".join(f"{name} {seconds:.3f} s per scene" for name, seconds in figures.per_scene.items()))
    scale = Scale(arguments.models, arguments.grasps_per_model, arguments.scenes_per_shard)
    written = (serial.bytes_per_table["samples"] + serial.bytes_per_table["scenes"]) / scene_count
    rows = print_projection(figures, scale, written)
    check = projected_seconds(figures, 1000, 2, scale)
    print(f"check: pipelines/default.toml (1,000 scenes) on 2 cores projects to {_duration(check)} "
          "(README: about 19 minutes from a fresh clone, install included)")
    if arguments.json:
        _write_json(arguments.json, builds, measured, figures, rows)
    print(f"load average now {os.getloadavg()[0]:.2f}")
    return 0


def _write_json(path: Path, builds: Sequence[Build], measured: dict, figures: PerCore, rows: list[dict]) -> None:
    document = {
        "builds": [{"label": build.label, "backend": build.backend, "workers": build.workers,
                    "stages": {name: {"items": timing.items, "seconds": timing.seconds,
                                      "cpu_seconds": timing.cpu_seconds}
                               for name, timing in build.stages.items()}} for build in builds],
        "ray_starts": measured["ray_starts"], "noop_seconds_per_item": measured["noop"],
        "per_core": {"per_model": figures.per_model, "per_grasp": figures.per_grasp, "per_scene": figures.per_scene,
                     "overhead_per_item": figures.overhead_per_item},
        "projection": rows,
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(document, indent=1) + "\n")


if __name__ == "__main__":
    sys.exit(main())
