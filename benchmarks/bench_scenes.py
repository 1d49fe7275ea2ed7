"""Benchmark of the scenes stage: scenes per second per core, steps, memory.

Runs in one process (one core): the same scenes are dropped twice, once
stopping at rest (the stage's rule) and once for a fixed 3 s of simulated
time after the last release (what the original generator did, REFERENCE
section 2), and the ratio is printed. Target: under 0.5 s per
scene per core on average, so that the paper's 8,000 scenes take under 30
minutes on 2 cores.

Then the same scenes again with each convex part colliding as its reduced
hull of ``--max-hull-vertices`` corners (``scenes.max_hull_vertices``):
the time ratio, the hulls' corners and shrink, and, for both
runs side by side, the piles' statistics (contacts measured on the stored
parts, top-down overlap and occlusion on the meshes) and the deepest
interpenetration of the stored parts per pile.

With ``--config``, the stage with that pipeline's ``[scenes]`` parameters
against the reduced hulls dropped with a new pybullet client per attempt
(the stage before :func:`osgd.physics.worker_client`): the time ratio, the piles'
statistics and how still the piles are (each simulated again for 1 s)
side by side. Where the config sets ``maximal_coordinates``, the config
with multibodies runs as a third arm, so that the option's own effect
shows.

With ``--built DATA_DIR`` (a whole build of ``pipelines/osgd.toml``) it only
times ``--items`` of that build's scenes items and the stage's summary (the
stacking statistics ``osgd run`` prints) in fresh one-core processes,
commit ``--before`` against the working tree.

It then prints where the stage's time goes (cProfile over the first run):
the share of the attempts that were thrown away, creating the bodies, the
per-step blow-up test and the physics steps.

Usage::

    python benchmarks/bench_scenes.py                      # test fixture models
    python benchmarks/bench_scenes.py --data-dir DATA      # every models row under DATA
    python benchmarks/bench_scenes.py --osgd-models ../shared/osgd-models --scenes 60   # the authors' models
    python benchmarks/bench_scenes.py --scenes 40 --seed 1
    python benchmarks/bench_scenes.py --osgd-models ../shared/osgd-models --scenes 200 --config pipelines/osgd.toml
    python benchmarks/bench_scenes.py --osgd-models ../shared/osgd-models --scenes 200 --config pipelines/osgd.toml \
        --config-only
    python benchmarks/bench_scenes.py --built DATA_DIR --before COMMIT [--items 9]

``--osgd-models`` builds (once; kept in ``.bench/osgd-render``) the small
pipeline of 20 of the paper authors' models that ``bench_render.py
--osgd-models`` uses, and stacks those models.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import resource
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from osgd.physics import get_mesh_pose, physics_client, pybullet_module, reduced_hull
from osgd.scenes import drop
from osgd.scenes.drop import MODEL_COLUMNS, ModelPool, generate_scene, stored_penetration
from osgd.scenes.params import ScenesStageParams
from osgd.scenes.statistics import STATISTICS_COLUMNS, StackingSummary, scene_statistics, summarize_statistics
from osgd.scenes.views import load_models
from osgd.store import ShardStore


def load_pool(data_dir: Path | None) -> tuple[ModelPool, str]:
    """The models of a data dir, or the test fixtures when none is given."""
    if data_dir is None:
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
        from helpers import fixture_models  # noqa: PLC0415

        return ModelPool(fixture_models()), "test fixtures (hammer, screwdriver, block)"
    store = ShardStore(data_dir)
    keys = store.keys_on_disk("models")
    table = store.read_many("models", keys, MODEL_COLUMNS)
    return ModelPool(table.to_pylist()), f"{table.num_rows} models from {data_dir}"


def run(pool: ModelPool, params: ScenesStageParams, seed: int, scenes: int) -> dict[str, Any]:
    """Drop ``scenes`` scenes serially; times in wall seconds, steps simulated, the kept scene rows."""
    seconds, steps, sim_times, attempts, rows = [], [], [], [], []
    rejections: Counter = Counter()
    for index in range(scenes):
        start = time.perf_counter()
        result = generate_scene(pool, params, seed, index)
        seconds.append(time.perf_counter() - start)
        rejections.update(result.rejections)
        if result.row is not None:
            rows.append(result.row)
            steps.append(result.row["sim_steps"])
            sim_times.append(result.row["sim_time"])
            attempts.append(result.row["attempts"])
    return {
        "seconds_per_scene": float(np.mean(seconds)),
        "median_seconds": float(np.median(seconds)),
        "p90_seconds": float(np.percentile(seconds, 90)),
        "steps_per_scene": float(np.mean(steps)) if steps else 0.0,
        "sim_time": float(np.mean(sim_times)) if sim_times else 0.0,
        "attempts": float(np.mean(attempts)) if attempts else 0.0,
        "accepted": float(len(steps)),
        "rejections": dict(sorted(rejections.items())),
        "rows": rows,
    }


def hull_figures(pool: ModelPool, max_vertices: int) -> str:
    """Corners per convex part before and after :func:`osgd.physics.reduced_hull`, and its shrink."""
    before, after, shrink = [], [], []
    for row in pool.rows:
        for part in row["convex_parts"]:
            vertices = np.asarray(part["vertices"], dtype=np.float64).reshape(-1, 3)
            corners, _, reach = reduced_hull(vertices, max_vertices)
            before.append(len(vertices))
            after.append(len(corners))
            shrink.append(reach)
    return (f"{len(before)} convex parts: corners {np.median(before):.0f} median, {max(before)} max -> "
            f"{np.median(after):.0f} median, {max(after)} max; the part beyond the reduced hull's planes "
            f"{1000 * np.median(shrink):.2f} mm median, {1000 * np.percentile(shrink, 90):.2f} mm p90, "
            f"{1000 * max(shrink):.2f} mm max")


def penetration_figures(pool: ModelPool, rows: list[dict[str, Any]]) -> str:
    """The deepest interpenetration of the stored parts per kept pile (objects, floor, walls)."""
    models = {str(row["model_id"]): row for row in pool.rows}
    depths = []
    for row in rows:
        poses = [(np.asarray(obj["position"]), np.asarray(obj["quaternion"])) for obj in row["objects"]]
        depths.append(1000 * stored_penetration([models[obj["model_id"]] for obj in row["objects"]], poses,
                                                ScenesStageParams())[0])
    return (f"{np.median(depths):.2f} mm median, {np.percentile(depths, 90):.2f} mm p90, {max(depths):.2f} mm max"
            if depths else "no piles")


def pile_figures(data_dir: Path | None, rows: list[dict[str, Any]]) -> StackingSummary | None:
    """The stacking statistics of kept scene rows (``None`` for the test fixtures, which have no data dir)."""
    if data_dir is None or not rows:
        return None
    ids = {obj["model_id"] for row in rows for obj in row["objects"]}
    models = load_models(ShardStore(data_dir), ids, STATISTICS_COLUMNS)
    return summarize_statistics([scene_statistics(row, models) for row in rows])


def compare_hulls(pool: ModelPool, data_dir: Path | None, seed: int, scenes: int, max_vertices: int,
                  stored: dict[str, Any]) -> None:
    """The at-rest run again with reduced hulls; times, hulls and pile statistics beside the stored parts'."""
    hulls = run(pool, ScenesStageParams(max_hull_vertices=max_vertices), seed, scenes)
    print(f"reduced hulls of {max_vertices} corners: {hull_figures(pool, max_vertices)}")
    print(f"  {hulls['seconds_per_scene']:.3f} s per scene per core (median {hulls['median_seconds']:.3f}, "
          f"p90 {hulls['p90_seconds']:.3f}), {hulls['steps_per_scene']:.0f} steps per accepted scene, "
          f"{hulls['attempts']:.2f} attempts, rejections {hulls['rejections']}")
    print(f"  ratio stored parts / reduced hulls (wall time per scene): "
          f"{stored['seconds_per_scene'] / hulls['seconds_per_scene']:.2f}")
    print_pile_figures(data_dir, ("stored parts", stored["rows"]), ("reduced hulls", hulls["rows"]))
    for label, rows in (("stored parts", stored["rows"]), ("reduced hulls", hulls["rows"])):
        print(f"  interpenetration of the stored parts per pile, {label}: {penetration_figures(pool, rows)}")


