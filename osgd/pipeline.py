"""The pipeline: the stages in data-flow order, planning and manifests.

::

    models -> grasps -> checks -> scenes -> samples
    (annotate)          (check)   (stack)   (render)
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from osgd.config import PipelineConfig, load_config
from osgd.contract.schemas import SCHEMA_VERSION
from osgd.contract.taxonomy import TABLE1
from osgd.errors import describe
from osgd.executor import Executor
from osgd.stage import PlannedShard, Stage, StageReport, run_stage
from osgd.store import ShardStore

log = logging.getLogger(__name__)


@functools.cache
def stages() -> tuple[Stage, ...]:
    """Every stage, in data-flow order (imported on first use: ``osgd --help`` loads no stage)."""
    from osgd.checks.stage import ChecksStage  # noqa: PLC0415
    from osgd.grasps.stage import GraspsStage  # noqa: PLC0415
    from osgd.models.stage import ModelsStage  # noqa: PLC0415
    from osgd.samples.stage import SamplesStage  # noqa: PLC0415
    from osgd.scenes.stage import ScenesStage  # noqa: PLC0415

    return (ModelsStage(), GraspsStage(), ChecksStage(), ScenesStage(), SamplesStage())


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


class PlanError(RuntimeError):
    """A stage cannot plan its work (a models folder that is not there...); one line.

    Raised by :func:`run_stages`, it carries the reports of the stages run before (``reports``).
    """

    reports: list[StageReport]


def _plan_stage(
    stage: Stage, config: PipelineConfig, planned: Mapping[str, Sequence[PlannedShard]], leave_out: Collection[str]
) -> list[PlannedShard]:
    """The planned shards of one stage, given those of the stages before it, less ``leave_out`` item ids."""
    upstream = {table: planned[table] for table in stage.inputs}
    try:
        shards = stage.planned(config.params[stage.name], config.pipeline.seed, upstream, config.taxonomy)
    except (OSError, ValueError, KeyError) as error:
        file, cause = describe(error)
        raise PlanError(f"stage {stage.name} cannot plan its work: {file + ': ' if file else ''}{cause}") from error
    return [shard for shard in shards if shard.item.item_id not in leave_out]


def plan_pipeline(
    config: PipelineConfig, failed: Mapping[str, Collection[str]] | None = None
) -> dict[str, list[PlannedShard]]:
    """The planned shards of every stage; reads no shard content.

    Parameters
    ----------
    config : PipelineConfig
    failed : mapping of stage name to item ids, optional
        Items that failed: left out of their stage's plan, so that the later
        stages plan without them (a scene draws from the models that exist).

    Raises
    ------
    PlanError
    """
    failed = failed or {}
    planned: dict[str, list[PlannedShard]] = {}
    for stage in stages():
        planned[stage.name] = _plan_stage(stage, config, planned, failed.get(stage.name, ()))
    return planned


class MissingInputError(RuntimeError):
    """A stage was asked to run before the stages it reads from; carries ``reports`` as :class:`PlanError` does."""

    reports: list[StageReport]


def _manifest_stage_entry(
    stage: Stage, config: PipelineConfig, report: StageReport, planned: int,
    extra: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    entry = {
        **(extra or {}),
        "version": stage.version,
        "table": stage.table,
        "params": config.params[stage.name].key_dict(),
        "complete": report.ok and len(report.records) == planned,
        "rows": sum(record.rows for record in report.records),
        "shards": [record.as_dict() for record in report.records],
    }
    if report.failures:
        # Item ids only (no messages: they hold paths): later commands plan without them.
        entry["failed"] = sorted(failure.item_id for failure in report.failures)
    return entry


def recorded_stages(store: ShardStore, pipeline: str) -> dict[str, Any]:
    """The ``stages`` of the pipeline's manifest on disk; empty when none (or of another schema)."""
    manifest = store.read_manifest(pipeline) or {}
    return dict(manifest.get("stages", {})) if manifest.get("schema_version") == SCHEMA_VERSION else {}


def recorded_failures(recorded: Mapping[str, Any]) -> dict[str, set[str]]:
    """Stage name to the item ids its last run could not build, from :func:`recorded_stages`."""
    return {name: set(entry.get("failed", ())) for name, entry in recorded.items() if isinstance(entry, dict)}


