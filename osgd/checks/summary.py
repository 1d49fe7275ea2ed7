"""Acceptance rates of the grasp trials per category and per task.

The ``checks`` table holds only ``model_id`` and ``grasp_id``; the task
comes from the ``grasps`` shard the checks shard was built from and the
category from the ``models`` shards. The stage knows the grasps shard of
each item from its plan; without a plan (another process, a fresh stage)
the grasps shards on disk with the same item id are read instead.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from osgd.checks.trial import FAIL_REASONS
from osgd.contract.shards import ShardRecord
from osgd.contract.taxonomy import CATEGORIES, TASKS
from osgd.store import ShardStore


@dataclass
class AcceptanceCounts:
    """Trials and held trials per category, per task and per failure reason.

    Attributes
    ----------
    trials, stable, lift, shake : Counter of (category, task) -> int
        All trials, and those held under the stage's criterion, under
        ``lift`` and under ``shake``.
    unshaken : Counter of (category, task) -> int
        Trials held on the lift whose shakes did not run (``shake_stable``
        null).
    fail_reasons : Counter of str -> int
    user_trials, user_approach_collisions : int
        Trials on users' meshes (``source`` "user"), and those that failed on the approach.
    """

    trials: Counter[tuple[str, str]] = field(default_factory=Counter)
    stable: Counter[tuple[str, str]] = field(default_factory=Counter)
    lift: Counter[tuple[str, str]] = field(default_factory=Counter)
    shake: Counter[tuple[str, str]] = field(default_factory=Counter)
    unshaken: Counter[tuple[str, str]] = field(default_factory=Counter)
    fail_reasons: Counter[str] = field(default_factory=Counter)
    user_trials: int = 0
    user_approach_collisions: int = 0

    def rate(self, category: str | None = None, task: str | None = None,
             criterion: str = "stable") -> tuple[int, int]:
        """(held, trials) summed over the keys matching ``category`` and ``task`` (None: any).

        ``criterion`` is ``"stable"`` (the stage's), ``"lift"`` or ``"shake"``;
        the ``"shake"`` rate is unknown, (held, 0), where a matching trial
        held on the lift skipped its shakes.
        """
        def matches(key: tuple[str, str]) -> bool:
            return (category is None or key[0] == category) and (task is None or key[1] == task)

        held: Counter[tuple[str, str]] = getattr(self, criterion)
        trials = sum(value for key, value in self.trials.items() if matches(key))
        if criterion == "shake" and any(value for key, value in self.unshaken.items() if matches(key)):
            trials = 0
        return sum(value for key, value in held.items() if matches(key)), trials


def _grasps_keys_by_item(store: ShardStore) -> dict[str, list[str]]:
    """Item id -> keys of the grasps shards on disk with that item id."""
    keys: dict[str, list[str]] = {}
    for key in store.keys_on_disk("grasps"):
        try:
            item_id = json.loads(store.checksum_path("grasps", key).read_text())["item"]
        except (FileNotFoundError, ValueError, KeyError):
            continue
        keys.setdefault(item_id, []).append(key)
    return keys


def acceptance_counts(
    store: ShardStore,
    records: Sequence[ShardRecord],
    grasps_keys: Mapping[str, Sequence[str]] | None = None,
) -> AcceptanceCounts:
    """Count the trials of the given ``checks`` shards.

    Parameters
    ----------
    store : ShardStore
    records : sequence of ShardRecord
        ``checks`` shards.
    grasps_keys : mapping of item id to grasps keys, optional
        The grasps shards each checks item read; found on disk by item id
        where missing.

    Returns
    -------
    AcceptanceCounts
        A grasp whose task or model is not found counts under ``"?"``.
    """
    grasps_keys = dict(grasps_keys or {})
    if any(record.item_id not in grasps_keys for record in records):
        on_disk = _grasps_keys_by_item(store)
        for record in records:
            grasps_keys.setdefault(record.item_id, on_disk.get(record.item_id, []))
    categories: dict[str, str] = {}
    users: set[str] = set()
    for key in store.keys_on_disk("models"):
        models = store.read("models", key, columns=["model_id", "category", "source"])
        model_ids = models.column("model_id").to_pylist()
        categories.update(zip(model_ids, models.column("category").to_pylist(), strict=True))
        users.update(model_id for model_id, source in zip(model_ids, models.column("source").to_pylist(),
                                                          strict=True) if source == "user")
    counts = AcceptanceCounts()
    for record in records:
        tasks: dict[tuple[str, int], str] = {}
        for key in grasps_keys.get(record.item_id, ()):
            grasps = store.read("grasps", key, columns=["model_id", "grasp_id", "task"])
            tasks.update(zip(zip(grasps.column("model_id").to_pylist(), grasps.column("grasp_id").to_pylist(),
                                 strict=True), grasps.column("task").to_pylist(), strict=True))
        columns = ("model_id", "grasp_id", "stable", "lift_stable", "shake_stable", "fail_reason")
        checks = store.read("checks", record.key, columns=list(columns))
        for model_id, grasp_id, stable, lift, shake, reason in zip(
            *(checks.column(name).to_pylist() for name in columns), strict=True,
        ):
            key = (categories.get(model_id, "?"), tasks.get((model_id, grasp_id), "?"))
            counts.trials[key] += 1
            counts.stable[key] += int(stable)
            counts.lift[key] += int(lift)
            counts.shake[key] += int(bool(shake))
            counts.unshaken[key] += int(shake is None)
            if reason:
                counts.fail_reasons[reason] += 1
            if model_id in users:
                counts.user_trials += 1
                counts.user_approach_collisions += int(reason == "approach_collision")
    return counts


def _percent(held: int, trials: int, width: int) -> str:
    """``held / trials`` as a percentage right-aligned in ``width`` characters; "-" without trials."""
    return f"{100 * held / trials:>{width - 1}.1f}%" if trials else f"{'-':>{width}}"


def _table(title: str, names: Sequence[str], counts: AcceptanceCounts, by: str) -> list[str]:
    lines = [title, f"  {'':<14}{'trials':>8}{'stable':>8}{'lift':>8}{'shake':>8}"]
    for name in names:
        stable, trials = counts.rate(**{by: name})
        if trials:
            lift, shake = (counts.rate(**{by: name}, criterion=criterion) for criterion in ("lift", "shake"))
            lines.append(f"  {name:<14}{trials:>8}{stable:>8}{_percent(*lift, 8)}{_percent(*shake, 8)}")
    return lines


def format_acceptance(counts: AcceptanceCounts, approach_geometry: str = "auto") -> str:
    """Acceptance per category, per task and the failure reasons, as text.

    Users' meshes whose approach was swept against their convex parts
    (``approach_geometry`` set to ``hulls``) get a note: on scans that fails
    the approach far more often than against the mesh (docs/models.md, "The
    checks on scans").
    """
    stable, trials = counts.rate()
    if not trials:
        return "checks: no grasps tried"
    categories = [*CATEGORIES, *sorted({key[0] for key in counts.trials} - set(CATEGORIES))]
    tasks = [*TASKS, *sorted({key[1] for key in counts.trials} - set(TASKS))]
    lift = counts.rate(criterion="lift")[0]
    shake, shaken = counts.rate(criterion="shake")
    shake_text = (f"shake {100 * shake / shaken:.1f}%" if shaken
                  else "shake not run (checks.store_shake)")
    lines = [f"checks: {stable} of {trials} grasps stable ({100 * stable / trials:.1f}%); "
             f"lift {100 * lift / trials:.1f}%, {shake_text}"]
    lines += _table("per category", categories, counts, "category")
    lines += _table("per task", tasks, counts, "task")
    if counts.fail_reasons:
        lines.append("failures: " + ", ".join(
            f"{reason} {counts.fail_reasons[reason]}" for reason in FAIL_REASONS if counts.fail_reasons[reason]))
    if counts.user_trials and approach_geometry == "hulls":
        lines.append(f"note: the approach of the {counts.user_trials} trials on users' meshes was swept against "
                     f"their convex parts ({counts.user_approach_collisions} failed it); for scans set "
                     'checks.approach_geometry = "mesh" (docs/models.md, "The checks on scans")')
    return "\n".join(lines)
