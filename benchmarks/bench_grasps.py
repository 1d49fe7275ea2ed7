"""Throughput of the grasps stage: OSGD pair conversion and antipodal sampling.

Runs in one process (so the figures are per core) on:

- one shared OSGD model per category (../shared/osgd-models; skipped when
  absent), rows built as in tests/test_grasps_osgd.py: their annotated pairs
  are converted; then the same meshes without pairs go through the sampler
  (no part labels, so every label is "no task": the geometry is what costs);
- the part-labelled fixture tools of tests/helpers.py through the sampler.

Prints grasps per second, pairs per second and the peak resident memory.

    python benchmarks/bench_grasps.py [--repeat N]
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from helpers import OSGD_MODELS, fixture_models, models_table  # noqa: E402
from test_grasps_osgd import osgd_row  # noqa: E402

from osgd.contract.taxonomy import CATEGORIES  # noqa: E402
from osgd.grasps.labels import effective_rules  # noqa: E402
from osgd.grasps.model_grasps import GraspAnnotator, ModelInput  # noqa: E402
from osgd.grasps.params import GraspsStageParams  # noqa: E402
from osgd.gripper import PANDA  # noqa: E402


def measure(label: str, rows: list[dict], repeat: int) -> None:
    params = GraspsStageParams()
    rules = effective_rules({})
    table = models_table(rows)
    models = [ModelInput.from_table(table, index) for index in range(table.num_rows)]
    grasps = pairs = 0
    started = time.perf_counter()
    for run in range(repeat):
        for model in models:
            result = GraspAnnotator(model, params, rules, PANDA, seed=run).grasps()
            grasps += result.num_rows
            pairs += len(set(result.column("pair_index").to_pylist()))
    seconds = time.perf_counter() - started
    print(f"{label:<38} {len(models) * repeat:4d} models {grasps:6d} grasps {seconds:7.2f} s  "
          f"{grasps / seconds:7.1f} grasps/s  {pairs / seconds:6.1f} pairs/s  "
          f"{seconds / (len(models) * repeat):5.2f} s/model")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=1, help="passes over the models")
    args = parser.parse_args()
    print("grasps stage throughput, one process (per core); defaults of GraspsStageParams")
    if OSGD_MODELS.is_dir():
        rows = [osgd_row(sorted(OSGD_MODELS.glob(f"{category}_*"))[0]) for category in CATEGORIES]
        measure("OSGD pair conversion (10 models)", rows, args.repeat)
        measure("antipodal sampler, OSGD meshes", [{**row, "annotated_pairs": []} for row in rows], args.repeat)
    else:
        print(f"(no shared OSGD models at {OSGD_MODELS}: OSGD figures skipped)")
    measure("antipodal sampler, fixture tools", fixture_models(), args.repeat)
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(f"peak resident memory: {own:.0f} MiB (children {children:.0f} MiB)")


if __name__ == "__main__":
    main()