def _check_inputs(
    stage: Stage, planned: Mapping[str, Sequence[PlannedShard]], names: Sequence[str], store: ShardStore,
    config: PipelineConfig,
) -> None:
    """Raise :class:`MissingInputError` when a table this stage reads, made by another command, is not built."""
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

    An item that fails does not stop its stage nor the later ones: they are
    planned without it (and without what it would have fed), the manifest
    records its item id under ``failed``, and a later command that reads
    the stage plans without it too. Temporary and lock files that killed
    processes left in the data dir are removed first.

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
    PlanError
        If a stage cannot plan its work.
    """
    temporaries, locks = store.clean_leftovers()
    if temporaries or locks:
        log.info("removed %d temporary and %d lock file(s) left by killed processes", temporaries, locks)
    recorded = recorded_stages(store, config.pipeline.name)
    failed_before = recorded_failures(recorded)
    ordered = list(stages())
    last = max((index for index, stage in enumerate(ordered) if stage.name in names), default=-1)
    planned: dict[str, list[PlannedShard]] = {}
    reports: list[StageReport] = []
    try:
        _run_in_order(config, store, executor, names, ordered[: last + 1], planned, reports, recorded,
                      failed_before, force=force, on_item=on_item, on_stage=on_stage)
    except (MissingInputError, PlanError) as error:
        error.reports = reports  # what was built before the stage that could not plan (the CLI reports it)
        raise
    return reports


def _run_in_order(
    config: PipelineConfig, store: ShardStore, executor: Executor, names: Sequence[str], ordered: Sequence[Stage],
    planned: dict[str, list[PlannedShard]], reports: list[StageReport], recorded: dict[str, Any],
    failed_before: Mapping[str, Collection[str]], *, force: bool,
    on_item: Callable[[str, str, str], None] | None, on_stage: Callable[[str, int], None] | None,
) -> None:
    """The loop of :func:`run_stages`: plan each stage, run the named ones, write the manifest after each."""
    for stage in ordered:
        if stage.name not in names:
            planned[stage.name] = _plan_stage(stage, config, planned, failed_before.get(stage.name, ()))
            continue
        shards = _plan_stage(stage, config, planned, ())
        _check_inputs(stage, planned, names, store, config)
        checksums = {entry["key"]: entry["sha256"] for entry in recorded.get(stage.name, {}).get("shards", [])}
        if on_stage:
            on_stage(stage.name, len(shards))
        report = run_stage(
            stage,
            shards,
            store,
            executor,
            force=force,
            manifest_shards=checksums,
            on_item=(lambda item, status, _name=stage.name: on_item(_name, item, status)) if on_item else None,
        )
        reports.append(report)
        failed_ids = {failure.item_id for failure in report.failures}
        planned[stage.name] = [shard for shard in shards if shard.item.item_id not in failed_ids]
        extra = stage.manifest_extra(planned[stage.name], store) if planned[stage.name] else {}
        recorded[stage.name] = _manifest_stage_entry(stage, config, report, len(shards), extra)
        store.write_manifest(config.pipeline.name, _manifest(config, recorded))


def _manifest(config: PipelineConfig, recorded: Mapping[str, Any]) -> dict[str, Any]:
    """The manifest document; it names a taxonomy other than Table I (its name and :attr:`Taxonomy.digest`)."""
    manifest: dict[str, Any] = {"pipeline": config.pipeline.name, "seed": config.pipeline.seed}
    if config.taxonomy != TABLE1:
        manifest["taxonomy"] = {"name": config.taxonomy.name, "sha256": config.taxonomy.digest}
    return {**manifest, "schema_version": SCHEMA_VERSION, "stages": recorded}


@dataclass(frozen=True)
class StageStatus:
    """Shards of one stage: done, missing, failed (items the last run could
    not build), corrupt (present but failing verification) and stale (on disk
    but not in the current plan)."""

    stage: str
    done: int
    missing: int
    corrupt: int
    stale: int
    failed: int = 0


#: ``osgd status``'s exit code is the sum of these, one per kind of problem found in any stage; 0: all done.
STATUS_EXIT_CODES: dict[str, int] = {"missing": 4, "failed": 8, "corrupt": 16, "stale": 32}


def status_exit_code(rows: Sequence[StageStatus]) -> int:
    """``osgd status``'s exit code for its rows: 0 when every shard is done, else :data:`STATUS_EXIT_CODES` summed."""
    return sum(code for kind, code in STATUS_EXIT_CODES.items() if any(getattr(row, kind) for row in rows))


def pipeline_status(config: PipelineConfig, store: ShardStore) -> list[StageStatus]:
    """Per stage, how many planned shards are done, missing, failed, corrupt or stale.

    The plan leaves out the items the manifest records as failed, as
    :func:`run_stages` does; a shard counts as done when it passes
    :meth:`ShardStore.verify` against the manifest's checksum too.
    """
    recorded = recorded_stages(store, config.pipeline.name)
    failed = recorded_failures(recorded)
    planned = plan_pipeline(config, failed)
    result = []
    for stage in stages():
        checksums = {entry["key"]: entry["sha256"] for entry in recorded.get(stage.name, {}).get("shards", [])}
        done = missing = corrupt = 0
        keys = set()
        for shard in planned[stage.name]:
            keys.add(shard.key)
            if store.is_done(stage.table, shard.key, checksums.get(shard.key)):
                done += 1
            elif store.shard_path(stage.table, shard.key).exists():
                corrupt += 1
            else:
                missing += 1
        stale = len(set(store.keys_on_disk(stage.table)) - keys)
        result.append(StageStatus(stage.name, done, missing, corrupt, stale, len(failed.get(stage.name, ()))))
    return result
