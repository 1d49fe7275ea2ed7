"""Dropping a pile of objects in pybullet until it comes to rest.

One scene is drawn and simulated per *attempt*: its random draws come from a
generator seeded by :func:`attempt_seed` (pipeline seed, scene index,
attempt) only, so any scene can be rebuilt alone, whatever shard it is in.
An attempt whose simulation goes wrong is rejected with a reason and the
scene is redrawn with the next attempt's seed.

World frame (``docs/scenes.md``): z up, the floor is the plane z = 0, the
walled area is a square of side ``area_size`` (1 m, paper section IV-A)
centred on the origin. Poses are of each model's *mesh frame* (the frame of
the ``models`` row's vertices), through :mod:`osgd.physics`.

The drop: objects are released one after another, ``release_interval``
apart, each at a uniformly random orientation, its box centre at
``drop_height`` (30 cm, paper section IV-A) above a point drawn in a small
disc around the pile centre, raised when needed to clear what is already
there. Releasing them into the same small disc is what makes them land on
each other (REFERENCE section 2: the original generator dropped all objects
from one point).
"""

from __future__ import annotations

import atexit
import json
import logging
import math
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from osgd.physics import ObjectBody, PileWorld, create_object_body, get_mesh_pose, pybullet_module, worker_client
from osgd.scenes.params import ScenesStageParams

log = logging.getLogger(__name__)

#: Why an attempt was rejected; the keys of the ``rejections`` JSON column.
REJECTION_REASONS: tuple[str, ...] = (
    "blew_up",  # NaN or a speed above max_linear_speed / max_angular_speed
    "left_area",  # an object's centre of mass crossed the walls' inner faces
    "fell_through_floor",  # an object's centre of mass went below z = 0
    "interpenetration",  # two bodies overlap deeper than penetration_tolerance after settling
    "not_settled",  # max_sim_time ran out before every object was at rest
)

#: Columns of the ``models`` table the drop needs.
MODEL_COLUMNS: tuple[str, ...] = (
    "model_id", "name", "category", "convex_parts", "mass", "center_of_mass", "inertia", "friction", "decomposition",
)

_WALL_THICKNESS = 0.1


def attempt_seed(pipeline_seed: int, scene_index: int, attempt: int) -> int:
    """The seed of one attempt at one scene, in [0, 2**63).

    Derived with :class:`numpy.random.SeedSequence` from the three numbers
    only, so scenes do not depend on how they are split into shards.
    """
    entropy = [int(pipeline_seed) & 0xFFFF_FFFF_FFFF_FFFF, int(scene_index), int(attempt)]
    state = np.random.SeedSequence(entropy).generate_state(1, dtype=np.uint64)[0]
    return int(state >> np.uint64(1))


class ModelPool:
    """The models a scene can be drawn from, in a fixed order.

    Parameters
    ----------
    rows : sequence of mapping
        ``models`` rows (at least the :data:`MODEL_COLUMNS`).

    Raises
    ------
    ValueError
        If there are no rows.
    """

    def __init__(self, rows: Sequence[Mapping[str, Any]]) -> None:
        if not rows:
            raise ValueError("the models table has no rows: no scene can be drawn (did every model get rejected?)")
        # Sorted by name (the content hash breaks ties), so the pool does not
        # depend on shard order, and a model whose mesh changes (an edit, or
        # another processor's rounding) changes only the scenes it is in, not
        # the draws of every scene, as sorting by content hash did.
        self.rows: list[Mapping[str, Any]] = sorted(rows, key=lambda row: (str(row["name"]), str(row["model_id"])))
        self.categories: list[str] = sorted({str(row["category"]) for row in self.rows})
        self.by_category: dict[str, list[int]] = {
            category: [index for index, row in enumerate(self.rows) if row["category"] == category]
            for category in self.categories
        }
        self._hull_points: dict[int, np.ndarray] = {}

    def hull_points(self, index: int) -> np.ndarray:
        """Every convex-part vertex of a model, (V, 3) float64, mesh frame, metres."""
        if index not in self._hull_points:
            parts = self.rows[index]["convex_parts"]
            self._hull_points[index] = np.concatenate(
                [np.asarray(part["vertices"], dtype=np.float64).reshape(-1, 3) for part in parts]
            )
        return self._hull_points[index]


