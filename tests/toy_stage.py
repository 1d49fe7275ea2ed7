"""A small real stage for testing the framework: it writes ``checks`` rows.

It lives in its own importable module so that spawned worker processes and
subprocesses can load it, exactly as they load the pipeline's stages.
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping, Sequence

import numpy as np
import pyarrow as pa
from pydantic import Field

from osgd.contract.schemas import CHECKS
from osgd.stage import BuildResult, PlannedShard, Stage, StageParams, WorkItem
from osgd.store import ShardStore


class ToyParams(StageParams):
    items: int = Field(6, description="How many shards to plan.")
    rows: int = Field(50, description="Rows per shard.")
    scale: float = Field(1.0, description="Multiplies every value.")
    fail_item: int = Field(-1, description="Index of an item whose build raises; -1 for none.")
    workdir: str = Field("", description="Where builds leave a trace file.", json_schema_extra={"location": True})


class ToyStage(Stage):
    """Seeded random rows; optionally reads an upstream toy table."""

    name = "toy"
    table = "checks"
    version = 1
    inputs = ()
    Params = ToyParams

    def plan(self, params: StageParams, seed: int, upstream: Mapping[str, Sequence[PlannedShard]]) -> list[WorkItem]:
        assert isinstance(params, ToyParams)
        payload = params.key_dict()
        return [
            WorkItem(f"toy_{index:03d}", {"params": payload, "seed": seed, "index": index})
            for index in range(params.items)
        ]

    def build(self, item: WorkItem, store: ShardStore) -> BuildResult:
        params = item.payload["params"]
        index = item.payload["index"]
        # The trace is a test hook outside the payload, so it never changes keys.
        trace_dir = os.environ.get("OSGD_TOY_TRACE")
        if trace_dir:
            with open(os.path.join(trace_dir, "builds.log"), "a") as trace:
                trace.write(f"{item.item_id}\n")
        # Slowing builds down (to interrupt a run halfway) must not change keys.
        time.sleep(float(os.environ.get("OSGD_TOY_DELAY", "0")))
        if index == params["fail_item"]:
            raise RuntimeError(f"item {index} is set to fail")
        rng = np.random.default_rng([item.payload["seed"], index])
        rows = params["rows"]
        table = pa.table(
            {
                "model_id": pa.array([f"m{index}"] * rows),
                "grasp_id": pa.array(np.arange(rows, dtype=np.int32)),
                "stable": pa.array(stable := rng.random(rows) > 0.5),
                "lift_stable": pa.array(stable),
                "shake_stable": pa.array(stable),
                "fail_reason": pa.array([""] * rows),
                "slip_distance": pa.array(rng.random(rows) * params["scale"]),
                "slip_rotation": pa.array(rng.random(rows)),
                "final_opening": pa.array(rng.random(rows)),
                "sim_steps": pa.array(rng.integers(0, 100, rows).astype(np.int32)),
            },
            schema=CHECKS,
        )
        return BuildResult(table, [f"built {item.item_id}"] if index == 0 else [])
