"""The checks stage (not implemented yet: issue #5)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import pyarrow as pa

from osgd.stage import PlannedShard, Stage, StageParams, WorkItem
from osgd.store import ShardStore


class ChecksStageParams(StageParams):
    """Parameters of the checks stage."""


class ChecksStage(Stage):
    """Simulated grasp trials in pybullet."""

    name = "checks"
    table = "checks"
    version = 1
    inputs = ('models', 'grasps')
    Params = ChecksStageParams
    description = "Simulated grasp trials in pybullet."
    implemented = False

    def plan(
        self, params: StageParams, seed: int, upstream: Mapping[str, Sequence[PlannedShard]]
    ) -> list[WorkItem]:
        return []

    def build(self, item: WorkItem, store: ShardStore) -> pa.Table:
        raise NotImplementedError("the checks stage is not implemented yet (issue #5)")