def compare_config(pool: ModelPool, data_dir: Path | None, seed: int, scenes: int, config: Path,
                   max_vertices: int) -> None:
    """The config's ``[scenes]`` parameters against the reduced hulls alone dropped with a new client per attempt.

    Before: a new pybullet client per attempt and per stored-parts check
    (today's :func:`osgd.physics.worker_client` swapped for
    :func:`osgd.physics.physics_client`, as the stage did until then),
    reduced hulls, every other parameter at its default. After: the stage
    as it is, with the config's parameters. Where the config sets
    ``maximal_coordinates``, a third run, the config with multibodies,
    shows that option alone.
    """
    from contextlib import contextmanager  # noqa: PLC0415

    from osgd.pipeline import load_pipeline  # noqa: PLC0415

    @contextmanager
    def new_client(timestep: float = 1.0 / 240.0, gravity: float = -9.81) -> Any:
        with physics_client(timestep, gravity) as client:
            yield client

    configured = load_pipeline(config).params["scenes"]
    assert isinstance(configured, ScenesStageParams)
    before = ScenesStageParams(max_hull_vertices=max_vertices)
    kept = drop.worker_client
    drop.worker_client = new_client
    try:
        arms = [("before", before, run(pool, before, seed, scenes))]
    finally:
        drop.worker_client = kept
    if configured.maximal_coordinates:
        multibody = configured.model_copy(update={"maximal_coordinates": False})
        arms.append(("multibody", multibody, run(pool, multibody, seed, scenes)))
    arms.append(("after", configured, run(pool, configured, seed, scenes)))
    changed = {name: value for name, value in configured.key_dict().items()
               if name not in ("count", "max_hull_vertices") and value != ScenesStageParams().key_dict().get(name)}
    print(f"{config}'s [scenes] ({changed}) against reduced hulls of {max_vertices} corners dropped as before"
          + (" (multibody: the config without maximal_coordinates)" if configured.maximal_coordinates else "") + ":")
    for label, _, figures in arms:
        print(f"  {label:9s} {figures['seconds_per_scene']:.3f} s per scene per core (median "
              f"{figures['median_seconds']:.3f}), {figures['steps_per_scene']:.0f} steps per accepted scene, "
              f"{figures['attempts']:.2f} attempts, rejections {figures['rejections']}")
    after = arms[-1][2]
    for label, _, figures in arms[:-1]:
        print(f"  ratio {label} / after (wall time per scene): "
              f"{figures['seconds_per_scene'] / after['seconds_per_scene']:.2f}")
    print_pile_figures(data_dir, *((label, figures["rows"]) for label, _, figures in arms))
    for label, params, figures in arms:
        print(f"  {label}: simulated again for 1 s, {rest_quality(pool, figures['rows'], params)}")


