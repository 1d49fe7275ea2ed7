"""The stage framework: plan work items, build missing shards, record them.

A stage turns the shards of its input tables into shards of its output table.
It defines:

- ``name``, ``table`` (the output table), ``version`` (bump it whenever the
  output for the same inputs changes) and ``inputs`` (the tables it reads);
- ``Params``: a pydantic model, the stage's section of the pipeline config;
- :meth:`Stage.plan`: the work items, from the parameters and the planned
  shards of the input tables. Planning reads no shard content, so the keys of
  a whole pipeline are known before anything is built;
- :meth:`Stage.build`: the rows of one item, computed from the item's payload
  and the input shards it names. It reads nothing else, so everything it
  depends on is in the shard key.

:func:`run_stage` builds the items whose shards are missing or corrupt, on any
executor, and returns a :class:`StageReport`.
"""

from __future__ import annotations

import abc
import dataclasses
import importlib
import logging
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypeVar

import pyarrow as pa
from pydantic import BaseModel, ConfigDict

from osgd.contract.shards import ShardError, ShardRecord
from osgd.contract.taxonomy import TABLE1, Taxonomy, taxonomy_of_document
from osgd.executor import Executor, SerialExecutor, TaskFailure
from osgd.store import ShardStore, shard_key

log = logging.getLogger(__name__)


_Read = TypeVar("_Read")

#: The payload key of an item's taxonomy (:meth:`Stage.planned`).
TAXONOMY_KEY = "taxonomy"


def item_taxonomy(item: WorkItem) -> Taxonomy:
    """The taxonomy an item labels with: the one in its payload, else Table I."""
    return taxonomy_of_document(item.payload.get(TAXONOMY_KEY))

#: :func:`read_once_per_worker`'s last value per name, with the data dir and shard keys it was read from.
_WORKER_READS: dict[str, tuple[tuple[str, ...], Any]] = {}


def read_once_per_worker(name: str, store: ShardStore, keys: Sequence[str], read: Callable[[], _Read]) -> _Read:
    """``read()``, called once per worker process while the data dir and the shard keys stay the same.

    Every item of a stage names the same upstream shards (every models
    shard, say), and a shard key stands for its content, so a worker reads
    and converts them for its first item and reuses them for the rest.
    One value is kept per ``name``: other keys
    replace it.

    Parameters
    ----------
    name : str
        What is read (one cache entry per name).
    store : ShardStore
    keys : sequence of str
        The shard keys ``read`` depends on.
    read : callable() -> value
    """
    cache_key = (str(store.root), *keys)
    cached = _WORKER_READS.get(name)
    if cached is None or cached[0] != cache_key:
        _WORKER_READS.pop(name, None)  # the old value goes before the new one is read
        _WORKER_READS[name] = (cache_key, read())
    return _WORKER_READS[name][1]


class StageParams(BaseModel):
    """Base of every stage's parameters: unknown keys are an error.

    A field whose ``json_schema_extra`` holds ``{"location": True}`` names
    where something is (a folder path), not what it is: it is left out of
    shard keys and manifests, so moving a folder recomputes nothing and
    manifests hold no absolute paths. The stage must then put the content
    hash of whatever it reads from there into the item payload.

    A field whose ``json_schema_extra`` holds ``{"omit_default": True}`` is
    left out of shard keys and manifests while it has its default value: an
    option added later, whose default does what the stage did before it,
    leaves the keys of the shards built before it unchanged.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    def taxonomy_mistakes(self, taxonomy: Taxonomy) -> list[str]:
        """What in these parameters the pipeline's taxonomy does not know (a category, a part), a line each."""
        return []

    def key_dict(self) -> dict[str, Any]:
        """The parameters as JSON-able values, location fields and omitted defaults left out."""
        dumped = self.model_dump(mode="json")
        for name, info in type(self).model_fields.items():
            extra = info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}
            if extra.get("location") or (extra.get("omit_default") and getattr(self, name) == info.default):
                dumped.pop(name, None)
        return dumped


