"""The scenes stage: piles of 3-6 objects dropped in pybullet until at rest.

Plan: ``count`` scenes in shards of ``scenes_per_shard`` (``scenes_000``,
``scenes_001``, ...), each shard reading every ``models`` shard. A scene's
random draws depend on the pipeline seed, its index and the attempt only
(:func:`osgd.scenes.drop.attempt_seed`), so the shard size changes no scene.
With ``split.by = "model"`` each pile draws from the models of its own side
only (:mod:`osgd.scenes.split`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import pyarrow as pa

from osgd.contract.schemas import SCENES
from osgd.contract.shards import ShardRecord
from osgd.scenes.drop import MODEL_COLUMNS, ModelPool, generate_scene, scene_id
from osgd.scenes.params import ScenesStageParams
from osgd.scenes.split import SIDES, SplitParams, model_sides, pile_side
from osgd.stage import BuildResult, PlannedShard, Stage, StageParams, WorkItem, read_once_per_worker
from osgd.store import ShardStore


def worker_model_pool(store: ShardStore, keys: Sequence[str], item_id: str) -> ModelPool:
    """The :class:`ModelPool` of the models shards ``keys``, read once per worker.

    Every scenes item of a pipeline names the same models shards
    (:func:`osgd.stage.read_once_per_worker`; reading them for each item
    would cost a large share of its time).

    Parameters
    ----------
    store : ShardStore
    keys : sequence of str
        The item's ``models`` shard keys.
    item_id : str
        Named in the error message.

    Returns
    -------
    ModelPool

    Raises
    ------
    ValueError
        If the models table has no rows.
    """
    def read() -> ModelPool:
        models = store.read_many("models", list(keys), MODEL_COLUMNS)
        if models.num_rows == 0:
            raise ValueError(f"{item_id}: the models table ({len(keys)} shard(s) under {store.root / 'models'}) "
                             "has no rows, so no scene can be drawn")
        return ModelPool(models.to_pylist())

    return read_once_per_worker("scenes: model pool", store, keys, read)


def worker_side_pools(store: ShardStore, keys: Sequence[str], item_id: str,
                      split: SplitParams) -> dict[str, ModelPool | None]:
    """The train and the test models of the models shards ``keys`` as two pools, read once per worker.

    Parameters
    ----------
    store : ShardStore
    keys : sequence of str
        The item's ``models`` shard keys.
    item_id : str
        Named in the error message.
    split : SplitParams
        A ``by = "model"`` rule (:func:`osgd.scenes.split.model_sides`).

    Returns
    -------
    dict of side to ModelPool, or to None where the side has no model

    Raises
    ------
    ValueError
        If the models table has no rows, or ``split.test_models`` names no model.
    """
    def read() -> dict[str, ModelPool | None]:
        rows = worker_model_pool(store, keys, item_id).rows
        sides = model_sides(rows, split)
        pools: dict[str, ModelPool | None] = {}
        for side in SIDES:
            chosen = [row for row in rows if sides[str(row["model_id"])] == side]
            pools[side] = ModelPool(chosen) if chosen else None
        return pools

    return read_once_per_worker("scenes: side pools", store, [*keys, split.model_dump_json()], read)


class ScenesStage(Stage):
    """Piles of 3-6 objects dropped in pybullet until they come to rest."""

    name = "scenes"
    table = "scenes"
    version = 4
    inputs = ("models",)
    Params = ScenesStageParams
    description = "Piles of 3-6 objects dropped from 30 cm in pybullet until they come to rest."

    def plan(
        self, params: StageParams, seed: int, upstream: Mapping[str, Sequence[PlannedShard]]
    ) -> list[WorkItem]:
        assert isinstance(params, ScenesStageParams)
        model_keys = tuple(sorted(shard.key for shard in upstream.get("models", ())))
        shards = -(-params.count // params.scenes_per_shard)
        digits = max(3, len(str(max(shards - 1, 0))))
        items = []
        for shard in range(shards):
            first = shard * params.scenes_per_shard
            last = min(params.count, first + params.scenes_per_shard)
            payload = {"params": params.key_dict(), "seed": seed, "first_scene": first, "scene_count": last - first}
            items.append(WorkItem(f"scenes_{shard:0{digits}d}", payload, {"models": model_keys}))
        return items

    def build(self, item: WorkItem, store: ShardStore) -> BuildResult:
        params = ScenesStageParams(**item.payload["params"])
        keys = tuple(item.inputs["models"])
        pool = worker_model_pool(store, keys, item.item_id)
        side_pools = worker_side_pools(store, keys, item.item_id, params.split) if params.split.by == "model" else {}
        rows, notes = [], []
        first = int(item.payload["first_scene"])
        for scene_index in range(first, first + int(item.payload["scene_count"])):
            if side_pools:
                side = pile_side(scene_id(scene_index), params.split)
                pool = side_pools[side]
                if pool is None:
                    raise ValueError(f"{item.item_id}: [scenes.split] holds out {'every' if side == 'train' else 'no'} "
                                     f"model, so {scene_id(scene_index)}, a {side} pile, has no {side} model to "
                                     "draw; change model_fraction, per_category or test_models")
            result = generate_scene(pool, params, int(item.payload["seed"]), scene_index)
            if result.row is None:
                reasons = ", ".join(f"{reason} {count}" for reason, count in sorted(result.rejections.items()))
                notes.append(f"scene {scene_index} left out: all {params.max_attempts} attempts rejected ({reasons})")
                continue
            rows.append(result.row)
        return BuildResult(pa.Table.from_pylist(rows, schema=SCENES), notes)

    def summary(self, store: ShardStore, records: Sequence[ShardRecord]) -> str:
        """Objects per scene, contacts, top-down overlap and occlusion, rejections."""
        from osgd.scenes.statistics import format_statistics, stacking_statistics  # noqa: PLC0415

        summary, simulation = stacking_statistics(store, records)
        return format_statistics(summary, simulation)
