"""The checks stage: every grasp tried in pybullet.

One work item per ``models`` shard, paired with the ``grasps`` shard of the
same item id (the grasps stage plans exactly one per models shard); it
writes one ``checks`` shard with one row per grasp. A models shard with no
rows (a rejected model) has no grasps and gives an empty checks shard.

The trial itself: :mod:`osgd.checks.trial`; the simulated hand:
:mod:`osgd.checks.hand`; the parameters: :mod:`osgd.checks.params`; the
acceptance summary: :mod:`osgd.checks.summary`. ``docs/checks.md`` explains
the design and the evidence.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
from collections.abc import Mapping, Sequence

import numpy as np
import pyarrow as pa

from osgd.checks.params import ChecksStageParams
from osgd.checks.summary import acceptance_counts, format_acceptance
from osgd.checks.trial import TrialResult, approach_surface, run_trial
from osgd.contract.schemas import CHECKS, vectors_from_arrow
from osgd.contract.shards import ShardRecord
from osgd.gripper import PANDA, Gripper
from osgd.stage import BuildResult, PlannedShard, Stage, StageParams, WorkItem
from osgd.store import ShardStore

log = logging.getLogger(__name__)

__all__ = ["ChecksStage", "ChecksStageParams", "trial_seed"]


def trial_seed(seed: int, model_id: str, grasp_id: int) -> np.random.Generator:
    """The random generator of one trial, from the pipeline seed and the grasp's identity.

    Seeding per grasp (not per shard) keeps a trial's outcome independent of
    which other grasps its model has.
    """
    model_number = int.from_bytes(hashlib.sha256(model_id.encode("utf-8")).digest()[:8], "little")
    return np.random.default_rng([int(seed), model_number, int(grasp_id)])


class ChecksStage(Stage):
    """Simulated grasp trials in pybullet."""

    name = "checks"
    table = "checks"
    # Bump whenever the outcome of a trial for the same inputs changes.
    version = 3
    inputs = ("models", "grasps")
    Params = ChecksStageParams
    description = "Simulated grasp trials in pybullet."

    def __init__(self) -> None:
        # item id -> (models key, grasps key) of the last plan, so that
        # summary() can find the shards its records were built from.
        self._planned_inputs: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {}
        self._approach_geometry = "auto"

    def plan(
        self, params: StageParams, seed: int, upstream: Mapping[str, Sequence[PlannedShard]]
    ) -> list[WorkItem]:
        """One item per models shard, paired with the grasps shard of the same item id.

        The payload holds the parameters, the seed and the gripper's
        dimensions, so a change to any of them gives new shard keys. The
        approach geometry is resolved per models item (``auto``: the mesh
        for a user's mesh); the convex hulls, the only approach before
        ``auto``, stay out of the payload, so those shards keep their keys.
        A models shard without a grasps shard (its grasps item failed and
        was left out of the plan) gets no item.
        """
        assert isinstance(params, ChecksStageParams)
        self._approach_geometry = params.approach_geometry
        grasps_by_item = {shard.item.item_id: shard.key for shard in upstream.get("grasps", ())}
        common = {key: value for key, value in params.key_dict().items() if key != "approach_geometry"}
        items = []
        for shard in upstream.get("models", ()):
            item_id = shard.item.item_id
            if item_id not in grasps_by_item:
                log.info("checks: models item %s has no grasps shard (its grasps failed); not checked", item_id)
                continue
            mesh = params.approach_for(shard.item.payload.get("source")) == "mesh"
            item_params = {**common, "approach_geometry": "mesh"} if mesh else common
            payload = {"params": item_params, "seed": int(seed), "gripper": dataclasses.asdict(PANDA)}
            inputs = {"models": (shard.key,), "grasps": (grasps_by_item[item_id],)}
            items.append(WorkItem(item_id, payload, inputs))
            self._planned_inputs[item_id] = (inputs["models"], inputs["grasps"])
        return items

    def build(self, item: WorkItem, store: ShardStore) -> BuildResult:
        """Try every grasp of every model of the item's shards, in grasp-id order."""
        # a payload without approach_geometry is one of the convex hulls (plan)
        params = ChecksStageParams(**{"approach_geometry": "hulls", **item.payload["params"]})
        gripper = Gripper(**item.payload["gripper"])
        seed = int(item.payload["seed"])
        models = store.read_many("models", item.inputs.get("models", ()))
        grasps = store.read_many("grasps", item.inputs.get("grasps", ()))
        model_rows = {row["model_id"]: row for row in models.to_pylist()}
        notes: list[str] = []
        grasp_model_ids = grasps.column("model_id").to_pylist()
        unknown = sorted(set(grasp_model_ids) - set(model_rows))
        if unknown:
            notes.append(f"{len(unknown)} model ids of the grasps shard are not in the models shard; "
                         f"their grasps are not checked: {unknown[:3]}")
        positions = vectors_from_arrow(grasps.column("position"), 3)
        quaternions = vectors_from_arrow(grasps.column("quaternion"), 4)
        widths = grasps.column("width").to_numpy()
        grasp_ids = grasps.column("grasp_id").to_pylist()
        order = sorted(
            (index for index, model_id in enumerate(grasp_model_ids) if model_id in model_rows),
            key=lambda index: (grasp_model_ids[index], grasp_ids[index]),
        )
        rows: list[dict] = []
        surfaces = {model_id: approach_surface(model, params) for model_id, model in model_rows.items()}
        for index in order:
            model_id, grasp_id = grasp_model_ids[index], int(grasp_ids[index])
            result: TrialResult = run_trial(
                model_rows[model_id], positions[index], quaternions[index], float(widths[index]),
                params, gripper, trial_seed(seed, model_id, grasp_id), surface=surfaces[model_id],
            )
            rows.append({"model_id": model_id, "grasp_id": grasp_id, **dataclasses.asdict(result)})
        stable = sum(row["stable"] for row in rows)
        log.debug("checks %s: %d of %d grasps stable", item.item_id, stable, len(rows))
        return BuildResult(pa.Table.from_pylist(rows, schema=CHECKS), notes)

    def summary(self, store: ShardStore, records: list[ShardRecord]) -> str:
        """Acceptance rate per category and per task, as text tables."""
        grasps_keys = {item_id: inputs[1] for item_id, inputs in self._planned_inputs.items()}
        return format_acceptance(acceptance_counts(store, records, grasps_keys), self._approach_geometry)