def rest_quality(pool: ModelPool, rows: list[dict[str, Any]], params: ScenesStageParams) -> str:
    """How still the kept piles are: each simulated again for 1 s from its stored poses, at rest.

    Per pile, the largest displacement and turn of any of its objects
    (colliding as they were dropped: ``params.max_hull_vertices``); the
    share of piles beyond 3 mm or 0.03 rad is what the scenes tests bound.
    """
    models = {str(row["model_id"]): row for row in pool.rows}
    pybullet = pybullet_module()
    moved, turned = [], []
    for row in rows:
        with physics_client(timestep=params.timestep) as client:
            drop.build_world(client, params)
            bodies = [drop.pile_body(client, models[obj["model_id"]], np.asarray(obj["position"]),
                                     np.asarray(obj["quaternion"]), params)
                      for obj in row["objects"]]
            for _ in range(round(1.0 / params.timestep)):
                pybullet.stepSimulation(physicsClientId=client)
            poses = [get_mesh_pose(body) for body in bodies]
        moved.append(max(float(np.linalg.norm(position - obj["position"]))
                         for (position, _), obj in zip(poses, row["objects"], strict=True)))
        turned.append(max((Rotation.from_quat(quaternion) * Rotation.from_quat(obj["quaternion"]).inv()).magnitude()
                          for (_, quaternion), obj in zip(poses, row["objects"], strict=True)))
    if not rows:
        return "no piles"
    moved_mm, turned_rad = 1000 * np.array(moved), np.array(turned)
    beyond = np.mean((moved_mm > 3.0) | (turned_rad > 0.03))
    return (f"moved {np.median(moved_mm):.2f} mm median ({np.percentile(moved_mm, 90):.2f} p90), turned "
            f"{np.median(turned_rad):.4f} rad median ({np.percentile(turned_rad, 90):.4f} p90); piles beyond 3 mm "
            f"or 0.03 rad: {100 * beyond:.1f} %")


