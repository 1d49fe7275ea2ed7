"""The robot experiment's loop: trials -> pile -> image -> each policy's grasp -> execution -> verdict.

Each trial's pile is dropped and rendered once and every policy is tried on
it in a fresh physics world of its own, so the policies of one run are
compared on the same piles. :func:`run_trials` runs a list of trials in
this process; :func:`run_protocol` splits them over worker processes.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import torch

from osgd.simulation import load_pipeline, make_renderer, stage_renderer
from togcrf.robot.execute import execute, judge
from togcrf.robot.lifting import RobotParams, lift_rectangle
from togcrf.robot.observation import Observation
from togcrf.robot.pictures import failure_picture, render_state
from togcrf.robot.pile import feasible_pile
from togcrf.robot.policies import Choice, OraclePolicy, Policy, RandomPolicy, model_policy
from togcrf.robot.protocol import Trial
from togcrf.robot.world import World, load_world

log = logging.getLogger(__name__)

#: Policy names that are not checkpoints.
BUILT_IN_POLICIES: tuple[str, ...] = ("oracle", "random")


@dataclass(frozen=True)
class RunSpec:
    """Everything a worker needs to rebuild the run (picklable).

    Attributes
    ----------
    config_path : Path
    overrides : tuple of str
        ``section.key=value`` overrides of the config.
    data_dir : Path or None
        Where the pipeline is built (None: the world is given directly, in-process only).
    policies : tuple of str
        ``oracle``, ``random`` and checkpoint paths, in the log's order.
    out : Path
        The run folder (failure pictures under ``failures/``).
    params : RobotParams
    min_score, min_stability : float
        For checkpoints (:func:`togcrf.predict.best_grasp_for_task`).
    views : int
        For checkpoints: test-time views averaged per image (:mod:`togcrf.tta`).
    pictures : bool
        Draw a picture of every failure.
    require_clear : bool
        Redraw a trial's pile until the task can be done in it (:func:`togcrf.robot.pile.feasible_pile`).
    max_piles : int
        Piles drawn at most per trial.
    """

    config_path: Path | None
    overrides: tuple[str, ...]
    data_dir: Path | None
    policies: tuple[str, ...]
    out: Path
    params: RobotParams = field(default_factory=RobotParams)
    min_score: float = 0.5
    min_stability: float = 0.5
    views: int = 1
    pictures: bool = True
    require_clear: bool = True
    max_piles: int = 20


def make_policies(spec: RunSpec, world: World) -> list[Policy]:
    """The run's policies: the built-in ones by name, the rest loaded as checkpoints."""
    policies: list[Policy] = []
    for name in spec.policies:
        if name == "oracle":
            policies.append(OraclePolicy(world, spec.params))
        elif name == "random":
            policies.append(RandomPolicy(world.seed, world.gripper.finger_width, world.gripper.max_opening))
        else:
            policies.append(model_policy(Path(name), min_score=spec.min_score, min_stability=spec.min_stability,
                                         views=spec.views))
    return policies


def _rectangle_row(choice: Choice, observation: Observation) -> dict[str, Any]:
    aimed = -1 if choice.rectangle is None else observation.object_at(choice.rectangle[0], choice.rectangle[1])
    return {
        "rectangle": None if choice.rectangle is None else [float(value) for value in choice.rectangle],
        "chosen_category": choice.category, "task_probability": float(choice.task_probability),
        "stability": float(choice.stability), "detections": int(choice.detections), "aimed_object": aimed,
        "aimed_category": observation.categories[aimed] if aimed >= 0 else "",
    }


def _execution_row(execution: Any, observation: Observation) -> dict[str, Any]:
    if execution is None:
        return {"grasp_position": None, "grasp_quaternion": None, "opening": float("nan"),
                "approach_stopped": False, "stopped_by": "", "held_object": -1, "held_category": "", "held": False,
                "rise": 0.0, "label": "", "nearest_task": "", "nearest_distance": float("nan")}
    gripped = execution.gripped
    return {
        "grasp_position": execution.grasp.position.tolist(), "grasp_quaternion": execution.grasp.quaternion.tolist(),
        "opening": execution.grasp.opening, "approach_stopped": execution.stopped, "stopped_by": execution.stopped_by,
        "held_object": gripped, "held_category": observation.categories[gripped] if gripped >= 0 else "",
        "held": execution.held, "rise": float(execution.rise), "label": execution.label,
        "nearest_task": execution.nearest_task, "nearest_distance": float(execution.nearest_distance),
    }


