"""Time the samples stage's build of a pipeline's items in this process (a helper of bench_render.py).

Imports only what every version of osgd since issue #19 has, so that
``bench_render.py`` can run it against an older checkout (``PYTHONPATH``)
and against today's in the same run. Prints one JSON line.

    python benchmarks/time_samples_items.py DATA_DIR CONFIG [-s KEY=VALUE ...] [--items 3]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from osgd.pipeline import load_pipeline, plan_pipeline
from osgd.samples.stage import SamplesStage
from osgd.store import ShardStore


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data_dir", type=Path)
    parser.add_argument("config", type=Path)
    parser.add_argument("-s", "--set", dest="overrides", action="append", default=[])
    parser.add_argument("--items", type=int, default=3, help="items to build: the first warms up, the rest are timed")
    arguments = parser.parse_args()
    config = load_pipeline(arguments.config, arguments.overrides)
    items = [shard.item for shard in plan_pipeline(config)["samples"]][: arguments.items]
    if len(items) < 2:
        raise SystemExit(f"{len(items)} samples item(s) planned; at least 2 are needed (a warm-up and one timed)")
    store = ShardStore(arguments.data_dir)
    stage = SamplesStage()
    stage.build(items[0], store)  # a worker builds many items: its caches and the renderer are warm after one
    samples = 0
    start = time.perf_counter()
    for item in items[1:]:
        samples += stage.build(item, store).table.num_rows
    seconds = time.perf_counter() - start
    print(json.dumps({"samples": samples, "seconds": seconds, "seconds_per_sample": seconds / samples}))


if __name__ == "__main__":
    main()
