"""The samples stage (not implemented yet: issue #7)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import pyarrow as pa

from osgd.stage import PlannedShard, Stage, StageParams, WorkItem
from osgd.store import ShardStore


class SamplesStageParams(StageParams):
    """Parameters of the samples stage."""


class SamplesStage(Stage):
    """Noisy depth images with boxes and task-labelled grasp rectangles."""

    name = "samples"
    table = "samples"
    version = 1
    inputs = ('models', 'grasps', 'checks', 'scenes')
    Params = SamplesStageParams
    description = "Noisy depth images with boxes and task-labelled grasp rectangles."
    implemented = False

    def plan(
        self, params: StageParams, seed: int, upstream: Mapping[str, Sequence[PlannedShard]]
    ) -> list[WorkItem]:
        return []

    def build(self, item: WorkItem, store: ShardStore) -> pa.Table:
        raise NotImplementedError("the samples stage is not implemented yet (issue #7)")
