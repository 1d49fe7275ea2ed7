"""The pipeline: the stages in data-flow order, planning and manifests.

::

    models -> grasps -> checks -> scenes -> samples
    (annotate)          (check)   (stack)   (render)
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from osgd.config import PipelineConfig, load_config
from osgd.executor import Executor
from osgd.schemas import SCHEMA_VERSION
from osgd.stage import PlannedShard, Stage, StageReport, run_stage
from osgd.store import ShardStore

log = logging.getLogger(__name__)


def _stages() -> tuple[Stage, ...]:
    from osgd.checks.stage import ChecksStage  # noqa: PLC0415
    from osgd.grasps.stage import GraspsStage  # noqa: PLC0415
    from osgd.models.stage import ModelsStage  # noqa: PLC0415
    from osgd.samples.stage import SamplesStage  # noqa: PLC0415
    from osgd.scenes.stage import ScenesStage  # noqa: PLC0415

    return (ModelsStage(), GraspsStage(), ChecksStage(), ScenesStage(), SamplesStage())


_STAGES: tuple[Stage, ...] | None = None


def stages() -> tuple[Stage, ...]:
    """Every stage, in data-flow order."""
    global _STAGES
    if _STAGES is None:
        _STAGES = _stages()
    return _STAGES


def stage_by_name(name: str) -> Stage:
    """The stage called ``name``.

    Raises
    ------
    KeyError
    """
    for stage in stages():
        if stage.name == name:
            return stage
    raise KeyError(f"no stage {name!r}; stages: {[stage.name for stage in stages()]}")


#: The CLI commands and the stages each runs.
COMMAND_STAGES: dict[str, tuple[str, ...]] = {
    "annotate": ("models", "grasps"),
    "check": ("checks",),
    "stack": ("scenes",),
    "render": ("samples",),
}


def stage_params_classes() -> dict[str, type]:
    """Stage name to its Params class, for :func:`osgd.config.load_config`."""
    return {stage.name: stage.Params for stage in stages()}


def load_pipeline(path: str | Path, overrides: Sequence[str] = ()) -> PipelineConfig:
    """Load a pipeline config with every stage's parameters validated."""
    return load_config(path, stage_params_classes(), overrides)


def plan_pipeline(config: PipelineConfig) -> dict[str, list[PlannedShard]]:
    """The planned shards of every stage; reads no shard content."""
    planned: dict[str, list[PlannedShard]] = {}
    for stage in stages():
        upstream = {table: planned[table] for table in stage.inputs}
        planned[stage.name] = stage.planned(config.params[stage.name], config.pipeline.seed, upstream)
    return planned


class MissingInputError(RuntimeError):
    """A stage was asked to run before the stages it reads from."""


def _manifest_stage_entry(stage: Stage, config: PipelineConfig, report: StageReport, planned: int) -> dict[str, Any]:
    return {
        "version": stage.version,
        "table": stage.table,
        "params": config.params[stage.name].key_dict(),
        "complete": report.ok and len(report.records) == planned,
        "rows": sum(record.rows for record in report.records),
        "shards": [record.as_dict() for record in report.records],
    }


def run_stages(
    config: PipelineConfig,
    store: ShardStore,
    executor: Executor,
    names: Sequence[str],
    *,
    force: bool = False,
    on_item: Callable[[str, str, str], None] | None = None,
    on_stage: Callable[[str, int], None] | None = None,
) -> list[StageReport]:
    """Run the named stages in data-flow order and update the manifest.

    Parameters
    ----------
    names : sequence of str
        Stage names; the stages they read from must be done already (or be
        among ``names``).
    on_item : callable(stage, item_id, status), optional
    on_stage : callable(stage, item_count), optional
        Called when a stage starts.

    Raises
    ------
    MissingInputError
        If an input shard is missing; names the command that makes it.
    """
    planned = plan_pipeline(config)
    manifest = store.read_manifest(config.pipeline.name) or {}
    recorded = manifest.get("stages", {}) if manifest.get("schema_version") == SCHEMA_VERSION else {}
    reports = []
    selected = [stage for stage in stages() if stage.name in names]
    for stage in selected:
        for table in stage.inputs:
            if table in names:
                continue
            missing = [shard for shard in planned[table] if not store.is_done(table, shard.key)]
            if missing:
                command = next(command for command, tables in COMMAND_STAGES.items() if table in tables)
                raise MissingInputError(
                    f"stage {stage.name!r} reads table {table!r}, but {len(missing)} of its "
                    f"{len(planned[table])} shards are not built; run `osgd {command} --config "
                    f"{config.path}` first"
                )
        checksums = {entry["key"]: entry["sha256"] for entry in recorded.get(stage.name, {}).get("shards", [])}
        if on_stage:
            on_stage(stage.name, len(planned[stage.name]))
        report = run_stage(
            stage,
            planned[stage.name],
            store,
            executor,
            force=force,
            manifest_shards=checksums,
            on_item=(lambda item, status, _name=stage.name: on_item(_name, item, status)) if on_item else None,
        )
        reports.append(report)
        recorded[stage.name] = _manifest_stage_entry(stage, config, report, len(planned[stage.name]))
        store.write_manifest(
            config.pipeline.name,
            {
                "pipeline": config.pipeline.name,
                "seed": config.pipeline.seed,
                "schema_version": SCHEMA_VERSION,
                "stages": recorded,
            },
        )
        if not report.ok:
            break
    return reports


@dataclass(frozen=True)
class StageStatus:
    """Shards of one stage: done, missing, corrupt (present but failing
    verification) and stale (on disk but not in the current plan)."""

    stage: str
    done: int
    missing: int
    corrupt: int
    stale: int


def pipeline_status(config: PipelineConfig, store: ShardStore) -> list[StageStatus]:
    """Per stage, how many planned shards are done, missing, corrupt or stale."""
    planned = plan_pipeline(config)
    result = []
    for stage in stages():
        done = missing = corrupt = 0
        keys = set()
        for shard in planned[stage.name]:
            keys.add(shard.key)
            if store.is_done(stage.table, shard.key):
                done += 1
            elif store.shard_path(stage.table, shard.key).exists():
                corrupt += 1
            else:
                missing += 1
        stale = len(set(store.keys_on_disk(stage.table)) - keys)
        result.append(StageStatus(stage.name, done, missing, corrupt, stale))
    return result
