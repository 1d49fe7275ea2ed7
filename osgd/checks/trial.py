"""One simulated grasp trial: approach, close, lift, shake, judge.

The trial follows the shake tests of ACRONYM and OMG-Planner and the tug of
GraspGen (REFERENCE section 5) in a world with no floor:

1. **Approach.** The hand starts at the pre-grasp pose, the grasp pose backed
   off by ``approach_distance`` against the approach axis ``z``, with the
   fingers at the grasp's pre-grasp ``width``, and sweeps in to the grasp
   pose. The sweep is a collision test at every ``approach_spacing``, not a
   dynamic motion: a free-floating object pushed aside by the hand would
   otherwise still count as reached. Any pose where the object enters the
   hand deeper than ``approach_penetration`` is an ``approach_collision``.
   ``approach_geometry`` says what the object is here: its convex parts in
   pybullet (``hulls``), or samples of its own surface (``mesh``), which
   keep the concavities a decomposition fills (between a screwdriver's
   handle and shaft, between a pair of pliers' jaws). The ``mesh`` test is
   geometry alone and runs before any physics is set up: a grasp that fails
   it never builds a world.
2. **Close.** Gravity is off: the object floats where the grasp says, so
   fingertips never stop on a floor above a thin object (REFERENCE section 8)
   and the object is free to centre itself between the pads, as it would on
   a real hand closing on a resting object. The fingers close at
   ``close_speed`` with the grip force limit until they are still. Unless
   both pads then touch the object, the trial ends as ``empty_close``.
3. **Lift.** Gravity is switched on and the hand rises ``lift_height``, then
   holds still for at most ``hold_duration``. The object's pose relative to
   the hand after closing is the reference of all slip measures; if the
   object is no longer touched by both pads, or has slipped more than
   ``max_slip_distance`` / ``max_slip_rotation``, the trial ends as
   ``slipped_on_lift``. The outcome here is the ``lift`` criterion (the
   paper's check). Both the lift and the hold stop as soon as their outcome
   is known: every few steps an object no longer gripped ends the trial
   there (with no floor and gravity on, it has fallen away), and the hold
   ends once the object has been still in the hand (its pose in the hand
   within ``hold_still_distance`` / ``hold_still_rotation``) for
   ``hold_still_duration``.
4. **Shake.** Three linear shakes (one sine period of ``shake_distance``
   amplitude along each axis of a random frame) then three rotational ones
   (``shake_angle`` about each axis of the same frame, through the grasp
   centre). The same criterion judged at the end (and every few steps, to
   stop early) gives ``dropped_on_shake``; otherwise the grasp holds under
   the ``shake`` criterion (ACRONYM's) too. The stage's ``criterion`` says
   which of the two ``stable`` means. Under ``lift`` the shakes cannot
   change ``stable``, and they run only where ``store_shake`` asks for
   their outcome; otherwise a grasp held on the lift ends there, its
   ``shake_stable`` unknown (None).

World frame: the grasp centre is at the origin with the approach pointing
down (world ``-z``), the usual top-down pick, so gravity pulls the object
along the approach, out of the hand's opening; the object is placed where the
grasp row puts it relative to the gripper.

Each trial starts from a reset world (``resetSimulation``, then a new hand
and object), so its outcome depends only on its own inputs and the random
generator it is given: never on the trials run before it in the same
process.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from osgd.checks.hand import CONVEX_HULL_MARGIN, FINGER_A, FINGER_B, SimulatedHand, create_hand
from osgd.checks.params import ChecksStageParams
from osgd.grasps.geometry import ObjectSurface
from osgd.gripper import Gripper
from osgd.physics import ObjectBody, create_object_body, process_client, pybullet_module

log = logging.getLogger(__name__)

#: Outcomes of a trial, in the order its phases run ("" for a stable grasp).
FAIL_REASONS: tuple[str, ...] = ("approach_collision", "empty_close", "slipped_on_lift", "dropped_on_shake")

#: The gripper frame in the world at the grasp: rotated pi about world x,
#: so the approach axis z points down.
GRASP_QUATERNION_IN_WORLD = np.array([1.0, 0.0, 0.0, 0.0])

#: During the lift, the hold and the shake the grip is tested every this many
#: steps (cheaper than every step; a dropped object falls clear of the pads
#: within a few), and during the hold the object's stillness in the hand.
_HOLD_CHECK_INTERVAL = 8

#: Cap on the surface samples of the ``mesh`` approach test (the spacing grows past it).
MAX_APPROACH_SAMPLES = 200_000


@dataclass(frozen=True)
class TrialResult:
    """The outcome of one grasp trial; the columns of the ``checks`` table.

    Attributes
    ----------
    stable : bool
        The outcome under the stage's ``criterion``: ``lift_stable`` or
        ``shake_stable``.
    lift_stable : bool
        Closed, lifted and held: the paper's check.
    shake_stable : bool or None
        Held through the shakes as well (implies ``lift_stable``); None for
        a grasp held on the lift whose trial skipped the shakes
        (``ChecksStageParams.shakes``).
    fail_reason : str
        ``""`` or one of :data:`FAIL_REASONS`: the phase where the full
        trial (through the shakes) failed.
    slip_distance : float
        Displacement of the object's centre of mass relative to the hand
        since the fingers closed, at the end of the trial, m (0 when the
        trial ended before closing).
    slip_rotation : float
        Rotation of the object relative to the hand since the fingers
        closed, rad.
    final_opening : float
        Pad-to-pad distance at the end of the trial, m.
    sim_steps : int
        Physics steps simulated.
    """

    stable: bool
    lift_stable: bool
    shake_stable: bool | None
    fail_reason: str
    slip_distance: float
    slip_rotation: float
    final_opening: float
    sim_steps: int


# -- geometry helpers ----------------------------------------------------------

def _compose(
    position_a: np.ndarray, quaternion_a: np.ndarray, position_b: np.ndarray, quaternion_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The transform ``a * b`` of two (position, (x, y, z, w)) poses."""
    rotation_a = Rotation.from_quat(quaternion_a)
    return rotation_a.apply(position_b) + position_a, (rotation_a * Rotation.from_quat(quaternion_b)).as_quat()