@dataclass(frozen=True)
class Release:
    """One object of a drawn scene, before the simulation.

    Attributes
    ----------
    model_index : int
        Index into :attr:`ModelPool.rows`.
    quaternion : (4,) float64
        Mesh-frame orientation at release, (x, y, z, w).
    xy : (2,) float64
        Where the centre of its box is released, world frame, metres.
    """

    model_index: int
    quaternion: np.ndarray
    xy: np.ndarray


def draw_releases(rng: np.random.Generator, pool: ModelPool, params: ScenesStageParams) -> list[Release]:
    """Draw the models, orientations and release points of one scene."""
    count = int(rng.integers(params.min_objects, params.max_objects + 1))
    chosen: list[int] = []
    if params.balance == "category":
        weights = np.array([params.category_weights.get(name, 1.0) for name in pool.categories], dtype=np.float64)
        if weights.sum() <= 0:
            raise ValueError(f"category_weights give every available category {pool.categories} zero weight")
        weights /= weights.sum()
    for _ in range(count):
        if params.balance == "category":
            category = pool.categories[int(rng.choice(len(pool.categories), p=weights))]
            candidates = pool.by_category[category]
        else:
            candidates = list(range(len(pool.rows)))
        if params.distinct_models:
            unused = [index for index in candidates if index not in chosen]
            candidates = unused or candidates
        chosen.append(candidates[int(rng.integers(len(candidates)))])
    centre_radius = params.pile_center_radius * math.sqrt(rng.uniform())
    centre_angle = rng.uniform(0.0, 2 * math.pi)
    centre = centre_radius * np.array([math.cos(centre_angle), math.sin(centre_angle)])
    releases = []
    for model_index in chosen:
        quaternion = Rotation.random(random_state=rng).as_quat()
        radius = params.drop_radius * math.sqrt(rng.uniform())
        angle = rng.uniform(0.0, 2 * math.pi)
        xy = centre + radius * np.array([math.cos(angle), math.sin(angle)])
        releases.append(Release(model_index, quaternion, xy))
    return releases


@dataclass
class DropOutcome:
    """What one simulated attempt gave.

    Attributes
    ----------
    reason : str
        ``""`` when accepted, else one of :data:`REJECTION_REASONS`.
    positions : (N, 3) float64
        Final mesh-frame origins, world frame, metres.
    quaternions : (N, 4) float64
        Final mesh-frame orientations, (x, y, z, w).
    settled : bool
    sim_time : float
        Simulated seconds.
    sim_steps : int
    detail : str
        What exactly went wrong (for logs).
    """

    reason: str
    positions: np.ndarray
    quaternions: np.ndarray
    settled: bool
    sim_time: float
    sim_steps: int
    detail: str = ""


def build_world(client: int, params: ScenesStageParams) -> list[int]:
    """The floor plane at z = 0 and four walls around the area; returns body ids."""
    pybullet = pybullet_module()
    lateral, rolling, spinning = params.floor_friction
    plane = pybullet.createCollisionShape(pybullet.GEOM_PLANE, physicsClientId=client)
    # A body without a visual shape gets one made from its collision shape for pybullet's renderer: for the
    # plane that is slow, as long as many steps of a pile. A small box instead; physics never sees it.
    look = pybullet.createVisualShape(pybullet.GEOM_BOX, halfExtents=[0.01] * 3, physicsClientId=client)
    maximal = params.maximal_coordinates
    bodies = [pybullet.createMultiBody(0, plane, look, useMaximalCoordinates=maximal, physicsClientId=client)]
    half = params.area_size / 2
    length = params.area_size + 2 * _WALL_THICKNESS
    for axis in (0, 1):
        extents = [length / 2, length / 2, params.wall_height / 2]
        extents[axis] = _WALL_THICKNESS / 2
        shape = pybullet.createCollisionShape(pybullet.GEOM_BOX, halfExtents=extents, physicsClientId=client)
        for side in (-1.0, 1.0):
            position = [0.0, 0.0, params.wall_height / 2]
            position[axis] = side * (half + _WALL_THICKNESS / 2)
            bodies.append(pybullet.createMultiBody(0, shape, basePosition=position, useMaximalCoordinates=maximal,
                                                   physicsClientId=client))
    for body in bodies:
        pybullet.changeDynamics(body, -1, lateralFriction=lateral, rollingFriction=rolling,
                                spinningFriction=spinning, physicsClientId=client)
    return bodies


