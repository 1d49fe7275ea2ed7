"""From a lifted grasp to its execution among the whole pile, and its judgement.

The grasp is a top-down :class:`~togcrf.robot.lifting.GraspPose` lifted from the chosen rectangle
(:func:`togcrf.robot.lifting.lift_rectangle`).

Execution (:func:`execute`)
---------------------------
A fresh pybullet world (the checks stage's physics settings: time step,
solver iterations, contact ERP) holds the stack stage's floor and walls
and every object of the pile, dynamic, at its resting pose, with gravity;
the pile settles for ``settle_time``. The hand is the checks stage's
simulated gripper (:func:`osgd.simulation.create_hand`, from the one
:data:`osgd.simulation.PANDA`), pre-shaped to the opening above the pile, then:

1. **approach**: down at ``approach_speed`` to the grasp pose; a guarded
   move: it stops where the contact force on the hand passes
   ``stop_force`` (a finger on a neighbour, on the table, on the target);
   what it touches on the way is pushed, as a real hand would;
2. **close**: the checks stage's closing (force-limited at the gripper's
   grip force, until the fingers are still);
3. **lift**: ``lift_height`` in ``lift_duration`` (cosine profile), then
   **hold** still for ``hold_duration``.

Outcome: the objects between the pads after closing (both pads within
``contact_distance``; none: ``empty_close``; two when the pads closed on a
tool and its neighbour) are followed through the lift; the one held is
the one still between the pads after the hold that rose most, and it
counts when its centre of mass rose by at least ``min_rise``. Otherwise the simulation stops the moment the pads lose it
(tested every 8 steps): ``slipped`` when it had risen less than 1 cm (the
pads slid off at once: fingertips on an edge, a thin part), ``dropped``
when it fell from higher up; or ``pinned`` (still between the pads after
the hold but it did not rise: held down by another object).

Judgement (:func:`judge`)
-------------------------
GSR-S: an object is held whose category can do the task (for a tool task:
a category whose grasps carry that task; for "no task" and "hand over": the
named category). GSR-T: also the grasps stage's own label of the held pose
(the parts between the pads, :mod:`osgd.grasps.labels`) is the task; for a
model without part labels, the task of the nearest annotated grasp.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from osgd.simulation import (
    FINGER_A,
    FINGER_B,
    add_floor_and_walls,
    create_hand,
    create_object_body,
    get_mesh_pose,
    physics_client,
    pybullet_module,
)
from togcrf.robot.lifting import GraspPose, RobotParams
from togcrf.robot.observation import Observation
from togcrf.robot.pile import suitable_categories
from togcrf.robot.protocol import Trial
from togcrf.robot.world import World

log = logging.getLogger(__name__)

#: Why a trial failed, in the order its phases can fail ("" is a success).
REASONS: tuple[str, ...] = ("no_grasp", "no_depth", "empty_close", "slipped", "dropped", "pinned",
                            "wrong_object", "wrong_grasp")

#: An object that leaves the pads before rising this far (m) slipped out at once; higher up, it dropped.
_SLIP_RISE = 0.01

#: During the lift and hold, the grip is tested every this many steps.
_GRIP_CHECK_INTERVAL = 8


@dataclass
class Execution:
    """What happened when a grasp was executed.

    Attributes
    ----------
    grasp : GraspPose
    stopped : bool
        The guarded approach stopped before the grasp pose.
    stopped_by : str
        Category of what the hand touched hardest when it stopped ("floor", "" when not stopped).
    reached : float
        Height of the grasp centre where the approach ended, m.
    gripped : int
        Scene index of the object held (or the last one to leave the pads), -1 when the pads closed on nothing.
    held : bool
    rise : float
        Rise of the gripped object's centre of mass, m.
    lost : str
        ``""``, ``"empty_close"``, ``"dropped"`` or ``"pinned"``.
    label : str
        The grasps stage's label of the held pose ("" when nothing is gripped).
    nearest_task : str
        Task of the nearest annotated grasp of the gripped object.
    nearest_distance : float
    object_poses : list of (position (3,), quaternion (4,))
        Every object's mesh-frame pose at the end (the moment of failure).
    hand_pose : (position (3,), quaternion (4,))
        At the end.
    hand_opening : float
    steps : int
    """

    grasp: GraspPose
    stopped: bool = False
    stopped_by: str = ""
    reached: float = float("nan")
    gripped: int = -1
    held: bool = False
    rise: float = 0.0
    lost: str = ""
    label: str = ""
    nearest_task: str = ""
    nearest_distance: float = float("nan")
    object_poses: list = field(default_factory=list)
    hand_pose: tuple = ()
    hand_opening: float = 0.0
    steps: int = 0


class _Scene:
    """The pybullet world of one execution: floor, walls, pile and hand."""

    def __init__(self, client: int, world: World, scene: dict[str, Any], grasp: GraspPose) -> None:
        self.pybullet = pybullet_module()
        self.client = client
        self.checks = world.params("checks")
        self.steps = 0
        scenes = world.params("scenes")
        statics = add_floor_and_walls(client, scenes)
        self.names = {statics[0]: "floor", **{body: "wall" for body in statics[1:]}}
        self.objects = []
        for index, obj in enumerate(scene["objects"]):
            body = create_object_body(client, world.models[obj["model_id"]], np.asarray(obj["position"]),
                                      np.asarray(obj["quaternion"]), maximal_coordinates=scenes.maximal_coordinates)
            self.objects.append(body)
            self.names[body.body_id] = f"{obj['category']}#{index}"
        checks = self.checks
        self.grip_force = world.gripper.grip_force if checks.grip_force is None else checks.grip_force
        self.hand = create_hand(client, world.gripper, palm_mass=checks.palm_mass, finger_mass=checks.finger_mass,
                                finger_friction=checks.finger_friction, constraint_force=checks.hand_force,
                                pad_contact=checks.pad_contact)
        # Out of the way while the pile settles.
        self.hand.reset(grasp.position + np.array([0.0, 0.0, 1.0]), grasp.quaternion, grasp.opening)

    def step(self, count: int = 1) -> None:
        for _ in range(count):
            self.pybullet.stepSimulation(physicsClientId=self.client)
            self.steps += 1

    def seconds(self, duration: float) -> int:
        return max(1, round(duration / self.checks.timestep))

    def pile_top(self) -> float:
        return max(self.pybullet.getAABB(body.body_id, physicsClientId=self.client)[1][2] for body in self.objects)

    def hand_contact(self) -> tuple[float, str]:
        """Total normal force on the hand, and the body pushing hardest."""
        forces: dict[int, float] = {}
        for point in self.pybullet.getContactPoints(bodyA=self.hand.body_id, physicsClientId=self.client):
            forces[point[2]] = forces.get(point[2], 0.0) + point[9]
        if not forces:
            return 0.0, ""
        hardest = max(forces, key=forces.get)
        return sum(forces.values()), self.names.get(hardest, str(hardest))

    def touching(self, finger: int, body: int) -> bool:
        return bool(self.pybullet.getClosestPoints(self.hand.body_id, body, self.checks.contact_distance,
                                                   linkIndexA=finger, physicsClientId=self.client))

    def between_pads(self, candidates: list[int] | None = None) -> list[int]:
        """Indices of the objects (of ``candidates``, default all) both pads touch, in scene order."""
        if self.hand.opening() < self.checks.min_opening:
            return []
        indices = range(len(self.objects)) if candidates is None else candidates
        return [index for index in indices if self.touching(FINGER_A, self.objects[index].body_id)
                and self.touching(FINGER_B, self.objects[index].body_id)]

    def com_height(self, index: int) -> float:
        position, _ = self.pybullet.getBasePositionAndOrientation(self.objects[index].body_id,
                                                                  physicsClientId=self.client)
        return float(position[2])


def _approach(scene: _Scene, grasp: GraspPose, params: RobotParams, outcome: Execution) -> None:
    """The guarded move from above the pile down to the grasp pose."""
    gripper = scene.hand.gripper
    start = max(grasp.position[2] + params.approach_height, scene.pile_top() + gripper.finger_depth / 2 + 0.02)
    quaternion = grasp.quaternion
    scene.hand.reset(np.array([grasp.position[0], grasp.position[1], start]), quaternion, grasp.opening)
    per_step = params.approach_speed * scene.checks.timestep
    count = math.ceil((start - grasp.position[2]) / per_step)
    for index in range(1, count + 1):
        height = max(grasp.position[2], start - index * per_step)
        scene.hand.move_to(np.array([grasp.position[0], grasp.position[1], height]), quaternion)
        scene.step()
        force, body = scene.hand_contact()
        if force > params.stop_force:
            outcome.stopped, outcome.stopped_by = True, body.split("#")[0]
            scene.hand.move_to(scene.hand.pose()[0], quaternion)
            break
    scene.step(scene.seconds(0.05))
    outcome.reached = float(scene.hand.pose()[0][2])


def _close(scene: _Scene) -> None:
    """The checks stage's closing: force-limited until the fingers are still."""
    checks = scene.checks
    scene.hand.close_fingers(checks.close_speed, scene.grip_force)
    still = 0
    for _ in range(scene.seconds(checks.close_duration)):
        scene.step()
        still = still + 1 if scene.hand.finger_speed() < checks.settle_speed else 0
        if still >= 3:
            break


