"""The trials of the robot experiment and the seeds of their piles.

The paper's protocol (Section V-C): 10 trials for each of the 10 tool tasks,
30 for "no task" and 30 for "hand over", each of those with a randomly named
object category. Every trial is identified by its task and its repeat
number; its pile, its named category and the random policy's draws derive
from ``(pipeline seed, task, repeat)`` only, so a trial is the same whatever
else runs, and every policy and checkpoint meets the same piles.

Fresh piles: the stack stage numbers a pipeline's scenes ``0 .. count - 1``
and seeds scene ``i`` from ``(pipeline seed, i, attempt)``
(:func:`osgd.scenes.drop.attempt_seed`). The robot's piles use scene indices
from :data:`ROBOT_SCENE_OFFSET` (10^9) on, which no pipeline reaches
(:func:`check_fresh` refuses a config whose ``scenes.count`` does), so
their seeds come from other SeedSequence entropy than any training scene's;
:func:`check_fresh` also compares them with the ``seed`` column of every
scenes shard in the data dir.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from osgd.contract.taxonomy import TABLE1, TASKS, Taxonomy

#: Tasks for which the paper names an object category first (Section V-C).
NAMED_TASKS: tuple[str, ...] = ("no task", "hand over")

#: The 10 tool tasks, in Table I's order.
TOOL_TASKS: tuple[str, ...] = tuple(task for task in TASKS if task not in NAMED_TASKS)

#: The rows of Table III, in the paper's order (a pipeline's own taxonomy adds its tasks after them).
TABLE_TASKS: tuple[str, ...] = TASKS

#: First scene index of the robot's piles; a pipeline's own scenes are 0 .. count - 1.
ROBOT_SCENE_OFFSET = 10**9

#: Scene indices per task and per trial: pile k of repeat r of task t is scene
#: ROBOT_SCENE_OFFSET + t * REPEATS_PER_TASK * PILES_PER_TRIAL + r * PILES_PER_TRIAL + k.
REPEATS_PER_TASK = 10**4
PILES_PER_TRIAL = 100

#: Mixed into the seeds of the named category and the random policy.
_SALT = 0x12_0B07


@dataclass(frozen=True)
class Trial:
    """One trial of the protocol.

    Attributes
    ----------
    task : str
        One of the pipeline's taxonomy's tasks.
    task_index : int
        Its index there (Table I's first: a pipeline's own taxonomy extends Table I), which seeds its piles.
    repeat : int
        0, 1, ... within the task.
    category : str or None
        The named object category ("no task" and "hand over"), else None.
    scene_index : int
        The scene index of the trial's first pile (see the module text);
        pile ``k`` (:func:`togcrf.robot.pile.feasible_pile`) is ``scene_index + k``.
    """

    task: str
    task_index: int
    repeat: int
    category: str | None
    scene_index: int

    @property
    def name(self) -> str:
        """``cut_03`` or ``hand_over_12``: unique within a protocol, usable in file names."""
        return f"{self.task.replace(' ', '_')}_{self.repeat:02d}"


def scene_index(task_index: int, repeat: int) -> int:
    """The scene index of a trial's first pile (>= :data:`ROBOT_SCENE_OFFSET`), from its task's index."""
    if not 0 <= repeat < REPEATS_PER_TASK:
        raise ValueError(f"repeat {repeat} is outside 0..{REPEATS_PER_TASK - 1}")
    return ROBOT_SCENE_OFFSET + (task_index * REPEATS_PER_TASK + repeat) * PILES_PER_TRIAL


def trial_rng(seed: int, task_index: int, repeat: int, purpose: int) -> np.random.Generator:
    """A generator for one trial (its task's index, its repeat) and one purpose (0: named category, 1: random
    policy)."""
    return np.random.default_rng(np.random.SeedSequence([seed % 2**64, _SALT, task_index, repeat, purpose]))


def _no_stable_grasp(task: str) -> str:
    return f"no category of the models has a stable {task!r} grasp"


def named_category(seed: int, task: str, task_index: int, repeat: int, eligible: Mapping[str, Sequence[str]]) -> str:
    """The category named for a "no task" or "hand over" trial, uniform over the eligible ones.

    Raises
    ------
    ValueError
        If no category is eligible for the task.
    """
    choices = sorted(eligible.get(task, ()))
    if not choices:
        raise ValueError(f"{_no_stable_grasp(task)}: the task cannot be tried")
    return choices[int(trial_rng(seed, task_index, repeat, 0).integers(len(choices)))]


def untried_tasks(tasks: Iterable[str], eligible: Mapping[str, Sequence[str]],
                  afforded: Iterable[str]) -> dict[str, str]:
    """The tasks that cannot be tried on a set of models, each with the reason.

    A named task ("no task", "hand over") needs a category with a stable
    grasp of it to name (``eligible``, as :func:`protocol_trials` takes it);
    a tool task needs a model whose grasps carry it (``afforded``: every task
    of the models' grasps). A model set annotated without "no task" grasps
    (the paper authors' models) cannot be tried on "no task".
    """
    afforded = set(afforded)
    untried = {}
    for task in tasks:
        if task in NAMED_TASKS and not eligible.get(task):
            untried[task] = _no_stable_grasp(task)
        elif task not in NAMED_TASKS and task not in afforded:
            untried[task] = f"no grasp of the models is labelled {task!r}"
    return untried


def protocol_trials(seed: int, eligible: Mapping[str, Sequence[str]], tool_trials: int = 10,
                    named_trials: int = 30, tasks: Iterable[str] | None = None,
                    taxonomy: Taxonomy = TABLE1) -> list[Trial]:
    """The trials of the protocol, task by task in Table III's order.

    Parameters
    ----------
    seed : int
        The pipeline seed.
    eligible : mapping of task to categories
        The categories that may be named for "no task" and "hand over"
        (:meth:`togcrf.robot.world.World.eligible_categories`).
    tool_trials, named_trials : int
        Trials per tool task (paper: 10) and per named task (paper: 30).
    tasks : iterable of str, optional
        Only these tasks; default: every task of ``taxonomy``.
    taxonomy : Taxonomy
        The pipeline's: its tasks, and their indices that seed the piles.

    Returns
    -------
    list of Trial
    """
    trials = []
    for task in taxonomy.tasks if tasks is None else tasks:
        if task not in taxonomy.tasks:
            raise ValueError(f"unknown task {task!r}; tasks are {list(taxonomy.tasks)}")
        index = taxonomy.tasks.index(task)
        count = named_trials if task in NAMED_TASKS else tool_trials
        for repeat in range(count):
            category = named_category(seed, task, index, repeat, eligible) if task in NAMED_TASKS else None
            trials.append(Trial(task, index, repeat, category, scene_index(index, repeat)))
    return trials


def check_fresh(scene_count: int, pile_seeds: Iterable[int], training_seeds: Iterable[int]) -> None:
    """Refuse piles that could be training scenes.

    Parameters
    ----------
    scene_count : int
        The pipeline's ``scenes.count``.
    pile_seeds : iterable of int
        The seeds of the robot's piles (the accepted attempts').
    training_seeds : iterable of int
        The ``seed`` column of every scenes shard of the data dir.

    Raises
    ------
    ValueError
        If the pipeline's scenes reach the robot's indices, or a pile's seed
        is a stored scene's.
    """
    if scene_count > ROBOT_SCENE_OFFSET:
        raise ValueError(f"scenes.count = {scene_count} reaches the robot's scene indices "
                         f"(from {ROBOT_SCENE_OFFSET}): its piles could be training scenes")
    shared = set(pile_seeds) & set(training_seeds)
    if shared:
        raise ValueError(f"{len(shared)} robot pile seed(s) are seeds of stored scenes, e.g. {min(shared)}")


#: Table III of the paper, per task: (GSR-S, GSR-T) in percent, for TOG and TOG-CRFs.
PAPER_TABLE3: dict[str, dict[str, tuple[float, float]]] = {
    "TOG": {
        "no task": (70.0, 63.3), "cut": (50.0, 50.0), "screw": (80.0, 60.0), "ladle": (40.0, 30.0),
        "fork": (40.0, 20.0), "wrench": (80.0, 60.0), "hammer": (100.0, 80.0), "write": (80.0, 50.0),
        "brush": (60.0, 40.0), "shovel": (100.0, 100.0), "pinch": (90.0, 60.0), "hand over": (83.3, 63.3),
    },
    "TOG-CRFs": {
        "no task": (70.0, 63.3), "cut": (50.0, 50.0), "screw": (90.0, 90.0), "ladle": (50.0, 30.0),
        "fork": (30.0, 20.0), "wrench": (90.0, 90.0), "hammer": (100.0, 100.0), "write": (80.0, 50.0),
        "brush": (80.0, 70.0), "shovel": (100.0, 100.0), "pinch": (100.0, 100.0), "hand over": (83.3, 70.0),
    },
}

#: The paper's "Total" row: (GSR-S, GSR-T), the mean of the 12 task rates.
PAPER_TOTAL: dict[str, tuple[float, float]] = {"TOG": (72.8, 56.4), "TOG-CRFs": (76.9, 69.4)}