def pile_body(client: int, model: dict, position: np.ndarray, quaternion: np.ndarray,
              params: ScenesStageParams) -> ObjectBody:
    """One object of a pile as the stage simulates it: the collision hulls and the coordinates ``params`` ask for.

    Parameters
    ----------
    model : dict
        A ``models`` row.
    position : (3,) float
        World position of the mesh frame, m.
    quaternion : (4,) float
        World orientation of the mesh frame, (x, y, z, w).
    """
    return create_object_body(client, model, position, quaternion, max_hull_vertices=params.max_hull_vertices,
                              maximal_coordinates=params.maximal_coordinates)


def _release(client: int, pool: ModelPool, release: Release, objects: list[ObjectBody],
             params: ScenesStageParams) -> ObjectBody:
    pybullet = pybullet_module()
    rotated = Rotation.from_quat(release.quaternion).apply(pool.hull_points(release.model_index))
    low, high = rotated.min(axis=0), rotated.max(axis=0)
    box_centre = (low + high) / 2
    half_height = (high[2] - low[2]) / 2
    top = max((pybullet.getAABB(body.body_id, physicsClientId=client)[1][2] for body in objects), default=0.0)
    centre_z = max(params.drop_height, top + params.drop_clearance + half_height)
    target = np.array([release.xy[0], release.xy[1], centre_z])
    return pile_body(client, pool.rows[release.model_index], target - box_centre, release.quaternion, params)


def simulate_drop(pool: ModelPool, releases: Sequence[Release], params: ScenesStageParams,
                  initial_poses: Sequence[tuple[np.ndarray, np.ndarray]] | None = None) -> DropOutcome:
    """Simulate one attempt in an empty world (this process's :func:`osgd.physics.worker_client`) and judge it.

    Parameters
    ----------
    pool : ModelPool
    releases : sequence of Release
    params : ScenesStageParams
    initial_poses : sequence of (position (3,), quaternion (4,)), optional
        Place every object at these mesh-frame poses at time 0 instead of
        releasing them one by one (to rebuild or test a given arrangement).

    Returns
    -------
    DropOutcome
    """
    with worker_client(timestep=params.timestep) as client:
        build_world(client, params)
        run = _step_until_rest(client, pool, releases, params, initial_poses)
        reason, detail, objects = run.reason, run.detail, run.objects
        if not reason and len(objects) < len(releases):  # a pile without all its objects is never kept
            reason, detail = "not_settled", (f"max_sim_time {params.max_sim_time} s ended before object "
                                             f"{len(objects) + 1} of {len(releases)} was released")
        if not reason:
            reason, detail = _final_verdict(client, objects, params, run.at_rest,
                                            f"{run.step * params.timestep:.2f}", run.mover)
        poses = [get_mesh_pose(body) for body in objects]
    if not reason and params.max_hull_vertices > 0:
        depth, pair = stored_penetration([pool.rows[release.model_index] for release in releases], poses, params)
        if depth > params.penetration_tolerance:
            reason, detail = "interpenetration", f"stored parts of objects {pair} overlap by {depth * 1000:.1f} mm"
    positions = np.array([pose[0] for pose in poses], dtype=np.float64).reshape(-1, 3)
    quaternions = np.array([pose[1] for pose in poses], dtype=np.float64).reshape(-1, 4)
    if reason:
        log.debug("attempt rejected (%s): %s", reason, detail)
    return DropOutcome(reason, positions, quaternions, run.at_rest, run.step * params.timestep, run.step, detail)


@dataclass
class _Run:
    """Where one attempt's simulation stopped (:func:`_step_until_rest`)."""

    objects: list[ObjectBody] = field(default_factory=list)
    step: int = 0
    reason: str = ""  # why it went wrong ("" when it did not)
    detail: str = ""
    at_rest: bool = False
    mover: str = ""  # the object that moved most in the last rest window