@dataclass(frozen=True)
class WorkItem:
    """One unit of work: it builds exactly one shard.

    Attributes
    ----------
    item_id : str
        Identity within the stage, e.g. ``"hammer_001"`` or ``"scenes_0003"``.
    payload : dict
        JSON-able; everything :meth:`Stage.build` reads besides input shards.
    inputs : dict of str to tuple of str
        Input table name to the keys of the shards the item reads.
    """

    item_id: str
    payload: dict[str, Any]
    inputs: dict[str, tuple[str, ...]] = field(default_factory=dict)


@dataclass(frozen=True)
class PlannedShard:
    """A work item with its key: what a downstream stage plans against."""

    item: WorkItem
    key: str


@dataclass(frozen=True)
class BuildResult:
    """What :meth:`Stage.build` may return instead of a bare table.

    Attributes
    ----------
    table : pyarrow.Table
        The rows, in the schema of the stage's table.
    notes : list of str
        Warnings worth showing a person (a repaired mesh, a dropped pair).
        They are kept beside the shard and shown again when it is reused.
    warnings : list of str
        What happened during this build only (a bad cache file rebuilt):
        shown once, not kept.
    """

    table: pa.Table
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


class Stage(abc.ABC):
    """Base class of the pipeline's stages."""

    name: ClassVar[str]
    table: ClassVar[str]
    version: ClassVar[int]
    inputs: ClassVar[tuple[str, ...]] = ()
    Params: ClassVar[type[StageParams]]
    description: ClassVar[str] = ""
    #: Whether the stage's rows depend on the taxonomy (categories, parts, tasks and their rules); its items
    #: then carry a taxonomy other than Table I in their payload (:func:`item_taxonomy`), and so in their keys.
    uses_taxonomy: ClassVar[bool] = False

    @abc.abstractmethod
    def plan(
        self, params: StageParams, seed: int, upstream: Mapping[str, Sequence[PlannedShard]]
    ) -> list[WorkItem]:
        """The stage's work items.

        Parameters
        ----------
        params : StageParams
            This stage's validated parameters.
        seed : int
            The pipeline seed; items derive their own seeds from it.
        upstream : mapping
            For each table in ``inputs``, the planned shards of that table.
        """

    @abc.abstractmethod
    def build(self, item: WorkItem, store: ShardStore) -> pa.Table | BuildResult:
        """Compute the rows of one item. Runs in a worker process."""

    def manifest_extra(self, shards: Sequence[PlannedShard], store: ShardStore) -> dict[str, Any]:
        """Keys this stage adds to its manifest entry beside version, params and shards; none by default.

        Parameters
        ----------
        shards : sequence of PlannedShard
            The stage's built shards (failed items left out).
        store : ShardStore
            Their data dir; what is read from it must follow from the shards' inputs.
        """
        return {}

    def planned(
        self, params: StageParams, seed: int, upstream: Mapping[str, Sequence[PlannedShard]],
        taxonomy: Taxonomy = TABLE1,
    ) -> list[PlannedShard]:
        """:meth:`plan` with the key of each item; a taxonomy other than Table I goes into the payload of each
        item of a stage that :attr:`uses_taxonomy` (Table I's keys stay as they were before taxonomies)."""
        items = self.plan(params, seed, upstream)
        if self.uses_taxonomy and taxonomy != TABLE1:
            document = taxonomy.document()
            items = [dataclasses.replace(item, payload={**item.payload, TAXONOMY_KEY: document}) for item in items]
        seen: set[str] = set()
        shards = []
        for item in items:
            if item.item_id in seen:
                raise ValueError(f"stage {self.name!r} planned item {item.item_id!r} twice")
            seen.add(item.item_id)
            input_keys = [key for keys in item.inputs.values() for key in keys]
            key = shard_key(self.name, self.version, item.item_id, item.payload, input_keys)
            shards.append(PlannedShard(item, key))
        return shards


@dataclass
class ItemFailure:
    """A work item whose build raised.

    Attributes
    ----------
    item_id, key : str
    error : str
        One line: the file (when known) and the cause.
    traceback : str
    file : str
        The file at fault; empty when the error names none.
    cause : str
        What went wrong, without the file.
    """

    item_id: str
    key: str
    error: str
    traceback: str
    file: str = ""
    cause: str = ""


