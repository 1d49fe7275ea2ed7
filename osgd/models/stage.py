"""The models stage (not implemented yet: issue #3)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import pyarrow as pa

from osgd.stage import PlannedShard, Stage, StageParams, WorkItem
from osgd.store import ShardStore


class ModelsStageParams(StageParams):
    """Parameters of the models stage."""


class ModelsStage(Stage):
    """Object models at real size with physical properties and convex parts."""

    name = "models"
    table = "models"
    version = 1
    inputs = ()
    Params = ModelsStageParams
    description = "Object models at real size with physical properties and convex parts."
    implemented = False

    def plan(
        self, params: StageParams, seed: int, upstream: Mapping[str, Sequence[PlannedShard]]
    ) -> list[WorkItem]:
        return []

    def build(self, item: WorkItem, store: ShardStore) -> pa.Table:
        raise NotImplementedError("the models stage is not implemented yet (issue #3)")