def _step_until_rest(client: int, pool: ModelPool, releases: Sequence[Release], params: ScenesStageParams,
                     initial_poses: Sequence[tuple[np.ndarray, np.ndarray]] | None) -> _Run:
    """Release the objects and step until the pile is at rest, goes wrong or the time is up."""
    pybullet = pybullet_module()
    dt = params.timestep
    release_steps = [0] * len(releases) if initial_poses is not None else [
        round(index * params.release_interval / dt) for index in range(len(releases))
    ]
    last_release = max(release_steps, default=0)
    fixed_steps = math.ceil(params.fixed_sim_time / dt) if params.fixed_sim_time > 0 else 0
    max_steps = last_release + fixed_steps if fixed_steps else math.ceil(params.max_sim_time / dt)
    run = _Run()
    window_start: list[tuple[np.ndarray, np.ndarray]] | None = None
    while run.step < max_steps:
        while len(run.objects) < len(releases) and release_steps[len(run.objects)] <= run.step:
            run.objects.append(_next_body(client, pool, releases, run.objects, params, initial_poses))
        pybullet.stepSimulation(physicsClientId=client)
        run.step += 1
        rest_test = (len(run.objects) == len(releases) and run.step > last_release
                     and (run.step - last_release) % params.rest_steps == 0)
        if run.step % params.runaway_check_steps == 0 or rest_test or run.step >= max_steps:
            run.reason, run.detail = _runaway(client, run.objects, params, run.step)
            if run.reason:
                break
        # At rest: over the last window of rest_steps steps every object
        # moved less than the rest speeds allow. Displacement, not the
        # instantaneous speeds: contact jitter (a light tool's angular
        # speed flickering above 0.05 rad/s while it goes nowhere) kept a
        # third of the attempts of the default pipeline from ever
        # counting as settled.
        if rest_test:
            poses = [_com_pose(client, body) for body in run.objects]
            if window_start is not None:
                run.at_rest, run.mover = _window_at_rest(window_start, poses, run.objects, params,
                                                         params.rest_steps * dt)
                if run.at_rest and fixed_steps == 0:
                    break
            window_start = poses
    return run


def _next_body(client: int, pool: ModelPool, releases: Sequence[Release], objects: list[ObjectBody],
               params: ScenesStageParams,
               initial_poses: Sequence[tuple[np.ndarray, np.ndarray]] | None) -> ObjectBody:
    """The next object of ``releases`` in the world: released, or placed at its initial pose."""
    index = len(objects)
    if initial_poses is None:
        return _release(client, pool, releases[index], objects, params)
    position, quaternion = initial_poses[index]
    return pile_body(client, pool.rows[releases[index].model_index], np.asarray(position), np.asarray(quaternion),
                     params)


def _runaway(client: int, objects: Sequence[ObjectBody], params: ScenesStageParams, step: int) -> tuple[str, str]:
    """Why the simulation went wrong at this step, for the first object that shows it.

    Returns
    -------
    reason : str
        ``"blew_up"``, ``"left_area"``, ``"fell_through_floor"`` or ``""`` when all is well.
    detail : str
        Which object and how ("" when all is well).
    """
    pybullet = pybullet_module()
    half = params.area_size / 2
    for body in objects:
        linear, angular = pybullet.getBaseVelocity(body.body_id, physicsClientId=client)
        position = pybullet.getBasePositionAndOrientation(body.body_id, physicsClientId=client)[0]
        linear_speed, angular_speed = math.hypot(*linear), math.hypot(*angular)
        if not (math.isfinite(linear_speed) and math.isfinite(angular_speed)
                and all(math.isfinite(value) for value in position)):
            return "blew_up", f"{body.model_id}: non-finite state at step {step}"
        if linear_speed > params.max_linear_speed or angular_speed > params.max_angular_speed:
            return "blew_up", f"{body.model_id}: {linear_speed:.2f} m/s, {angular_speed:.1f} rad/s at step {step}"
        if abs(position[0]) > half or abs(position[1]) > half:
            return "left_area", f"{body.model_id}: at {np.round(position, 3)} at step {step}"
        if pybullet.getAABB(body.body_id, physicsClientId=client)[1][2] < 0.0:
            # Wholly below the floor. (The centre of mass of a 3 mm
            # fork dips a millimetre below z = 0 on impact, and the
            # floor pushes it back up: that is no fall.)
            return "fell_through_floor", f"{body.model_id}: z = {position[2]:.3f} at step {step}"
    return "", ""


