"""Where the depth camera stands: a pose above the pile, drawn per sample.

Frames
------
World: ``z`` up, the floor (table top) at ``z = 0`` (as the scenes stage
writes it). Camera: OpenCV (``x`` right, ``y`` down, ``z`` forward;
:mod:`osgd.camera`). A :class:`CameraPose` is the camera frame in the world
frame: ``rotation`` has the camera axes as columns, expressed in world
coordinates, so ``p_world = rotation @ p_camera + position``.

The draw
--------
The camera looks at an aim point (by default the centre of the objects'
mesh-frame origins, projected onto the floor) from ``height`` metres above
the floor. Its optical axis leans away from straight down by a tilt drawn
uniformly in ``[0, max_tilt]`` towards a uniformly random azimuth, and the
image turns about the optical axis by a yaw drawn uniformly in
``[-max_yaw, max_yaw]``. The paper's Kinect v2 looked down at a workbench
(section V); the tilt and yaw ranges are our choice: they vary the view a
little without making grasps on the table leave the image plane.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


@dataclass(frozen=True)
class CameraPose:
    """The camera (OpenCV) frame in the world frame.

    Attributes
    ----------
    position : (3,) float64
        Camera origin in the world, metres.
    rotation : (3, 3) float64
        Columns: the camera ``x``, ``y``, ``z`` axes in world coordinates.
    """

    position: np.ndarray
    rotation: np.ndarray

    @property
    def quaternion(self) -> np.ndarray:
        """The rotation as ``(x, y, z, w)``, float64 (4,)."""
        return Rotation.from_matrix(self.rotation).as_quat()

    @classmethod
    def from_quaternion(cls, position: np.ndarray, quaternion: np.ndarray) -> CameraPose:
        """Build from a position (3,) and an ``(x, y, z, w)`` quaternion (4,)."""
        return cls(
            np.asarray(position, dtype=np.float64),
            Rotation.from_quat(np.asarray(quaternion, dtype=np.float64)).as_matrix(),
        )

    def world_to_camera(self, points_world: np.ndarray) -> np.ndarray:
        """Express world points (N, 3) in the camera frame; (N, 3) float64."""
        points = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
        return (points - self.position) @ self.rotation

    def camera_to_world(self, points_camera: np.ndarray) -> np.ndarray:
        """Express camera-frame points (N, 3) in the world frame; (N, 3) float64."""
        points = np.asarray(points_camera, dtype=np.float64).reshape(-1, 3)
        return points @ self.rotation.T + self.position


def look_at(position: np.ndarray, target: np.ndarray, image_right: np.ndarray) -> CameraPose:
    """A camera at ``position`` whose optical axis passes through ``target``.

    Parameters
    ----------
    position, target : (3,) float
        World frame, metres; distinct.
    image_right : (3,) float
        A world direction the image ``x`` axis should follow as closely as
        possible; not parallel to the optical axis.

    Returns
    -------
    CameraPose
    """
    forward = np.asarray(target, dtype=np.float64) - np.asarray(position, dtype=np.float64)
    forward /= np.linalg.norm(forward)
    right = np.asarray(image_right, dtype=np.float64) - np.dot(image_right, forward) * forward
    norm = np.linalg.norm(right)
    if norm < 1e-9:
        raise ValueError("image_right is parallel to the optical axis")
    right /= norm
    down = np.cross(forward, right)
    return CameraPose(np.asarray(position, dtype=np.float64), np.stack([right, down, forward], axis=1))


def draw_camera_pose(
    rng: np.random.Generator,
    aim_point: np.ndarray,
    height: float,
    max_tilt: float,
    max_yaw: float,
) -> CameraPose:
    """Draw a camera pose looking down at ``aim_point``.

    Parameters
    ----------
    rng : numpy.random.Generator
        Draws tilt, its azimuth and yaw, in that order.
    aim_point : (3,) float
        World point on the optical axis, metres.
    height : float
        Camera height above the floor (world ``z``), metres; above the aim
        point.
    max_tilt : float
        Largest angle between the optical axis and straight down, radians.
    max_yaw : float
        Largest turn of the image about the optical axis, radians.

    Returns
    -------
    CameraPose
    """
    aim = np.asarray(aim_point, dtype=np.float64)
    if height <= aim[2]:
        raise ValueError(f"camera height {height} m is not above the aim point (z = {aim[2]:.3f} m)")
    tilt = rng.uniform(0.0, max_tilt)
    azimuth = rng.uniform(-np.pi, np.pi)
    yaw = rng.uniform(-max_yaw, max_yaw)
    # Unit vector from the aim point up to the camera.
    up_to_camera = np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), np.cos(tilt)])
    position = aim + up_to_camera * (height - aim[2]) / up_to_camera[2]
    # With no yaw the image x axis follows world x (image y then follows
    # world -y when looking straight down).
    image_right = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    return look_at(position, aim, image_right)