def print_pile_figures(data_dir: Path | None, *runs: tuple[str, list[dict[str, Any]]]) -> None:
    """The piles' statistics of runs side by side (nothing for the test fixtures)."""
    names = ("touching_share", "lying_on_share", "off_floor_share", "overlapping_share", "occluded_share",
             "mean_occlusion")
    figures = [pile_figures(data_dir, rows) for _, rows in runs]
    if any(figure is None for figure in figures):
        return
    labels = " / ".join(label for label, _ in runs)
    objects = " / ".join(str(figure.objects) for figure in figures)
    print(f"  piles ({objects} objects), {labels}: "
          + ", ".join(f"{name.removesuffix('_share')} "
                      + " / ".join(f"{getattr(figure, name):.2f}" for figure in figures) for name in names))


#: Functions whose cumulative time the profile reports, by label.
PROFILED = {
    "physics steps": "<built-in method pybullet.stepSimulation>",
    "creating the bodies": "create_object_body",
    "blow-up test per step": "_runaway",
    "walls and floor": "build_world",
}


def where_time_goes(pool: ModelPool, params: ScenesStageParams, seed: int, scenes: int) -> None:
    """Drop ``scenes`` scenes under cProfile; print the thrown-away attempts' share and the profiled functions'."""
    attempts: list[tuple[bool, int, float]] = []
    simulate = drop.simulate_drop

    def timed(*arguments: Any, **options: Any) -> drop.DropOutcome:
        start = time.perf_counter()
        outcome = simulate(*arguments, **options)
        attempts.append((not outcome.reason, outcome.sim_steps, time.perf_counter() - start))
        return outcome

    profile = cProfile.Profile()
    drop.simulate_drop = timed
    try:
        profile.enable()
        for index in range(scenes):
            generate_scene(pool, params, seed, index)
        profile.disable()
    finally:
        drop.simulate_drop = simulate
    kept = [attempt for attempt in attempts if attempt[0]]
    thrown = [attempt for attempt in attempts if not attempt[0]]
    total = sum(attempt[2] for attempt in attempts)
    print(f"where the time goes ({len(attempts)} attempts):")
    for label, group in (("kept attempts", kept), ("thrown-away attempts", thrown)):
        print(f"  {label:24s} {len(group):4d}, {sum(a[1] for a in group):6d} steps, "
              f"{100 * sum(a[2] for a in group) / total:5.1f} % of the time")
    stats = pstats.Stats(profile).stats
    whole = sum(entry[2] for entry in stats.values())
    for label, name in PROFILED.items():
        seconds = sum(entry[3] for (_, _, function), entry in stats.items() if function == name)
        print(f"  {label:24s} {100 * seconds / whole:5.1f} % (cumulative)")