def _final_verdict(client: int, objects: Sequence[ObjectBody], params: ScenesStageParams, settled: bool,
                   elapsed: str, mover: str) -> tuple[str, str]:
    """Why a simulation that ran its course is rejected: unsettled or interpenetrating ("" when accepted).

    Parameters
    ----------
    elapsed : str
        Simulated seconds, as the message shows them.
    mover : str
        The object that moved most in the last rest window (from :func:`_window_at_rest`).

    Returns
    -------
    reason, detail : str
    """
    if not settled and params.reject_unsettled:
        return "not_settled", f"still moving after {elapsed} s: {mover}"
    depth, pair = deepest_penetration(client, [body.body_id for body in objects])
    if depth > params.penetration_tolerance:
        return "interpenetration", f"bodies {pair} overlap by {depth * 1000:.1f} mm"
    return "", ""


def _com_pose(client: int, body: ObjectBody) -> tuple[np.ndarray, np.ndarray]:
    pybullet = pybullet_module()
    position, quaternion = pybullet.getBasePositionAndOrientation(body.body_id, physicsClientId=client)
    return np.asarray(position, dtype=np.float64), np.asarray(quaternion, dtype=np.float64)


def _window_at_rest(start: Sequence[tuple[np.ndarray, np.ndarray]], end: Sequence[tuple[np.ndarray, np.ndarray]],
                    objects: Sequence[ObjectBody], params: ScenesStageParams, window: float) -> tuple[bool, str]:
    """Whether every object moved and turned less than the rest speeds allow over ``window`` seconds.

    Returns
    -------
    at_rest : bool
    mover : str
        The object furthest over its bounds and how far it went ("" when at rest).
    """
    worst, mover = 1.0, ""
    for body, (position_0, quaternion_0), (position_1, quaternion_1) in zip(objects, start, end, strict=True):
        # Plain Python floats: BLAS dot products may round by processor.
        moved = math.dist(position_0.tolist(), position_1.tolist())
        cosine = abs(math.fsum(a * b for a, b in zip(quaternion_0.tolist(), quaternion_1.tolist(), strict=True)))
        turned = 2.0 * math.acos(min(1.0, cosine))
        excess = max(moved / (params.rest_linear_speed * window), turned / (params.rest_angular_speed * window))
        if excess >= worst:
            worst = excess
            mover = f"{body.model_id} moved {moved * 1000:.2f} mm and turned {turned:.4f} rad in {window:.3f} s"
    return not mover, mover


def deepest_penetration(client: int, object_ids: Sequence[int]) -> tuple[float, tuple[int, int]]:
    """The deepest overlap of an object with anything, from current contacts.

    Returns
    -------
    depth : float
        Metres, >= 0 (0 when nothing overlaps).
    pair : (int, int)
        Body ids of the deepest pair ((-1, -1) when none).
    """
    pybullet = pybullet_module()
    deepest, pair = 0.0, (-1, -1)
    objects = set(object_ids)
    for contact in pybullet.getContactPoints(physicsClientId=client):
        body_a, body_b, distance = contact[1], contact[2], contact[8]
        if (body_a in objects or body_b in objects) and -distance > deepest:
            deepest, pair = -distance, (body_a, body_b)
    return deepest, pair


def stored_penetration(models: Sequence[Mapping[str, Any]], poses: Sequence[tuple[np.ndarray, np.ndarray]],
                       params: ScenesStageParams) -> tuple[float, tuple[int, int]]:
    """The deepest interpenetration of the objects' stored convex parts at the given poses.

    The objects are placed as static bodies beside the floor and walls of
    :func:`build_world` in an empty world; pybullet's closest points
    at distance 0 give the overlaps (a simulation with reduced hulls, whose
    contacts say nothing about the stored parts, is judged this way).

    Parameters
    ----------
    models : sequence of mapping
        The pile's ``models`` rows, one per object (:data:`MODEL_COLUMNS`).
    poses : sequence of (position (3,), quaternion (4,))
        Mesh-frame poses, one per object.
    params : ScenesStageParams
        The floor and walls.

    Returns
    -------
    depth : float
        Metres (0 when nothing overlaps).
    pair : (int, int)
        Indices of the deepest pair of objects; -1 stands for the floor or a wall.
    """
    pybullet = pybullet_module()
    deepest, pair = 0.0, (-1, -1)
    world = stored_parts_world(params)
    objects = [{"model_id": model["model_id"], "position": position, "quaternion": quaternion}
               for model, (position, quaternion) in zip(models, poses, strict=True)]
    bodies = world.place({model["model_id"]: model for model in models}, objects)
    try:
        for index, body in enumerate(bodies):
            others = [(other_index, bodies[other_index]) for other_index in range(index + 1, len(bodies))]
            for other_index, other in [*others, *((-1, wall) for wall in world.fixtures)]:
                for point in pybullet.getClosestPoints(body, other, 0.0, physicsClientId=world.client):
                    if -point[8] > deepest:
                        deepest, pair = -point[8], (index, other_index)
    finally:
        world.park(bodies)
    return deepest, pair


