"""Wall time of each item of a pipeline's checks stage: the stage's own build, on 2 processes (issue #22).

    python lab/results/checks-speed/check_times.py DATA pipelines/osgd.toml OUT.json

DATA must hold the pipeline's models and grasps (``osgd annotate``). Prints each item as it ends (time since
the start, the item's seconds, trials, physics steps) and writes {item: [seconds, trials, steps]} to OUT.json.
"""
import json
import multiprocessing
import sys
import time
from pathlib import Path

from osgd.pipeline import load_pipeline, plan_pipeline, stage_by_name
from osgd.store import ShardStore


def build_item(task: tuple[str, str, int]) -> tuple[str, float, int, int]:
    data_dir, config_path, index = task
    shard = plan_pipeline(load_pipeline(config_path))["checks"][index]
    start = time.perf_counter()
    table = stage_by_name("checks").build(shard.item, ShardStore(Path(data_dir))).table
    seconds = time.perf_counter() - start
    return shard.item.item_id, seconds, table.num_rows, sum(table.column("sim_steps").to_pylist())


if __name__ == "__main__":
    data_dir, config_path, out = sys.argv[1:4]
    count = len(plan_pipeline(load_pipeline(config_path))["checks"])
    times = {}
    started = time.perf_counter()
    with multiprocessing.get_context("spawn").Pool(2) as pool:
        tasks = [(data_dir, config_path, index) for index in range(count)]
        for item_id, seconds, trials, steps in pool.imap_unordered(build_item, tasks):
            times[item_id] = (seconds, trials, steps)
            print(f"{time.perf_counter() - started:7.1f} {item_id} {seconds:.1f}s {trials} trials {steps} steps",
                  flush=True)
    Path(out).write_text(json.dumps(times, indent=1))
    print("total", time.perf_counter() - started)