def bench_built(data_dir: Path, items: int, before: str) -> None:
    """Today's scenes stage and stacking statistics against commit ``before``, on a whole build of ``osgd.toml``.

    Both time the same ``items`` scenes items (the first warms up) in fresh
    one-core processes, then the stage's summary (the stacking statistics
    of 200 of the build's piles, which ``osgd run`` prints after the stage).
    """
    from bench_render import ROOT, checkout, time_items  # noqa: PLC0415 - the same helpers as the samples stage's

    print(f"scenes stage on {items} items of the build of pipelines/osgd.toml in {data_dir}, one process each:")
    config = ROOT / "pipelines" / "osgd.toml"
    times = {}
    with tempfile.TemporaryDirectory() as folder:
        old = checkout(before, Path(folder))
        for label, source in ((before, old), ("working tree", ROOT)):
            per_scene = time_items(source, data_dir, [], items, config, stage="scenes")
            summary = time_items(source, data_dir, [], items, config, stage="scenes", summary=True)
            times[label] = per_scene, summary
            print(f"  {label:12s}: {per_scene:.3f} s per scene per core; the stage's summary {summary:.1f} s",
                  flush=True)
    (stage_before, summary_before), (stage_today, summary_today) = times[before], times["working tree"]
    print(f"  ratio: {stage_before / stage_today:.2f}x the stage, {summary_before / summary_today:.2f}x its summary")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data-dir", type=Path, default=None, help="data dir with a models table")
    parser.add_argument("--osgd-models", type=Path, default=None,
                        help="the authors' models (OSGD layout): build 2 per category into --data-dir "
                             "(default .bench/osgd-render, shared with bench_render.py) and stack those")
    parser.add_argument("--scenes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-hull-vertices", type=int, default=32,
                        help="corners of the reduced hulls compared with the stored parts (0: no comparison)")
    parser.add_argument("--config", type=Path, default=None,
                        help="a pipeline config whose [scenes] parameters to compare with the reduced hulls "
                             "dropped with a new pybullet client per attempt (e.g. pipelines/osgd.toml)")
    parser.add_argument("--config-only", action="store_true",
                        help="with --config: only that comparison (no baselines, no profile)")
    parser.add_argument("--built", type=Path, default=None,
                        help="a data dir where `osgd run pipelines/osgd.toml` built the scenes: time --items of its "
                             "scenes items and the stage's summary with --before and today (skips the rest)")
    parser.add_argument("--before", default="b370b67", help="with --built: the commit to compare today's with")
    parser.add_argument("--items", type=int, default=9, help="with --built: scenes items timed (the first warms up)")
    arguments = parser.parse_args()
    if arguments.built is not None:
        bench_built(arguments.built, arguments.items, arguments.before)
        return
    if arguments.osgd_models is not None:
        from bench_render import ROOT, osgd_pipeline  # noqa: PLC0415 - the same small pipeline of the authors' models

        arguments.data_dir = arguments.data_dir or ROOT / ".bench" / "osgd-render"
        osgd_pipeline(arguments.osgd_models, arguments.data_dir, per_category=2, scenes=75, workers=2)
    pool, description = load_pool(arguments.data_dir)
    print(f"models: {description}; {arguments.scenes} scenes, seed {arguments.seed}, one process")

    if arguments.config is not None and arguments.config_only:
        compare_config(pool, arguments.data_dir, arguments.seed, arguments.scenes, arguments.config,
                       arguments.max_hull_vertices)
        return
    at_rest = run(pool, ScenesStageParams(), arguments.seed, arguments.scenes)
    fixed = run(pool, ScenesStageParams(fixed_sim_time=3.0, reject_unsettled=False), arguments.seed,
                arguments.scenes)
    for label, figures in (("until at rest", at_rest), ("fixed 3 s after the last release", fixed)):
        print(
            f"{label:34s}: {figures['seconds_per_scene']:.3f} s per scene per core "
            f"(median {figures['median_seconds']:.3f}, p90 {figures['p90_seconds']:.3f}), "
            f"{1 / figures['seconds_per_scene']:.2f} scenes/s per core, "
            f"{figures['steps_per_scene']:.0f} steps ({figures['sim_time']:.2f} s simulated) per accepted scene, "
            f"{figures['attempts']:.2f} attempts, {figures['accepted']:.0f} accepted, "
            f"rejections {figures['rejections']}"
        )
    ratio = at_rest["seconds_per_scene"] / fixed["seconds_per_scene"]
    print(f"ratio at rest / fixed 3 s (wall time per scene): {ratio:.2f}")
    hours_8000 = 8000 * at_rest["seconds_per_scene"] / 2 / 3600
    print(f"8,000 scenes on 2 cores: about {hours_8000 * 60:.1f} minutes (target: under 30)")
    if arguments.max_hull_vertices > 0:
        compare_hulls(pool, arguments.data_dir, arguments.seed, arguments.scenes, arguments.max_hull_vertices,
                      at_rest)
    if arguments.config is not None:
        compare_config(pool, arguments.data_dir, arguments.seed, arguments.scenes, arguments.config,
                       arguments.max_hull_vertices)
    where_time_goes(pool, ScenesStageParams(), arguments.seed, arguments.scenes)
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(f"peak memory: {own:.0f} MiB (this process), {children:.0f} MiB (children)")


if __name__ == "__main__":
    main()