def try_policy(world: World, trial: Trial, observation: Observation, policy: Policy, spec: RunSpec,
               picture_renderer: Any) -> dict[str, Any]:
    """One policy on one observed pile: choose, lift, execute, judge; a trial log row (no timing of the pile)."""
    started = time.perf_counter()
    choice = policy.choose(trial, observation)
    chosen = time.perf_counter()
    grasp = None if choice.rectangle is None else lift_rectangle(choice.rectangle, observation, world.gripper,
                                                                 spec.params)
    execution = None if grasp is None else execute(world, observation.scene, grasp, spec.params)
    no_grasp = "no_grasp" if choice.rectangle is None else "no_depth"
    verdict = judge(world, trial, observation, execution, no_grasp)
    picture = ""
    if verdict.reason and spec.pictures:
        picture = _draw_failure(world, trial, policy, observation, choice, execution, verdict.reason, spec,
                                picture_renderer)
    if choice.reason:
        log.info("%s %s: %s", policy.name, trial.name, choice.reason)
    return {
        "policy": policy.name, "checkpoint": policy.checkpoint, "task": trial.task, "category": trial.category or "",
        "repeat": trial.repeat, "scene_index": trial.scene_index, "pile_seed": int(observation.scene["seed"]),
        "pile_categories": observation.categories, **_rectangle_row(choice, observation),
        **_execution_row(execution, observation), "judged_by": verdict.judged_by, "gsr_s": verdict.gsr_s,
        "gsr_t": verdict.gsr_t, "reason": verdict.reason, "picture": picture,
        "seconds_policy": chosen - started, "seconds_execute": time.perf_counter() - chosen,
    }


def _draw_failure(world: World, trial: Trial, policy: Policy, observation: Observation, choice: Choice,
                  execution: Any, reason: str, spec: RunSpec, renderer: Any) -> str:
    relative = Path("failures") / policy.name.replace(":", "_").replace("/", "_") / f"{trial.name}.png"
    state = render_state(world, observation, execution, renderer)
    model = getattr(policy, "model", None)
    named = {} if model is None else {"categories": model.vocabulary["categories"]}
    failure_picture(spec.out / relative, trial, policy.name, observation, choice.rectangle, execution, reason, state,
                    getattr(policy, "last_detections", None), **named)
    return str(relative)


def picture_renderer(fallback: Any) -> Any:
    """The exact CPU ray caster for failure pictures, else the render stage's renderer."""
    try:
        return make_renderer("embree")
    except RuntimeError:
        return fallback


def run_trials(world: World, trials: Sequence[Trial], policies: Sequence[Policy], spec: RunSpec,
               progress: Callable[[dict[str, Any]], None] | None = None) -> list[dict[str, Any]]:
    """Run trials in this process; one trial log row per trial and policy.

    Parameters
    ----------
    world : World
    trials : sequence of Trial
    policies : sequence of Policy
    spec : RunSpec
    progress : callable, optional
        Called with every row as it is made.
    """
    renderer, notes = stage_renderer(world.params("samples").renderer)
    for note in notes:
        log.warning(note)
    pictures = picture_renderer(renderer)
    rows = []
    for trial in trials:
        started = time.perf_counter()
        observation, piles = feasible_pile(world, trial, renderer, spec.params, spec.max_piles, spec.require_clear)
        piled = time.perf_counter()
        for policy in policies:
            row = try_policy(world, trial, observation, policy, spec, pictures)
            row.update(piles=piles, seconds_pile=piled - started)
            rows.append(row)
            if progress is not None:
                progress(row)
    return rows


def worker_world(spec: RunSpec) -> World:
    """The world of a run, loaded from its data dir and config."""
    if spec.data_dir is None or spec.config_path is None:
        raise ValueError("a worker process needs the run's data dir and config file")
    return load_world(spec.data_dir, load_pipeline(spec.config_path, spec.overrides))


def _worker(spec: RunSpec, trials: Sequence[Trial], progress: Callable[[dict[str, Any]], None] | None
            ) -> list[dict[str, Any]]:
    torch.set_num_threads(1)
    world = worker_world(spec)
    return run_trials(world, trials, make_policies(spec, world), spec, progress)


def run_protocol(spec: RunSpec, trials: Sequence[Trial], workers: int = 1, world: World | None = None,
                 progress: Callable[[dict[str, Any]], None] | None = None) -> list[dict[str, Any]]:
    """Run the trials, in this process or split (interleaved) over ``workers`` spawned processes.

    Rows come back in trial order whatever the number of workers. ``progress``
    is called with every row as it is made, in the process that makes it (a
    module-level function, when there are workers).
    """
    order = {(trial.task, trial.repeat): index for index, trial in enumerate(trials)}
    if workers <= 1:
        world = world if world is not None else worker_world(spec)
        rows = run_trials(world, trials, make_policies(spec, world), spec, progress)
    else:
        chunks = [list(trials[start::workers]) for start in range(workers)]
        with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn")) as pool:
            futures = [pool.submit(_worker, spec, chunk, progress) for chunk in chunks if chunk]
            rows = [row for future in futures for row in future.result()]
    policy_order = {name: index for index, name in enumerate(dict.fromkeys(row["policy"] for row in rows))}
    return sorted(rows, key=lambda row: (order[(row["task"], row["repeat"])], policy_order[row["policy"]]))

