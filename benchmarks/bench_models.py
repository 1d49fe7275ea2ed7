"""Benchmark of the models stage: models per second and peak memory.

Runs the 75 shared OSGD models and 100 procedural models (10 per category)
through the stage framework with a process pool of 2, in a fresh data dir:

1. cold: nothing built, empty decomposition cache;
2. rebuild: every shard rebuilt (``force``), decompositions from the cache;
3. warm: every shard already done (what a resumed run sees).

Target on a 2-core machine: cold under 5 minutes for all 175,
warm under 10 s.

Usage::

    python benchmarks/bench_models.py [--osgd-dir ../shared/osgd-models] [--workers 2] [--data-dir DIR]
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
from pathlib import Path

from osgd.executor import ProcessPoolExecutor
from osgd.models.stage import ModelsStage
from osgd.stage import run_stage
from osgd.store import ShardStore

DEFAULT_OSGD = Path(__file__).resolve().parents[2] / "shared" / "osgd-models"


def _peak_mib() -> tuple[float, float]:
    """Peak resident memory of this process and of its largest finished child, MiB."""
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    return own, children


def _cpu_seconds() -> float:
    """User + system CPU time of this process and its finished children, s (the machine may be shared)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--osgd-dir", type=Path, default=DEFAULT_OSGD)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--per-category", type=int, default=10)
    parser.add_argument("--data-dir", type=Path, default=None,
                        help="empty folder to build in and keep (for `osgd show models`); default: temporary")
    arguments = parser.parse_args()

    stage = ModelsStage()
    sources = ["procedural", "osgd"] if arguments.osgd_dir.is_dir() else ["procedural"]
    if "osgd" not in sources:
        print(f"no OSGD models at {arguments.osgd_dir}: procedural only")
    params = stage.Params(
        sources=sources, procedural_per_category=arguments.per_category, osgd_dir=str(arguments.osgd_dir)
    )
    executor = ProcessPoolExecutor(arguments.workers)
    with tempfile.TemporaryDirectory(prefix="bench_models_") as temporary:
        data_dir = arguments.data_dir or temporary
        if any(Path(data_dir).glob("models/*.parquet")):
            parser.error(f"{data_dir} already holds models shards: the cold run needs an empty data dir")
        store = ShardStore(data_dir)
        started = time.perf_counter()
        shards = stage.planned(params, 0, {})
        planning = time.perf_counter() - started
        counts = {source: sum(s.item.payload["source"] == source for s in shards) for source in sources}
        print(f"models: {len(shards)} ({counts}); planning {planning:.2f} s; workers {arguments.workers}")
        for label, force in (("cold", False), ("rebuild, cached decompositions", True), ("warm", False)):
            started, cpu_started = time.perf_counter(), _cpu_seconds()
            report = run_stage(stage, shards, store, executor, force=force)
            elapsed = time.perf_counter() - started
            cpu = _cpu_seconds() - cpu_started
            rows = sum(record.rows for record in report.records)
            own, children = _peak_mib()
            print(
                f"{label:<32} {elapsed:8.1f} s  {len(shards) / elapsed:8.2f} models/s  CPU {cpu:7.1f} s  "
                f"built {report.built}, reused {report.reused}, failed {len(report.failures)}, rows {rows}; "
                f"peak RSS main {own:.0f} MiB, largest worker {children:.0f} MiB"
            )
        size = sum(path.stat().st_size for path in (Path(data_dir) / "models").glob("*.parquet"))
        print(f"models table on disk: {size / 2**20:.1f} MiB")


if __name__ == "__main__":
    main()
