"""From a rectangle to a grasp executed among the whole pile, and its judgement.

Lifting (:func:`lift_rectangle`)
--------------------------------
The approach is **top-down along the table normal** (world ``-z``), the
usual pick of a planar grasp detector over a workbench; the camera leans at
most ``max_tilt`` (10 degrees) from it. The rectangle's centre is
back-projected with the median depth reading within ``surface_radius``
pixels of it: the surface the camera sees there. Its two jaw ends are
back-projected at that depth; the closing axis is the horizontal part of
the line between them and the pre-grasp opening their distance (the
rectangle's ``h`` is the annotated pre-grasp opening, docs/samples.md)
plus ``extra_opening``, clipped to the gripper's maximum. The fingertips
are sent ``grasp_depth`` below the seen surface, but never lower than
``tip_clearance`` above the table.

Execution (:func:`execute`)
---------------------------
A fresh pybullet world (the checks stage's physics settings: time step,
solver iterations, contact ERP) holds the stack stage's floor and walls
and every object of the pile, dynamic, at its resting pose, with gravity;
the pile settles for ``settle_time``. The hand is the checks stage's
simulated gripper (:func:`osgd.checks.hand.create_hand`, from the one
:data:`osgd.gripper.PANDA`), pre-shaped to the opening above the pile, then:

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

from osgd.gripper import Gripper
from togcrf.robot.pile import Observation, suitable_categories
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


@dataclass(frozen=True)
class RobotParams:
    """How the robot lifts and executes a rectangle; lengths in m, times in s, forces in N.

    The physics (time step, solver, contact ERP, hand masses and forces,
    closing) is the checks stage's ``[checks]`` section of the pipeline.

    Attributes
    ----------
    surface_radius : float
        Pixels around the rectangle's centre whose median depth is the surface.
    extra_opening : float
        Added to the rectangle's opening for the pre-grasp.
    grasp_depth : float
        How far below the seen surface the fingertips go.
    tip_clearance : float
        The fingertips stay at least this far above the table.
    settle_time : float
        The pile settles this long in the execution's world before the hand comes.
    approach_height : float
        The approach starts this far above the grasp (and above the pile).
    approach_speed : float
    stop_force : float
        The guarded approach stops when the contact force on the hand passes this.
    lift_height, lift_duration, hold_duration : float
    min_rise : float
        A held object's centre of mass must rise this much.
    """

    surface_radius: float = 3.0
    extra_opening: float = 0.02
    grasp_depth: float = 0.025
    tip_clearance: float = 0.002
    settle_time: float = 0.1
    approach_height: float = 0.10
    approach_speed: float = 0.15
    stop_force: float = 30.0
    lift_height: float = 0.15
    lift_duration: float = 1.0
    hold_duration: float = 1.0
    min_rise: float = 0.05


@dataclass(frozen=True)
class GraspPose:
    """A top-down grasp in the world.

    Attributes
    ----------
    position : (3,) float64
        Grasp centre (gripper origin, mid-way down the pads), world, m.
    rotation : (3, 3) float64
        Gripper frame in the world (columns: closing, across, approach = -z).
    opening : float
        Pre-grasp opening, m.
    surface : (3,) float64
        The seen surface point under the rectangle's centre, world, m.
    """

    position: np.ndarray
    rotation: np.ndarray
    opening: float
    surface: np.ndarray

    @property
    def quaternion(self) -> np.ndarray:
        """The rotation as (x, y, z, w)."""
        return Rotation.from_matrix(self.rotation).as_quat()


def surface_depth(depth: np.ndarray, x: float, y: float, radius: float) -> float | None:
    """Median depth reading within ``radius`` px of a pixel; None when there is none."""
    height, width = depth.shape
    low_x, high_x = max(0, math.floor(x - radius)), min(width, math.ceil(x + radius) + 1)
    low_y, high_y = max(0, math.floor(y - radius)), min(height, math.ceil(y + radius) + 1)
    if low_x >= high_x or low_y >= high_y:
        return None
    rows, columns = np.mgrid[low_y:high_y, low_x:high_x]
    window = depth[low_y:high_y, low_x:high_x]
    near = ((columns - x) ** 2 + (rows - y) ** 2 <= radius**2) & (window > 0)
    return float(np.median(window[near])) if near.any() else None


def lift_rectangle(rectangle: np.ndarray, observation: Observation, gripper: Gripper,
                   params: RobotParams) -> GraspPose | None:
    """The top-down world grasp of a rectangle (see the module text); None without a depth reading."""
    x, y, h, _, theta = (float(value) for value in rectangle)
    depth = surface_depth(observation.depth, x, y, params.surface_radius)
    if depth is None:
        return None
    intrinsics, pose = observation.intrinsics, observation.pose
    along = np.array([math.cos(theta), math.sin(theta)]) * h / 2
    centre_pixel = np.array([x, y])
    pixels = np.array([centre_pixel, centre_pixel - along, centre_pixel + along])
    camera = np.column_stack([(pixels[:, 0] - intrinsics.cx) / intrinsics.fx * depth,
                              (pixels[:, 1] - intrinsics.cy) / intrinsics.fy * depth, np.full(3, depth)])
    centre, end_a, end_b = pose.camera_to_world(camera)
    closing = end_b - end_a
    closing[2] = 0.0
    norm = float(np.linalg.norm(closing))
    closing = closing / norm if norm > 1e-9 else pose.rotation[:, 0] * np.array([1.0, 1.0, 0.0])
    closing /= np.linalg.norm(closing)
    approach = np.array([0.0, 0.0, -1.0])
    rotation = np.column_stack([closing, np.cross(approach, closing), approach])
    tip = max(centre[2] - params.grasp_depth, params.tip_clearance)
    position = np.array([centre[0], centre[1], tip + gripper.finger_depth / 2])
    opening = float(np.clip(np.linalg.norm(end_b - end_a) + params.extra_opening, 0.0, gripper.max_opening))
    return GraspPose(position, rotation, opening, centre)


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
        from osgd.checks.hand import create_hand  # noqa: PLC0415
        from osgd.physics import create_object_body, pybullet_module  # noqa: PLC0415
        from osgd.scenes.drop import build_world  # noqa: PLC0415

        self.pybullet = pybullet_module()
        self.client = client
        self.checks = world.params("checks")
        self.steps = 0
        scenes = world.params("scenes")
        statics = build_world(client, scenes)
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
        from osgd.checks.hand import FINGER_A, FINGER_B  # noqa: PLC0415

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
    from osgd.physics import get_mesh_pose  # noqa: PLC0415

    object_position, object_quaternion = get_mesh_pose(scene.objects[outcome.gripped])
    hand_position, hand_quaternion = scene.hand.pose()
    inverse = Rotation.from_quat(object_quaternion).inv()
    position = inverse.apply(hand_position - object_position)
    rotation = (inverse * Rotation.from_quat(hand_quaternion)).as_matrix()
    outcome.label = world.grasp_label(model_id, position, rotation, scene.hand.opening())
    outcome.nearest_task, outcome.nearest_distance = world.nearest_grasp(model_id, position, rotation[:, 0])


def _finish(scene: _Scene, outcome: Execution) -> Execution:
    from osgd.physics import get_mesh_pose  # noqa: PLC0415

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
    from osgd.physics import physics_client  # noqa: PLC0415

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
