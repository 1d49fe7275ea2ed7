"""Print the stacking statistics of a build of pipelines/osgd.toml, as the scenes stage's summary computes them.

    PYTHONPATH=CODE python lab/results/osgd-build/stacking_statistics.py DATA_DIR

CODE: the folder holding the ``osgd`` package to measure with (a checkout of
another commit: ``git archive COMMIT osgd | tar -x -C CODE``).
"""

import sys
import time
from pathlib import Path
from types import SimpleNamespace

import osgd
from osgd.pipeline import load_pipeline, plan_pipeline
from osgd.scenes.statistics import stacking_statistics
from osgd.store import ShardStore

config = load_pipeline(Path(__file__).resolve().parents[3] / "pipelines" / "osgd.toml", [])
keys = [shard.key for shard in plan_pipeline(config)["scenes"]]
start = time.perf_counter()
summary, _ = stacking_statistics(ShardStore(sys.argv[1]), [SimpleNamespace(key=key) for key in keys])
print(osgd.__file__, f"{time.perf_counter() - start:.1f} s")
print(summary)
