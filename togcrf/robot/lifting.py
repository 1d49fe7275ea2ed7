"""From a rectangle in the depth image to a top-down grasp in the world (:func:`lift_rectangle`).

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

:class:`RobotParams` holds how the robot lifts a rectangle and how it then
executes the grasp (:mod:`togcrf.robot.execute`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from osgd.simulation import Gripper
from togcrf.robot.observation import Observation


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