def _invert(position: np.ndarray, quaternion: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    inverse = Rotation.from_quat(quaternion).inv()
    return -inverse.apply(position), inverse.as_quat()


class _Trial:
    """The state of one running trial: the hand, the object, the step count."""

    def __init__(self, client: int, hand: SimulatedHand, body: ObjectBody, params: ChecksStageParams) -> None:
        self.client = client
        self.hand = hand
        self.body = body
        self.params = params
        self.steps = 0
        self.reference: tuple[np.ndarray, np.ndarray] | None = None

    def step(self) -> None:
        pybullet = pybullet_module()
        pybullet.stepSimulation(physicsClientId=self.client)
        self.steps += 1

    def touching(self, finger: int) -> bool:
        """Whether a finger is within ``contact_distance`` of the object."""
        pybullet = pybullet_module()
        return bool(pybullet.getClosestPoints(
            self.hand.body_id, self.body.body_id, self.params.contact_distance,
            linkIndexA=finger, physicsClientId=self.client,
        ))

    def gripped(self) -> bool:
        """Whether the object is between the pads: both touch it, and they
        have not closed on each other (fingertips resting on a face touch it
        too)."""
        return (
            self.hand.opening() >= self.params.min_opening
            and self.touching(FINGER_A) and self.touching(FINGER_B)
        )

    def object_in_hand(self) -> tuple[np.ndarray, np.ndarray]:
        """Pose of the object's centre-of-mass frame in the gripper frame."""
        pybullet = pybullet_module()
        hand_position, hand_quaternion = self.hand.pose()
        com_position, com_quaternion = pybullet.getBasePositionAndOrientation(
            self.body.body_id, physicsClientId=self.client)
        inverse_position, inverse_quaternion = _invert(hand_position, hand_quaternion)
        return _compose(inverse_position, inverse_quaternion, np.asarray(com_position), np.asarray(com_quaternion))

    def slip(self) -> tuple[float, float]:
        """Displacement (m) and rotation (rad) of the object in the hand since closing."""
        if self.reference is None:
            return 0.0, 0.0
        position, quaternion = self.object_in_hand()
        distance = float(np.linalg.norm(position - self.reference[0]))
        relative = Rotation.from_quat(self.reference[1]).inv() * Rotation.from_quat(quaternion)
        return distance, float(relative.magnitude())

    def held(self) -> bool:
        """Both pads on the object and the slip within bounds."""
        if not self.gripped():
            return False
        distance, rotation = self.slip()
        return distance <= self.params.max_slip_distance and rotation <= self.params.max_slip_rotation

    def result(self, fail_reason: str, shaken: bool = True) -> TrialResult:
        """The outcome of a trial that ended in ``fail_reason`` ("" held); ``shaken``: whether its shakes ran."""
        distance, rotation = self.slip()
        lift_stable = fail_reason in ("", "dropped_on_shake")
        shake_stable = (not fail_reason) if shaken or not lift_stable else None
        return TrialResult(
            stable=lift_stable if self.params.criterion == "lift" else shake_stable,
            lift_stable=lift_stable,
            shake_stable=shake_stable,
            fail_reason=fail_reason,
            slip_distance=distance,
            slip_rotation=rotation,
            final_opening=self.hand.opening(),
            sim_steps=self.steps,
        )


def _steps(duration: float, timestep: float) -> int:
    return max(1, round(duration / timestep))


def _approach_collides(trial: _Trial, position: np.ndarray, quaternion: np.ndarray, opening: float) -> bool:
    """Sweep the open hand from the pre-grasp pose to the grasp pose."""
    pybullet = pybullet_module()
    params = trial.params
    approach = Rotation.from_quat(quaternion).apply([0.0, 0.0, 1.0])
    count = int(np.ceil(params.approach_distance / params.approach_spacing)) + 1
    for backoff in np.linspace(params.approach_distance, 0.0, count):
        trial.hand.reset(position - backoff * approach, quaternion, opening)
        contacts = pybullet.getClosestPoints(
            trial.hand.body_id, trial.body.body_id, 0.0, physicsClientId=trial.client)
        if any(contact[8] < -params.approach_penetration for contact in contacts):
            return True
    return False


def approach_surface(model: Mapping[str, Any], params: ChecksStageParams) -> np.ndarray | None:
    """Samples of a model's surface for the ``mesh`` approach test; None for ``hulls``, which needs none.

    Every vertex plus random points, one per ``spacing**2`` of area
    (:meth:`osgd.grasps.geometry.ObjectSurface.sample`, drawn from a fixed
    seed, so that a model always gets the same samples).

    Parameters
    ----------
    model : mapping
        A ``models`` row: ``vertices`` (V, 3) and ``faces`` (F, 3).
    params : ChecksStageParams
        ``approach_geometry`` and ``approach_surface_spacing``.

    Returns
    -------
    (P, 3) float64 or None
        Object frame, m.
    """
    if params.approach_geometry != "mesh":
        return None
    mesh = trimesh.Trimesh(np.asarray(model["vertices"], dtype=np.float64).reshape(-1, 3),
                           np.asarray(model["faces"], dtype=np.int64).reshape(-1, 3), process=False)
    no_parts = np.full(len(mesh.faces), -1, dtype=np.int64)
    return ObjectSurface.sample(mesh, no_parts, params.approach_surface_spacing, np.random.default_rng(0),
                                MAX_APPROACH_SAMPLES).points


def approach_hits_surface(
    surface: np.ndarray, grasp_position: np.ndarray, grasp_quaternion: np.ndarray, opening: float,
    params: ChecksStageParams, gripper: Gripper,
) -> bool:
    """Whether the open hand, swept in from the pre-grasp pose, takes a surface sample into one of its boxes.

    The hand backed off by ``b`` along its approach sees a sample at ``z +
    b`` of its frame; over every ``b`` from 0 to ``approach_distance`` a
    box's slab ``|z - c| < h - penetration`` therefore sweeps ``z``
    in ``(c - h + penetration - approach_distance, c + h - penetration)``.
    This is the sweep of :func:`_approach_collides` without its
    ``approach_spacing``, which is finer than every box. The tolerated
    penetration is the hull test's: ``approach_penetration`` less the
    ``CONVEX_HULL_MARGIN`` by which pybullet's hulls stand proud of the
    parts (1 mm into the true surface, the grasps stage's margin).

    Parameters
    ----------
    surface : (P, 3) float
        :func:`approach_surface`, object frame, m.
    grasp_position : (3,) float
        Grasp centre in the object frame, m.
    grasp_quaternion : (4,) float
        Gripper frame in the object frame, (x, y, z, w).
    opening : float
        Pre-grasp opening, m.
    params : ChecksStageParams
    gripper : Gripper
    """
    rotation = Rotation.from_quat(grasp_quaternion).as_matrix()
    local = (np.asarray(surface) - grasp_position) @ rotation
    penetration = max(params.approach_penetration - CONVEX_HULL_MARGIN, 0.0)
    for _name, centre, half in gripper.boxes(opening):
        inner = half - penetration
        across = np.all(np.abs(local[:, :2] - centre[:2]) < inner[:2], axis=1)
        along = local[across, 2]
        if np.any((along > centre[2] - inner[2] - params.approach_distance) & (along < centre[2] + inner[2])):
            return True
    return False


def _shake_targets(
    position: np.ndarray, quaternion: np.ndarray, params: ChecksStageParams, rng: np.random.Generator
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The hand's target poses during the six shakes, one array pair per shake.

    Returns
    -------
    list of (positions (S, 3) float64, quaternions (S, 4) float64)
        World frame; ``S`` steps per shake.
    """
    axes = Rotation.random(random_state=rng).as_matrix().T
    steps = _steps(params.shake_period, params.timestep)
    phase = np.sin(2 * np.pi * np.arange(1, steps + 1) / steps)[:, None]
    still_positions = np.repeat(position[None, :], steps, axis=0)
    still_quaternions = np.repeat(np.asarray(quaternion, dtype=np.float64)[None, :], steps, axis=0)
    targets = [(position + phase * params.shake_distance * axis, still_quaternions) for axis in axes]
    rest = Rotation.from_quat(quaternion)
    targets += [
        (still_positions, (Rotation.from_rotvec(phase * params.shake_angle * axis) * rest).as_quat())
        for axis in axes
    ]
    return targets


def _setup_world(client: int, params: ChecksStageParams) -> None:
    pybullet = pybullet_module()
    pybullet.resetSimulation(physicsClientId=client)
    pybullet.setPhysicsEngineParameter(
        fixedTimeStep=params.timestep, numSolverIterations=params.solver_iterations,
        deterministicOverlappingPairs=1, physicsClientId=client,
    )
    if params.contact_erp is not None:
        pybullet.setPhysicsEngineParameter(contactERP=params.contact_erp, physicsClientId=client)
    pybullet.setGravity(0.0, 0.0, 0.0, physicsClientId=client)


def _place_object(
    client: int, model: Mapping[str, Any], grasp_position: np.ndarray, grasp_quaternion: np.ndarray,
    params: ChecksStageParams,
) -> ObjectBody:
    """The object where the grasp puts it relative to the hand at the world origin.

    With soft pads the object's own rolling and spinning friction (the
    models table's, tuned for piles on a table) is set to zero, so that the
    torsional friction in the hand is the pads' alone.
    """
    pybullet = pybullet_module()
    # Object pose in the world: (hand in world) * (grasp in object)^-1.
    object_position, object_quaternion = _compose(
        np.zeros(3), GRASP_QUATERNION_IN_WORLD,
        *_invert(np.array(grasp_position, dtype=np.float64), np.array(grasp_quaternion, dtype=np.float64)),
    )
    body = create_object_body(client, model, object_position, object_quaternion)
    if params.pad_contact == "soft":
        pybullet.changeDynamics(body.body_id, -1, rollingFriction=0.0, spinningFriction=0.0, physicsClientId=client)
    return body


def _close(trial: _Trial, grip_force: float) -> bool:
    """Close the fingers until still; whether both pads then touch the object."""
    params = trial.params
    trial.hand.close_fingers(params.close_speed, grip_force)
    still_steps = 0
    for _ in range(_steps(params.close_duration, params.timestep)):
        trial.step()
        still_steps = still_steps + 1 if trial.hand.finger_speed() < params.settle_speed else 0
        if still_steps >= 3:
            break
    return trial.gripped()


def _moved(before: tuple[np.ndarray, np.ndarray], after: tuple[np.ndarray, np.ndarray],
           params: ChecksStageParams) -> bool:
    """Whether the object's pose in the hand changed beyond ``hold_still_distance`` / ``hold_still_rotation``."""
    if np.linalg.norm(after[0] - before[0]) >= params.hold_still_distance:
        return True
    turn = Rotation.from_quat(before[1]).inv() * Rotation.from_quat(after[1])
    return bool(turn.magnitude() >= params.hold_still_rotation)


def _lift(trial: _Trial) -> bool:
    """Gravity on, lift the hand and hold it still; whether the object is held.

    Every :data:`_HOLD_CHECK_INTERVAL` steps an object that is no longer
    gripped ends the lift or the hold as not held, and in the hold an object
    that has been still in the hand for ``hold_still_duration`` ends it
    early (a decision on simulated state alone).
    """
    pybullet = pybullet_module()
    params = trial.params
    pybullet.setGravity(0.0, 0.0, -params.gravity, physicsClientId=trial.client)
    lift_steps = _steps(params.lift_duration, params.timestep)
    for index in range(1, lift_steps + 1):
        # Smooth (cosine) profile: no jump in the hand's commanded velocity.
        fraction = (1 - np.cos(np.pi * index / lift_steps)) / 2
        trial.hand.move_to(np.array([0.0, 0.0, fraction * params.lift_height]), GRASP_QUATERNION_IN_WORLD)
        trial.step()
        if index % _HOLD_CHECK_INTERVAL == 0 and not trial.gripped():
            return False
    hold_steps = _steps(params.hold_duration, params.timestep) if params.hold_duration > 0 else 0
    still_steps = _steps(params.hold_still_duration, params.timestep) if params.hold_still_duration > 0 else 0
    # The object's pose in the hand when it was last seen moving, and the hold step of that test.
    anchor, anchor_index = (trial.object_in_hand(), 0) if still_steps and hold_steps else (None, 0)
    for index in range(1, hold_steps + 1):
        trial.step()
        if index % _HOLD_CHECK_INTERVAL:
            continue
        if not trial.gripped():
            return False
        if anchor is not None:
            pose = trial.object_in_hand()
            if _moved(anchor, pose, params):
                anchor, anchor_index = pose, index
            elif index - anchor_index >= still_steps:
                break
    return trial.held()


def _shake(trial: _Trial, rng: np.random.Generator) -> bool:
    """The six shakes about the lifted pose; whether the object is still held."""
    lifted_position = np.array([0.0, 0.0, trial.params.lift_height])
    for positions, quaternions in _shake_targets(lifted_position, GRASP_QUATERNION_IN_WORLD, trial.params, rng):
        for index, (position, quaternion) in enumerate(zip(positions, quaternions, strict=True), start=1):
            trial.hand.move_to(position, quaternion)
            trial.step()
            if index % _HOLD_CHECK_INTERVAL == 0 and not trial.gripped():
                return False
    trial.hand.move_to(lifted_position, GRASP_QUATERNION_IN_WORLD)
    return trial.held()


def trial_params(params: ChecksStageParams, mass: float) -> ChecksStageParams:
    """The parameters a trial of an object of ``mass`` kg runs with: a shorter step for a light one.

    With ``max_mass_ratio`` above 0 and the fingers more than that many
    times the object's mass, the step is divided by
    ``ceil(finger_mass / (max_mass_ratio * mass))``; every duration stays
    the same in seconds.
    """
    if params.max_mass_ratio <= 0 or mass <= 0:
        return params
    substeps = math.ceil(params.finger_mass / (params.max_mass_ratio * mass))
    return params if substeps <= 1 else params.model_copy(update={"timestep": params.timestep / substeps})


def run_trial(
    model: Mapping[str, Any],
    grasp_position: np.ndarray,
    grasp_quaternion: np.ndarray,
    width: float,
    params: ChecksStageParams,
    gripper: Gripper,
    rng: np.random.Generator,
    client: int | None = None,
    surface: np.ndarray | None = None,
) -> TrialResult:
    """Simulate one grasp of one model: both criteria in one trial.

    Parameters
    ----------
    model : mapping
        A ``models`` row (``Table.to_pylist()`` form).
    grasp_position : (3,) float
        Grasp centre (gripper-frame origin) in the object frame, m.
    grasp_quaternion : (4,) float
        Gripper frame in the object frame, (x, y, z, w).
    width : float
        Pre-grasp opening, m; clipped to the gripper's maximum.
    params : ChecksStageParams
    gripper : Gripper
        The hand to simulate.
    rng : numpy.random.Generator
        Draws the frame of the shake directions.
    client : int, optional
        pybullet client; this process's :func:`osgd.physics.process_client` by default.
    surface : (P, 3) float, optional
        The model's :func:`approach_surface` for ``approach_geometry =
        "mesh"`` (computed here when not given; pass it for many trials of
        one model).

    Returns
    -------
    TrialResult
        The ``lift`` outcome is decided after the hold; the shakes run only
        for grasps that pass it, and only where ``params.shakes``.
    """
    params = trial_params(params, float(model["mass"]))
    opening = float(np.clip(width, 0.0, gripper.max_opening))
    if params.approach_geometry == "mesh":
        if surface is None:
            surface = approach_surface(model, params)
        if approach_hits_surface(surface, np.asarray(grasp_position, dtype=np.float64),
                                 np.asarray(grasp_quaternion, dtype=np.float64), opening, params, gripper):
            # Decided by geometry: no world is built (the hand would stand fully open, no step simulated).
            return TrialResult(
                stable=False, lift_stable=False, shake_stable=False, fail_reason="approach_collision",
                slip_distance=0.0, slip_rotation=0.0, final_opening=float(gripper.max_opening), sim_steps=0,
            )
    client = process_client() if client is None else client
    _setup_world(client, params)
    hand = create_hand(
        client, gripper, palm_mass=params.palm_mass, finger_mass=params.finger_mass,
        finger_friction=params.finger_friction, constraint_force=params.hand_force, pad_contact=params.pad_contact,
    )
    body = _place_object(client, model, grasp_position, grasp_quaternion, params)
    trial = _Trial(client, hand, body, params)
    if params.approach_geometry != "mesh" and _approach_collides(trial, np.zeros(3), GRASP_QUATERNION_IN_WORLD,
                                                                 opening):
        return trial.result("approach_collision")
    hand.reset(np.zeros(3), GRASP_QUATERNION_IN_WORLD, opening)
    if not _close(trial, gripper.grip_force if params.grip_force is None else params.grip_force):
        return trial.result("empty_close")
    trial.reference = trial.object_in_hand()
    if not _lift(trial):
        return trial.result("slipped_on_lift")
    if not params.shakes:
        return trial.result("", shaken=False)
    if not _shake(trial, rng):
        return trial.result("dropped_on_shake")
    return trial.result("")
