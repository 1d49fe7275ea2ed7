"""The grasps stage (not implemented yet: issue #4)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import pyarrow as pa

from osgd.stage import PlannedShard, Stage, StageParams, WorkItem
from osgd.store import ShardStore


class GraspsStageParams(StageParams):
    """Parameters of the grasps stage."""


class GraspsStage(Stage):
    """6-DoF parallel-jaw grasps with task labels."""

    name = "grasps"
    table = "grasps"
    version = 1
    inputs = ('models',)
    Params = GraspsStageParams
    description = "6-DoF parallel-jaw grasps with task labels."
    implemented = False

    def plan(
        self, params: StageParams, seed: int, upstream: Mapping[str, Sequence[PlannedShard]]
    ) -> list[WorkItem]:
        return []

    def build(self, item: WorkItem, store: ShardStore) -> pa.Table:
        raise NotImplementedError("the grasps stage is not implemented yet (issue #4)")