@dataclass
class StageReport:
    """The outcome of :func:`run_stage`.

    Attributes
    ----------
    records : list of ShardRecord
        Every finished shard of the plan, in plan order.
    reused, built : int
        How many shards were already done, and how many were built now.
    rebuilt : list of str
        Problems found with shards on disk that were then rebuilt.
    failures : list of ItemFailure
    notes : dict of str to list of str
        Notes per item id, from builds now or earlier.
    warnings : dict of str to list of str
        Warnings per item id from builds now (:attr:`BuildResult.warnings`).
    seconds : float
        Wall time of the stage's run (checking what is done, building the rest), s.
    """

    stage: str
    records: list[ShardRecord] = field(default_factory=list)
    reused: int = 0
    built: int = 0
    rebuilt: list[str] = field(default_factory=list)
    failures: list[ItemFailure] = field(default_factory=list)
    notes: dict[str, list[str]] = field(default_factory=dict)
    warnings: dict[str, list[str]] = field(default_factory=dict)
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        return not self.failures


@dataclass(frozen=True)
class _BuildTask:
    stage_ref: str  # "module:ClassName", importable in a fresh worker process
    item: WorkItem
    key: str
    data_dir: str
    force: bool
    wait: bool = True


@dataclass(frozen=True)
class _Built:
    """What a worker sends back for one shard."""

    record: ShardRecord
    notes: list[str]
    built_here: bool  # False when another process finished it while this one waited
    warnings: list[str] = field(default_factory=list)


def _build_task(task: _BuildTask) -> _Built | None:
    """Build and write one shard; runs in a worker. Module-level so it pickles.

    Returns None when ``task.wait`` is False and another process holds the
    shard's lock.
    """
    module_name, class_name = task.stage_ref.split(":")
    stage = getattr(importlib.import_module(module_name), class_name)()
    store = ShardStore(task.data_dir)
    with store.lock(stage.table, task.key, wait=task.wait) as held:
        if not held:
            return None
        if not task.force and store.is_done(stage.table, task.key):
            # Another process built it while this one waited for the lock.
            return _Built(store.verify(stage.table, task.key), read_notes(store, stage.table, task.key), False)
        result = stage.build(task.item, store)
        if isinstance(result, pa.Table):
            result = BuildResult(result)
        record = store.write(stage.table, task.key, task.item.item_id, result.table)
        if result.notes:
            write_notes(store, stage.table, task.key, result.notes)
        return _Built(record, list(result.notes), True, list(result.warnings))


def _notes_file(table: str, key: str) -> str:
    return f"{table}/{key}.notes.json"


def write_notes(store: ShardStore, table: str, key: str, notes: list[str]) -> None:
    """Keep a shard's build notes beside it, so a resumed run reports them too."""
    import json  # noqa: PLC0415

    store.write_file(_notes_file(table, key), json.dumps(notes, indent=1).encode())


def read_notes(store: ShardStore, table: str, key: str) -> list[str]:
    """The build notes kept beside a shard (empty when none)."""
    import json  # noqa: PLC0415

    try:
        return list(json.loads(store.files.read_bytes(_notes_file(table, key))))
    except (FileNotFoundError, ValueError):
        return []


