"""Run the toy stage from the command line (used by the interruption tests).

usage: python run_toy.py DATA_DIR WORKERS ITEMS

OSGD_TOY_TRACE=DIR logs each build there; OSGD_TOY_DELAY=SECONDS slows each build.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from toy_stage import ToyParams, ToyStage

from osgd.executor import make_executor
from osgd.stage import run_stage
from osgd.store import ShardStore

if __name__ == "__main__":
    data_dir, workers, items = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    stage = ToyStage()
    shards = stage.planned(ToyParams(items=items), 7, {})
    report = run_stage(stage, shards, ShardStore(data_dir), make_executor(workers))
    print(f"built={report.built} reused={report.reused} failed={len(report.failures)}")
    sys.exit(0 if report.ok else 1)
