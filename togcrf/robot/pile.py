"""A trial's pile and what the camera sees of it, through the stack and render stages.

The pile is dropped by the stack stage's own drop (:func:`osgd.simulation.drop_pile`)
with the pipeline's ``[scenes]`` parameters, at the trial's scene index
(:mod:`togcrf.robot.protocol`); its draw is the stage's
:func:`~osgd.simulation.draw_releases` with one change: when none of the
drawn tools can do the trial's task (or is of the named category), one of
them, chosen at random, is replaced by such a tool, as the paper's piles
always held a suitable object. The depth image is rendered by the render
stage (:func:`osgd.simulation.render_pile`: camera pose, crop, renderer,
noise and ground-truth rectangles), with the pipeline's ``[samples]`` parameters;
:class:`~togcrf.robot.observation.Observation` holds what the robot sees.

A feasible pile (:func:`feasible_pile`): the render stage must annotate at
least one rectangle of the trial's task (on the named category for "no
task" and "hand over") in the image, that is, a stable grasp of the task
whose contacts are seen, and the robot's top-down grasp of that rectangle
must clear every tool on its way down (:func:`clear_grasps`); a pile
without one is redrawn (the next scene index), as the paper's experimenter
set up piles in which the task could be done. (The render stage tests its
grasps against the other tools but not the table, so some rectangles come
from grasps whose approach points up through the table; top-down, their
fingers may land on a neighbour.)
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numpy as np

from osgd.contract.encoding import decode_depth, decode_mask
from osgd.simulation import CameraIntrinsics, CameraPose, Release, draw_releases, drop_pile, pile_collider, render_pile
from togcrf.robot.lifting import lift_rectangle
from togcrf.robot.observation import Observation
from togcrf.robot.protocol import PILES_PER_TRIAL, Trial
from togcrf.robot.world import World

log = logging.getLogger(__name__)


def suitable_categories(world: World, trial: Trial) -> set[str]:
    """The categories that can serve a trial: the named one, or those affording the tool task."""
    if trial.category is not None:
        return {trial.category}
    return {category for category in world.pool.categories if world.affords(category, trial.task)}


def draw_with_suitable(categories: set[str]) -> Callable:
    """The stack stage's draw, with one tool replaced by one of ``categories`` when none was drawn."""

    def draw(rng: np.random.Generator, pool: Any, params: Any) -> list:
        releases = draw_releases(rng, pool, params)
        if not categories or any(pool.rows[item.model_index]["category"] in categories for item in releases):
            return releases
        candidates = [index for category in sorted(categories) for index in pool.by_category.get(category, [])]
        slot = int(rng.integers(len(releases)))
        chosen = candidates[int(rng.integers(len(candidates)))]
        releases[slot] = Release(chosen, releases[slot].quaternion, releases[slot].xy)
        return releases

    return draw


def build_pile(world: World, trial: Trial, pile: int = 0) -> dict[str, Any]:
    """Pile number ``pile`` of a trial, at rest: a ``scenes`` row.

    Raises
    ------
    RuntimeError
        If every attempt of the stack stage was rejected.
    """
    params = world.params("scenes")
    result = drop_pile(world.pool, params, world.seed, trial.scene_index + pile,
                       draw=draw_with_suitable(suitable_categories(world, trial)))
    if result.row is None:
        reasons = ", ".join(f"{reason} {count}" for reason, count in sorted(result.rejections.items()))
        raise RuntimeError(f"trial {trial.name}: all {params.max_attempts} attempts at its pile were rejected "
                           f"({reasons})")
    return result.row


def observe(world: World, scene: dict[str, Any], renderer: Any) -> Observation:
    """Render a pile with the render stage: noisy depth, mask, camera, ground-truth rectangles."""
    params = world.params("samples")
    model_ids = {obj["model_id"] for obj in scene["objects"]}
    near, far = params.intrinsics().near, params.intrinsics().far
    row = render_pile(scene, world.models, world.stable_grasps(model_ids), params, world.seed, renderer,
                      world.gripper, (near, far))
    fx, fy, cx, cy = row["intrinsics"]
    intrinsics = CameraIntrinsics(width=int(row["width"]), height=int(row["height"]), fx=fx, fy=fy, cx=cx, cy=cy,
                                  near=near, far=far)
    pose = CameraPose.from_quaternion(np.asarray(row["camera_position"]), np.asarray(row["camera_quaternion"]))
    return Observation(scene, decode_depth(row["depth"]), decode_mask(row["mask"]), intrinsics, pose, row)


def task_grasps(observation: Observation, trial: Trial) -> list[dict[str, Any]]:
    """The image's ground-truth grasps of the trial's task (on the named category)."""
    categories = {obj["object_index"]: obj["category"] for obj in observation.sample["objects"]}
    return [grasp for grasp in observation.sample["grasps"] if grasp["task"] == trial.task
            and (trial.category is None or categories[grasp["object_index"]] == trial.category)]


def clear_grasps(world: World, observation: Observation, grasps: list[dict[str, Any]], params: Any,
                 tolerance: float = 0.001) -> list[bool]:
    """Whether each ground-truth rectangle's top-down grasp is clear of every tool on its way down.

    The rectangle is lifted as the robot lifts it (:func:`togcrf.robot.lifting.lift_rectangle`) and the
    pre-shaped gripper is tested against every tool of the pile, the grasped one included, at the grasp
    pose and every 5 mm up to ``params.approach_height`` above it (the render stage's pile collision
    test, :func:`osgd.simulation.pile_collider`; penetration up to ``tolerance`` allowed).
    """
    raises = np.arange(0.0, params.approach_height + 1e-9, 0.005)
    clear = []
    with pile_collider(world.models, observation.scene["objects"], world.gripper, tolerance) as collider:
        for grasp in grasps:
            pose = lift_rectangle(np.asarray(grasp["rectangle"]), observation, world.gripper, params)
            clear.append(pose is not None and not any(
                collider.collides(-1, pose.position + np.array([0.0, 0.0, up]), pose.rotation, pose.opening)
                for up in raises))
    return clear


def feasible_pile(world: World, trial: Trial, renderer: Any, params: Any, max_piles: int = 20,
                  require_clear: bool = True) -> tuple[Observation, int]:
    """The trial's first pile in which the task can be done (see the module text).

    Returns
    -------
    observation : Observation
    piles : int
        Piles drawn (the last one is used, feasible or not, after ``max_piles``).
    """
    for pile in range(min(max_piles, PILES_PER_TRIAL)):
        observation = observe(world, build_pile(world, trial, pile), renderer)
        if not require_clear or any(clear_grasps(world, observation, task_grasps(observation, trial), params)):
            return observation, pile + 1
    log.warning("trial %s: in none of %d piles can the task be done; the last one is used", trial.name, max_piles)
    return observation, max_piles