def _lift(scene: _Scene, params: RobotParams, gripped: list[int]) -> tuple[list[int], dict[int, float], int]:
    """Lift and hold; stops when no object is left between the pads.

    Parameters
    ----------
    gripped : list of int
        The objects between the pads after closing (usually one; two when
        the pads closed on a tool and its neighbour).

    Returns
    -------
    between : list of int
        Those still between the pads at the end.
    rises : dict of int to float
        Rise of each one's centre of mass at the end, or when it left the pads, m.
    last : int
        The last one to leave the pads (meaningful when ``between`` is empty).
    """
    position, quaternion = scene.hand.pose()
    before = {index: scene.com_height(index) for index in gripped}
    rises = dict.fromkeys(gripped, 0.0)
    between, last = list(gripped), gripped[0]
    lift = scene.seconds(params.lift_duration)
    for step in range(1, lift + scene.seconds(params.hold_duration) + 1):
        fraction = (1 - math.cos(math.pi * min(step, lift) / lift)) / 2
        scene.hand.move_to(position + np.array([0.0, 0.0, fraction * params.lift_height]), quaternion)
        scene.step()
        if step % _GRIP_CHECK_INTERVAL == 0:
            rises.update({index: scene.com_height(index) - before[index] for index in between})
            last, between = between[0], scene.between_pads(between)
            if not between:
                return between, rises, last
    between = scene.between_pads(between)
    rises.update({index: scene.com_height(index) - before[index] for index in between})
    return between, rises, last


