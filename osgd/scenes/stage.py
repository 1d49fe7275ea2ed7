"""The scenes stage (not implemented yet: issue #6)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import pyarrow as pa

from osgd.stage import PlannedShard, Stage, StageParams, WorkItem
from osgd.store import ShardStore


class ScenesStageParams(StageParams):
    """Parameters of the scenes stage."""


class ScenesStage(Stage):
    """Stacks of 3-6 objects dropped in pybullet."""

    name = "scenes"
    table = "scenes"
    version = 1
    inputs = ('models',)
    Params = ScenesStageParams
    description = "Stacks of 3-6 objects dropped in pybullet."
    implemented = False

    def plan(
        self, params: StageParams, seed: int, upstream: Mapping[str, Sequence[PlannedShard]]
    ) -> list[WorkItem]:
        return []

    def build(self, item: WorkItem, store: ShardStore) -> pa.Table:
        raise NotImplementedError("the scenes stage is not implemented yet (issue #6)")
