"""Time a stage's build of a pipeline's items, or its summary, in this process (a helper of the benchmarks).

A script, not a module of osgd: ``bench_render.py`` and ``bench_scenes.py``
run it in a fresh process against an older checkout of osgd (on
``PYTHONPATH``) and against the working tree in the same run, so it imports
only what older versions have too (``osgd.pipeline``, the stages, the
store). Prints one JSON line.

    python benchmarks/time_stage_items.py DATA_DIR CONFIG [--stage samples] [-s KEY=VALUE ...] [--items 3]
    python benchmarks/time_stage_items.py DATA_DIR CONFIG --stage scenes --summary
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from types import SimpleNamespace

from osgd.pipeline import load_pipeline, plan_pipeline
from osgd.samples.stage import SamplesStage
from osgd.scenes.stage import ScenesStage
from osgd.store import ShardStore

STAGES = {"samples": SamplesStage, "scenes": ScenesStage}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data_dir", type=Path)
    parser.add_argument("config", type=Path)
    parser.add_argument("--stage", choices=sorted(STAGES), default="samples")
    parser.add_argument("-s", "--set", dest="overrides", action="append", default=[])
    parser.add_argument("--items", type=int, default=3, help="items to build: the first warms up, the rest are timed")
    parser.add_argument("--summary", action="store_true",
                        help="time the stage's summary of all its planned shards (already built) instead")
    arguments = parser.parse_args()
    config = load_pipeline(arguments.config, arguments.overrides)
    planned = plan_pipeline(config)[arguments.stage]
    store = ShardStore(arguments.data_dir)
    stage = STAGES[arguments.stage]()
    if arguments.summary:
        start = time.perf_counter()
        stage.summary(store, [SimpleNamespace(key=shard.key) for shard in planned])
        print(json.dumps({"seconds": time.perf_counter() - start}))
        return
    items = [shard.item for shard in planned][: arguments.items]
    if len(items) < 2:
        raise SystemExit(f"{len(items)} {arguments.stage} item(s) planned; at least 2 are needed "
                         "(a warm-up and one timed)")
    stage.build(items[0], store)  # a worker builds many items: its caches are warm after one
    rows = 0
    start = time.perf_counter()
    for item in items[1:]:
        rows += stage.build(item, store).table.num_rows
    seconds = time.perf_counter() - start
    print(json.dumps({"rows": rows, "seconds": seconds, "seconds_per_row": seconds / rows}))


if __name__ == "__main__":
    main()