#: :func:`stored_parts_world`'s one world, by the floor and walls it holds.
_STORED_PARTS_WORLD: dict[tuple[float, float, bool], PileWorld] = {}


def close_stored_parts_world() -> None:
    """Disconnect :func:`stored_parts_world`'s world (the next call makes a new one)."""
    for world in _STORED_PARTS_WORLD.values():
        world.close()
    _STORED_PARTS_WORLD.clear()


def stored_parts_world(params: ScenesStageParams) -> PileWorld:
    """This process's world of the stored parts for :func:`stored_penetration`.

    A :class:`osgd.physics.PileWorld` with the floor and walls of
    :func:`build_world`: each model's body of stored parts is made once per
    process and moved from pile to pile, rather than built anew for each
    pile (a stored part has hundreds of corners, slow to make into a body). One world
    at a time: parameters that move the walls replace it; disconnected at
    exit.

    Parameters
    ----------
    params : ScenesStageParams
        ``area_size``, ``wall_height`` and ``maximal_coordinates`` place and
        make the walls (friction plays no part in closest points).

    Returns
    -------
    PileWorld
    """
    key = (float(params.area_size), float(params.wall_height), bool(params.maximal_coordinates))
    if key not in _STORED_PARTS_WORLD:
        close_stored_parts_world()
        _STORED_PARTS_WORLD[key] = PileWorld(lambda client: build_world(client, params))
        atexit.unregister(close_stored_parts_world)  # registered once, however often the world is replaced
        atexit.register(close_stored_parts_world)
    return _STORED_PARTS_WORLD[key]


@dataclass
class SceneResult:
    """The accepted attempt at one scene, or None of it after ``max_attempts``.

    Attributes
    ----------
    row : dict or None
        A ``scenes`` row, or None when every attempt was rejected.
    rejections : Counter
        Rejected attempts by reason.
    """

    row: dict[str, Any] | None
    rejections: Counter = field(default_factory=Counter)


DrawFunction = Callable[[np.random.Generator, ModelPool, ScenesStageParams], list[Release]]


def generate_scene(pool: ModelPool, params: ScenesStageParams, pipeline_seed: int, scene_index: int,
                   draw: DrawFunction = draw_releases) -> SceneResult:
    """Draw and drop one scene, redrawing rejected attempts.

    Parameters
    ----------
    pool : ModelPool
    params : ScenesStageParams
    pipeline_seed : int
    scene_index : int
    draw : callable(rng, pool, params) -> list of Release
        How an attempt's objects are drawn (:func:`draw_releases`).

    Returns
    -------
    SceneResult
    """
    rejections: Counter = Counter()
    for attempt in range(params.max_attempts):
        seed = attempt_seed(pipeline_seed, scene_index, attempt)
        releases = draw(np.random.default_rng(seed), pool, params)
        outcome = simulate_drop(pool, releases, params)
        if outcome.reason:
            rejections[outcome.reason] += 1
            continue
        objects = [
            {
                "model_id": str(pool.rows[release.model_index]["model_id"]),
                "category": str(pool.rows[release.model_index]["category"]),
                "position": position.tolist(),
                "quaternion": quaternion.tolist(),
            }
            for release, position, quaternion in zip(releases, outcome.positions, outcome.quaternions, strict=True)
        ]
        row = {
            "scene_id": scene_id(scene_index),
            "scene_index": scene_index,
            "seed": seed,
            "attempts": attempt + 1,
            "rejections": json.dumps(dict(sorted(rejections.items())), separators=(",", ":")),
            "objects": objects,
            "settled": outcome.settled,
            "sim_time": outcome.sim_time,
            "sim_steps": outcome.sim_steps,
        }
        return SceneResult(row, rejections)
    return SceneResult(None, rejections)


def scene_id(scene_index: int) -> str:
    """``scene_000042`` for index 42."""
    return f"scene_{scene_index:06d}"
