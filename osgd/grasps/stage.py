"""The grasps stage: 6-DoF parallel-jaw grasps with task labels.

One work item per ``models`` shard, with the same item id, reading exactly
that shard; it writes one ``grasps`` shard holding the grasps of every model
of the models shard (none for a shard with no rows, i.e. a rejected model).
The checks stage pairs models and grasps shards by that item id.

How each model's grasps are made: :mod:`osgd.grasps.model_grasps`; the label
rules: :mod:`osgd.grasps.labels`; the collision test:
:mod:`osgd.grasps.geometry`; all documented in ``docs/grasps.md``.
"""

from __future__ import annotations

import dataclasses
import logging
from collections import Counter
from collections.abc import Mapping, Sequence

import pyarrow as pa

from osgd.contract.schemas import GRASPS
from osgd.contract.shards import ShardRecord
from osgd.contract.taxonomy import CATEGORIES, TASKS
from osgd.grasps.labels import LabelRule, effective_rules
from osgd.grasps.model_grasps import GraspAnnotator, ModelInput, rules_payload
from osgd.grasps.params import GraspsStageParams
from osgd.gripper import PANDA, Gripper
from osgd.models.parts import without_task_labels
from osgd.stage import BuildResult, PlannedShard, Stage, StageParams, WorkItem, item_taxonomy
from osgd.store import ShardStore

log = logging.getLogger(__name__)

__all__ = ["GraspsStage", "GraspsStageParams"]


class GraspsStage(Stage):
    """6-DoF parallel-jaw grasps with task labels."""

    name = "grasps"
    table = "grasps"
    # Bump whenever the grasps of the same models change (3: the tool axis points to the first working part).
    version = 3
    inputs = ("models",)
    Params = GraspsStageParams
    uses_taxonomy = True
    description = "6-DoF parallel-jaw grasps with task labels."

    def plan(
        self, params: StageParams, seed: int, upstream: Mapping[str, Sequence[PlannedShard]]
    ) -> list[WorkItem]:
        """One item per models shard, same item id (module text).

        The payload holds the parameters, the seed, the gripper's dimensions
        and the effective label rules of Table I's categories, so a change to
        any of them (including the defaults in code) gives new shard keys; a
        pipeline's own taxonomy, with its rules, joins the payload
        (:meth:`osgd.stage.Stage.planned`).
        """
        assert isinstance(params, GraspsStageParams)
        payload = {
            "params": params.key_dict(),
            "seed": int(seed),
            "gripper": dataclasses.asdict(PANDA),
            "rules": rules_payload(effective_rules(params.label_rules)),
        }
        return [
            WorkItem(shard.item.item_id, payload, {"models": (shard.key,)})
            for shard in upstream.get("models", ())
        ]

    def build(self, item: WorkItem, store: ShardStore) -> BuildResult:
        """The grasps of every model in the item's models shard."""
        params = GraspsStageParams(**item.payload["params"])
        taxonomy = item_taxonomy(item)
        rules = effective_rules({category: LabelRule(**rule) for category, rule in item.payload["rules"].items()},
                                taxonomy)
        gripper = Gripper(**item.payload["gripper"])
        (models_key,) = item.inputs["models"]
        models = store.read("models", models_key)
        tables = []
        notes: list[str] = []
        for row in range(models.num_rows):
            model = ModelInput.from_table(models, row, taxonomy)
            annotator = GraspAnnotator(model, params, rules, gripper, item.payload["seed"])
            tables.append(annotator.grasps())
            notes.extend(annotator.notes)
            log.debug("%s: %d grasps", model.name, tables[-1].num_rows)
        table = pa.concat_tables(tables) if tables else GRASPS.empty_table()
        return BuildResult(table, notes)

    def summary(self, store: ShardStore, records: list[ShardRecord]) -> str:
        """Grasps per category and task, as a text table."""
        counts = grasp_counts(store, records)
        return format_counts(counts, unlabelled_note(store, records, counts))


def unlabelled_note(store: ShardStore, records: Sequence[ShardRecord], counts: Counter[tuple[str, str]]) -> str:
    """How many grasps have no task, and how many of them belong to models without part labels or hand-made pairs."""
    unlabelled: set[str] = set()
    for key in store.keys_on_disk("models"):
        models = store.read("models", key, columns=["model_id", "name", "face_parts", "annotated_pairs"])
        names = set(without_task_labels(models))
        unlabelled.update(m for m, n in zip(models["model_id"].to_pylist(), models["name"].to_pylist(), strict=True)
                          if n in names)
    on_unlabelled = 0
    for record in records:
        grasps = store.read("grasps", record.key, columns=["model_id"])
        on_unlabelled += sum(model_id in unlabelled for model_id in grasps.column("model_id").to_pylist())
    no_task = sum(count for (_, task), count in counts.items() if task == "no task")
    return (f"no task: {no_task} of {sum(counts.values())} grasps, {on_unlabelled} of them on "
            f"{len(unlabelled)} models without part labels or hand-made pairs (docs/models.md, automatic parts)")


def grasp_counts(store: ShardStore, records: Sequence[ShardRecord]) -> Counter[tuple[str, str]]:
    """(category, task) -> number of grasps in the given grasps shards.

    Categories come from the models shards on disk (read by column, so cheap);
    a grasp whose model is not found counts under category ``"?"``.
    """
    categories: dict[str, str] = {}
    for key in store.keys_on_disk("models"):
        models = store.read("models", key, columns=["model_id", "category"])
        categories.update(zip(models.column("model_id").to_pylist(), models.column("category").to_pylist(),
                              strict=True))
    counts: Counter[tuple[str, str]] = Counter()
    for record in records:
        grasps = store.read("grasps", record.key, columns=["model_id", "task"])
        for model_id, task in zip(grasps.column("model_id").to_pylist(), grasps.column("task").to_pylist(),
                                  strict=True):
            counts[(categories.get(model_id, "?"), task)] += 1
    return counts


def format_counts(counts: Counter[tuple[str, str]], note: str = "") -> str:
    """A text table: one row per category, one column per task seen, totals; ``note`` ends the title line."""
    if not counts:
        return "grasps: none"
    tasks = [task for task in (*TASKS, *sorted({task for _, task in counts} - set(TASKS)))
             if any(key[1] == task for key in counts)]
    extra = sorted({category for category, _ in counts} - set(CATEGORIES))
    categories = [category for category in (*CATEGORIES, *extra) if any(key[0] == category for key in counts)]
    header = ["category", *tasks, "total"]
    lines = [header]
    for category in categories:
        values = [counts.get((category, task), 0) for task in tasks]
        lines.append([category, *map(str, values), str(sum(values))])
    totals = [sum(counts.get((category, task), 0) for category in categories) for task in tasks]
    lines.append(["total", *map(str, totals), str(sum(totals))])
    widths = [max(len(line[column]) for line in lines) for column in range(len(header))]
    text = [
        "  ".join(cell.ljust(widths[0]) if column == 0 else cell.rjust(widths[column])
                  for column, cell in enumerate(line))
        for line in lines
    ]
    return "grasps per category and task" + (f" ({note})" if note else "") + "\n" + "\n".join(text)
