"""Benchmark of the checks stage: grasp trials per second, and the OSGD set.

1. Trials per second on one core: the fixture tools (tests/helpers.py) with
   grasps across their handles and bodies, run serially in this process,
   first with the rigid pads (``pad_contact = "rigid"``, the baseline),
   then with the soft pads (both criteria come from one trial), then with
   the soft pads and the approach swept against the mesh
   (``approach_geometry = "mesh"``, as ``pipelines/osgd.toml``), and the
   ratios.
2. The whole shared OSGD set (``../shared/osgd-models``, skipped when
   absent): the models and grasps stages are run first (their shards are
   kept under ``--data-dir`` and reused on the next run, and not timed), then
   the checks stage is timed on every grasp (all annotated pairs with their
   approach variants) with ``--workers`` processes. Prints trials per second
   per core, the acceptance summary and the peak resident memory of this
   process and of its worker processes.

Usage::

    python benchmarks/bench_checks.py [--workers 2] [--data-dir DIR] [--quick]
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from helpers import OSGD_MODELS, fixture_models  # noqa: E402

from osgd.checks.params import ChecksStageParams  # noqa: E402
from osgd.checks.trial import approach_surface, run_trial  # noqa: E402
from osgd.gripper import PANDA  # noqa: E402


def peak_memory_mib() -> tuple[float, float]:
    """Peak resident memory of this process and of its largest child, MiB (Linux: ru_maxrss in KiB)."""
    return (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024)


def bench_fixture_trials(count: int, params: ChecksStageParams, label: str) -> float:
    """Time ``count`` trials on one core; returns trials per second."""
    models = fixture_models()
    # Closing across each tool's thickness, approach from above, centres along the tool.
    quaternion = Rotation.from_matrix(np.column_stack([[0, 1, 0], [1, 0, 0], [0, 0, -1]])).as_quat()
    rng = np.random.default_rng(0)
    # As the stage does: each model's surface sampled once for the mesh approach (timed).
    start = time.perf_counter()
    surfaces = [approach_surface(model, params) for model in models]
    sampling = time.perf_counter() - start
    run_trial(models[2], np.zeros(3), quaternion, 0.05, params, PANDA, rng)  # warm-up: imports, client
    outcomes: dict[str, int] = {}
    steps = 0
    start = time.perf_counter()
    for index in range(count):
        model = models[index % len(models)]
        x = rng.uniform(-0.1, 0.1)
        result = run_trial(model, np.array([x, 0.0, 0.0]), quaternion, 0.05, params, PANDA, rng,
                           surface=surfaces[index % len(models)])
        outcomes[result.fail_reason or "stable"] = outcomes.get(result.fail_reason or "stable", 0) + 1
        steps += result.sim_steps
    elapsed = time.perf_counter() - start + sampling
    print(f"fixture tools, {label}: {count} trials in {elapsed:.2f} s on one core: {count / elapsed:.1f} trials/s, "
          f"{1000 * elapsed / count:.1f} ms/trial, {steps / count:.0f} steps/trial, "
          f"{1e6 * elapsed / max(steps, 1):.0f} us/step (all costs included); outcomes {outcomes}")
    return count / elapsed


def bench_osgd_set(data_dir: Path, workers: int) -> None:
    from osgd.config import build_config  # noqa: PLC0415
    from osgd.executor import make_executor  # noqa: PLC0415
    from osgd.pipeline import run_stages, stage_by_name, stage_params_classes  # noqa: PLC0415
    from osgd.store import ShardStore  # noqa: PLC0415

    config = build_config(
        {"pipeline": {"name": "bench-checks", "seed": 0},
         "models": {"sources": ["osgd"], "osgd_dir": str(OSGD_MODELS)}},
        stage_params_classes(),
    )
    store = ShardStore(data_dir)
    executor = make_executor(workers)
    start = time.perf_counter()
    for report in run_stages(config, store, executor, ["models", "grasps"]):
        if not report.ok:
            raise SystemExit(f"{report.stage} failed: {[failure.error for failure in report.failures]}")
    print(f"OSGD set: models and grasps ready in {time.perf_counter() - start:.0f} s (not timed below)")
    start = time.perf_counter()
    (report,) = run_stages(config, store, executor, ["checks"], force=True)
    elapsed = time.perf_counter() - start
    if not report.ok:
        raise SystemExit(f"checks failed: {[failure.error for failure in report.failures]}")
    trials = sum(record.rows for record in report.records)
    print(f"OSGD set: {trials} trials of {len(report.records)} models in {elapsed:.0f} s with {workers} workers: "
          f"{trials / elapsed:.1f} trials/s, {trials / elapsed / workers:.1f} trials/s per core")
    print(stage_by_name("checks").summary(store, report.records))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--trials", type=int, default=150, help="fixture trials timed on one core")
    parser.add_argument("--data-dir", type=Path, default=Path(tempfile.gettempdir()) / "osgd-bench-checks")
    parser.add_argument("--quick", action="store_true", help="fixture trials only")
    arguments = parser.parse_args()
    baseline = bench_fixture_trials(arguments.trials, ChecksStageParams(pad_contact="rigid"), "rigid pads")
    soft = bench_fixture_trials(arguments.trials, ChecksStageParams(), "soft pads, lift and shake")
    mesh = bench_fixture_trials(arguments.trials, ChecksStageParams(approach_geometry="mesh"),
                                "soft pads, approach against the mesh")
    print(f"soft pads against rigid pads, same run: {soft / baseline:.2f}x the trials per second; "
          f"with the approach against the mesh: {mesh / baseline:.2f}x")
    if arguments.quick:
        pass
    elif OSGD_MODELS.is_dir():
        bench_osgd_set(arguments.data_dir, arguments.workers)
    else:
        print(f"OSGD set: skipped, the shared models are not at {OSGD_MODELS}")
    own, children = peak_memory_mib()
    print(f"peak resident memory: {own:.0f} MiB this process, {children:.0f} MiB largest worker")


if __name__ == "__main__":
    main()