def _record_hold(world: World, scene: _Scene, model_id: str, outcome: Execution) -> None:
    """The grasps stage's label of the held pose, and the nearest annotated grasp."""
    object_position, object_quaternion = get_mesh_pose(scene.objects[outcome.gripped])
    hand_position, hand_quaternion = scene.hand.pose()
    inverse = Rotation.from_quat(object_quaternion).inv()
    position = inverse.apply(hand_position - object_position)
    rotation = (inverse * Rotation.from_quat(hand_quaternion)).as_matrix()
    outcome.label = world.grasp_label(model_id, position, rotation, scene.hand.opening())
    outcome.nearest_task, outcome.nearest_distance = world.nearest_grasp(model_id, position, rotation[:, 0])


def _finish(scene: _Scene, outcome: Execution) -> Execution:
    outcome.object_poses = [get_mesh_pose(body) for body in scene.objects]
    outcome.hand_pose = scene.hand.pose()
    outcome.hand_opening = scene.hand.opening()
    outcome.steps = scene.steps
    return outcome


def execute(world: World, scene_row: dict[str, Any], grasp: GraspPose, params: RobotParams) -> Execution:
    """Execute a grasp among the whole pile (see the module text).

    Parameters
    ----------
    world : World
    scene_row : dict
        The pile, a ``scenes`` row.
    grasp : GraspPose
    params : RobotParams

    Returns
    -------
    Execution
    """
    checks = world.params("checks")
    outcome = Execution(grasp)
    with physics_client(timestep=checks.timestep, gravity=-checks.gravity) as client:
        scene = _Scene(client, world, scene_row, grasp)
        scene.pybullet.setPhysicsEngineParameter(numSolverIterations=checks.solver_iterations,
                                                 deterministicOverlappingPairs=1, physicsClientId=client)
        if checks.contact_erp is not None:
            scene.pybullet.setPhysicsEngineParameter(contactERP=checks.contact_erp, physicsClientId=client)
        scene.step(scene.seconds(params.settle_time))
        _approach(scene, grasp, params, outcome)
        _close(scene)
        gripped = scene.between_pads()
        if not gripped:
            outcome.lost = "empty_close"
            return _finish(scene, outcome)
        between, rises, last = _lift(scene, params, gripped)
        outcome.gripped = max(between, key=rises.get) if between else last
        outcome.rise = rises[outcome.gripped]
        outcome.held = bool(between) and outcome.rise >= params.min_rise
        if not between:
            outcome.lost = "slipped" if outcome.rise < _SLIP_RISE else "dropped"
        elif not outcome.held:
            outcome.lost = "pinned"
        if between:
            _record_hold(world, scene, scene_row["objects"][outcome.gripped]["model_id"], outcome)
        return _finish(scene, outcome)


@dataclass(frozen=True)
class Verdict:
    """A trial's outcome.

    Attributes
    ----------
    gsr_s, gsr_t : bool
    reason : str
        ``""`` or one of :data:`REASONS`.
    judged_by : str
        ``"parts"`` (the grasps stage's rule) or ``"nearest"`` (the nearest annotated grasp), "" when nothing was held.
    """

    gsr_s: bool
    gsr_t: bool
    reason: str
    judged_by: str = ""


def judge(world: World, trial: Trial, observation: Observation, execution: Execution | None,
          no_grasp_reason: str = "") -> Verdict:
    """GSR-S and GSR-T of a trial (see the module text).

    Parameters
    ----------
    world : World
    trial : Trial
    observation : Observation
    execution : Execution or None
        None when no grasp was executed.
    no_grasp_reason : str
        ``"no_grasp"`` or ``"no_depth"`` when ``execution`` is None.
    """
    if execution is None:
        return Verdict(False, False, no_grasp_reason or "no_grasp")
    if execution.lost:
        return Verdict(False, False, execution.lost)
    obj = observation.scene["objects"][execution.gripped]
    if obj["category"] not in suitable_categories(world, trial):
        return Verdict(False, False, "wrong_object")
    model = world.models[obj["model_id"]]
    has_parts = bool(np.any(np.asarray(model["face_parts"]) >= 0))
    label = execution.label if has_parts else execution.nearest_task
    judged_by = "parts" if has_parts else "nearest"
    if label != trial.task:
        return Verdict(True, False, "wrong_grasp", judged_by)
    return Verdict(True, True, "", judged_by)