def run_stage(
    stage: Stage,
    shards: Sequence[PlannedShard],
    store: ShardStore,
    executor: Executor | None = None,
    *,
    force: bool = False,
    manifest_shards: Mapping[str, str] | None = None,
    on_item: Callable[[str, str], None] | None = None,
) -> StageReport:
    """Build every planned shard that is not already done.

    Parameters
    ----------
    stage : Stage
    shards : sequence of PlannedShard
        From :meth:`Stage.planned`.
    store : ShardStore
    executor : Executor, optional
        Serial when omitted.
    force : bool
        Rebuild every shard, done or not.
    manifest_shards : mapping of key to sha256, optional
        Checksums a manifest recorded; a shard that disagrees is rebuilt.
    on_item : callable(item_id, status), optional
        Called once per item with ``"reused"``, ``"built"`` or ``"failed"``.

    Returns
    -------
    StageReport
    """
    started = time.perf_counter()
    executor = executor or SerialExecutor()
    report = StageReport(stage.name)
    if force:
        done, to_build, rejected = {}, list(shards), set()
    else:
        done, to_build, rejected = _sort_planned(stage, shards, store, manifest_shards or {}, report, on_item)

    stage_ref = f"{type(stage).__module__}:{type(stage).__qualname__}"
    tasks = [
        _BuildTask(stage_ref, shard.item, shard.key, str(store.root), force or shard.key in rejected, wait=False)
        for shard in to_build
    ]
    # Shards another process is building (another run on this data dir, on
    # this machine or another sharing the folder) are passed over at first
    # and waited for at the end, so that several runs share out the work
    # instead of queueing behind each other's locks.
    deferred: list[int] = []
    outcomes = _outcomes(executor, tasks, deferred)
    for index, outcome in outcomes:
        shard = to_build[index]
        if isinstance(outcome, TaskFailure):
            log.error("stage %s, item %s failed: %s", stage.name, shard.item.item_id, outcome.error)
            log.debug("%s", outcome.traceback)
            report.failures.append(ItemFailure(
                shard.item.item_id, shard.key, outcome.error, outcome.traceback, outcome.file, outcome.cause
            ))
            if on_item:
                on_item(shard.item.item_id, "failed")
            continue
        done[shard.key] = outcome.record
        if outcome.built_here:
            report.built += 1
        else:
            report.reused += 1
        if outcome.notes:
            report.notes[shard.item.item_id] = outcome.notes
        if outcome.warnings:
            report.warnings[shard.item.item_id] = outcome.warnings
        if on_item:
            on_item(shard.item.item_id, "built" if outcome.built_here else "reused")

    report.records = [done[shard.key] for shard in shards if shard.key in done]
    report.seconds = time.perf_counter() - started
    return report


def _sort_planned(
    stage: Stage,
    shards: Sequence[PlannedShard],
    store: ShardStore,
    manifest_shards: Mapping[str, str],
    report: StageReport,
    on_item: Callable[[str, str], None] | None,
) -> tuple[dict[str, ShardRecord], list[PlannedShard], set[str]]:
    """Sort planned shards into those done (verified on disk) and those to build; count the reused in ``report``.

    Returns
    -------
    done : dict of key to ShardRecord
    to_build : list of PlannedShard
    rejected : set of str
        Keys present on disk but judged bad: rebuilt even if a worker finds them "done".
    """
    done: dict[str, ShardRecord] = {}
    to_build: list[PlannedShard] = []
    rejected: set[str] = set()
    for shard in shards:
        try:
            done[shard.key] = store.verify(stage.table, shard.key, manifest_shards.get(shard.key))
        except ShardError as error:
            if store.shard_exists(stage.table, shard.key):
                log.warning("%s; rebuilding", error)
                report.rebuilt.append(str(error))
                rejected.add(shard.key)
            to_build.append(shard)
            continue
        report.reused += 1
        notes = read_notes(store, stage.table, shard.key)
        if notes:
            report.notes[shard.item.item_id] = notes
        if on_item:
            on_item(shard.item.item_id, "reused")
    return done, to_build, rejected


def _outcomes(executor: Executor, tasks: list[_BuildTask], deferred: list[int]) -> Iterator[tuple[int, Any]]:
    """Run ``tasks`` without waiting for locks, then wait for the ones that were busy.

    Yields (task index, outcome) for every task once; ``deferred`` collects
    the indices of busy tasks during the first pass.
    """
    for index, outcome in executor.map_unordered(_build_task, tasks):
        if outcome is None:
            deferred.append(index)
            continue
        yield index, outcome
    if deferred:
        log.info("waiting for %d shard(s) that another process is building", len(deferred))
        retries = [dataclasses.replace(tasks[index], wait=True) for index in deferred]
        for position, outcome in executor.map_unordered(_build_task, retries):
            yield deferred[position], outcome
