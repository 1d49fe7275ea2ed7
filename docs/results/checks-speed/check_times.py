"""Per-item wall time of the checks stage of a pipeline, 2 processes, longest last as planned."""
import sys, time, json, multiprocessing as mp
from pathlib import Path

def work(args):
    import os
    data_dir, config_path, index = args
    from osgd.pipeline import load_pipeline, plan_pipeline, stage_by_name
    from osgd.store import ShardStore
    config = load_pipeline(config_path)
    shard = plan_pipeline(config)["checks"][index]
    stage = stage_by_name("checks")
    store = ShardStore(Path(data_dir))
    start = time.perf_counter()
    result = stage.build(shard.item, store)
    seconds = time.perf_counter() - start
    table = result.table
    steps = sum(table.column("sim_steps").to_pylist())
    return shard.item.item_id, seconds, table.num_rows, steps

if __name__ == "__main__":
    data_dir, config_path = sys.argv[1], sys.argv[2]
    from osgd.pipeline import load_pipeline, plan_pipeline
    n = len(plan_pipeline(load_pipeline(config_path))["checks"])
    out = {}
    t0 = time.perf_counter()
    with mp.get_context("spawn").Pool(2) as pool:
        for item, seconds, rows, steps in pool.imap_unordered(work, [(data_dir, config_path, i) for i in range(n)]):
            out[item] = (seconds, rows, steps)
            print(f"{time.perf_counter()-t0:7.1f} {item} {seconds:.1f}s {rows} trials {steps} steps", flush=True)
    json.dump(out, open(sys.argv[3], "w"), indent=1)
    print("total", time.perf_counter() - t0)
