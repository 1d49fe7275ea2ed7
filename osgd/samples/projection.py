"""3-D grasps seen by the camera: frames, filters and 5-D rectangles.

Rectangle convention (also in ``osgd.contract.schemas.SAMPLES``)
-------------------------------------------------------
``(x, y, h, w, theta)`` in pixels and radians, image ``x`` to the right and
``y`` down (OpenCV, :mod:`osgd.camera`):

- ``x, y``: the projection of the grasp centre;
- ``h``: the projected opening: the distance in pixels between the
  projections of the two points ``width / 2`` either side of the centre
  along the closing axis (the paper's "h = gripper opening");
- ``w``: the projected finger width: ``finger_width * f / Z`` at the
  centre's depth ``Z`` (the paper's "w = finger width");
- ``theta``: the angle of the closing direction (finger A to finger B,
  which is the same line as B to A) to the image ``x`` axis, in
  ``[-pi/2, pi/2)``; positive turns from ``x`` towards ``y`` (clockwise on
  screen, as ``atan2(dy, dx)`` in image coordinates).

Filters (paper section IV-A, REFERENCE section 2)
-------------------------------------------------
A grasp is kept when its closing direction makes at least 45 degrees with
the optical axis (otherwise the rectangle says little about the grasp), its
contacts are seen (the rendered depth at each contact's pixel is not more
than a tolerance in front of the contact) and its centre projects into the
image; then non-maximum suppression on the 3-D grasp centres keeps, within
each radius, the grasp whose closing direction is most parallel to the
image plane.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from osgd.camera import CameraIntrinsics


@dataclass(frozen=True)
class GraspSet:
    """Grasps of one object in one frame (the frame is the holder's business).

    Attributes
    ----------
    grasp_ids : (G,) int64
    tasks : (G,) object
        Task names.
    positions : (G, 3) float64
        Grasp centres, metres.
    rotations : (G, 3, 3) float64
        Gripper frames (columns: closing ``x``, ``y``, approach ``z``).
    widths : (G,) float64
        Pre-grasp openings, metres.
    contacts_a, contacts_b : (G, 3) float64
        Contact points, metres.
    """

    grasp_ids: np.ndarray
    tasks: np.ndarray
    positions: np.ndarray
    rotations: np.ndarray
    widths: np.ndarray
    contacts_a: np.ndarray
    contacts_b: np.ndarray

    def __len__(self) -> int:
        return len(self.grasp_ids)

    def transformed(self, rotation: np.ndarray, translation: np.ndarray) -> GraspSet:
        """The same grasps after the rigid motion ``p -> rotation @ p + translation``."""
        rotation = np.asarray(rotation, dtype=np.float64)
        translation = np.asarray(translation, dtype=np.float64)
        return GraspSet(
            self.grasp_ids,
            self.tasks,
            self.positions @ rotation.T + translation,
            np.einsum("ij,gjk->gik", rotation, self.rotations),
            self.widths,
            self.contacts_a @ rotation.T + translation,
            self.contacts_b @ rotation.T + translation,
        )

    def subset(self, keep: np.ndarray) -> GraspSet:
        """The grasps selected by a boolean mask or index array."""
        return GraspSet(*(getattr(self, name)[keep] for name in (
            "grasp_ids", "tasks", "positions", "rotations", "widths", "contacts_a", "contacts_b")))

    @property
    def quaternions(self) -> np.ndarray:
        """Gripper orientations as ``(x, y, z, w)``, (G, 4) float64."""
        if not len(self):
            return np.zeros((0, 4))
        return Rotation.from_matrix(self.rotations).as_quat()

    @property
    def closing(self) -> np.ndarray:
        """Closing directions (gripper ``x`` axes), (G, 3) float64, unit."""
        return self.rotations[:, :, 0]


def grasp_set_from_rows(rows: list[dict]) -> GraspSet:
    """Build a :class:`GraspSet` from ``grasps`` table rows (dicts), object frame."""
    if not rows:
        empty3 = np.zeros((0, 3))
        return GraspSet(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=object), empty3, np.zeros((0, 3, 3)),
                        np.zeros(0), empty3, empty3)
    quaternions = np.array([row["quaternion"] for row in rows], dtype=np.float64)
    return GraspSet(
        grasp_ids=np.array([row["grasp_id"] for row in rows], dtype=np.int64),
        tasks=np.array([row["task"] for row in rows], dtype=object),
        positions=np.array([row["position"] for row in rows], dtype=np.float64),
        rotations=Rotation.from_quat(quaternions).as_matrix(),
        widths=np.array([row["width"] for row in rows], dtype=np.float64),
        contacts_a=np.array([row["contact_a"] for row in rows], dtype=np.float64),
        contacts_b=np.array([row["contact_b"] for row in rows], dtype=np.float64),
    )


def angle_to_optical_axis(closing_camera: np.ndarray) -> np.ndarray:
    """Angle between each closing line and the optical axis, in [0, pi/2].

    Parameters
    ----------
    closing_camera : (G, 3) float
        Closing directions in the camera frame (unit).

    Returns
    -------
    (G,) float64, radians
    """
    cosine = np.abs(np.asarray(closing_camera, dtype=np.float64).reshape(-1, 3)[:, 2])
    return np.arccos(np.clip(cosine, 0.0, 1.0))


def grasp_rectangles(grasps_camera: GraspSet, intrinsics: CameraIntrinsics, finger_width: float) -> np.ndarray:
    """Project camera-frame grasps to 5-D rectangles (see the module docstring).

    Parameters
    ----------
    grasps_camera : GraspSet
        In the camera frame; every centre and finger point in front of the
        camera.
    intrinsics : CameraIntrinsics
    finger_width : float
        The gripper's finger width, metres (``osgd.gripper.Gripper``).

    Returns
    -------
    (G, 5) float64
        ``x, y, h, w, theta``.
    """
    if not len(grasps_camera):
        return np.zeros((0, 5))
    half = grasps_camera.closing * (grasps_camera.widths / 2)[:, None]
    centre = intrinsics.project(grasps_camera.positions)
    finger_a = intrinsics.project(grasps_camera.positions - half)
    finger_b = intrinsics.project(grasps_camera.positions + half)
    delta = finger_b - finger_a
    opening = np.hypot(delta[:, 0], delta[:, 1])
    focal = (intrinsics.fx + intrinsics.fy) / 2
    finger = finger_width * focal / grasps_camera.positions[:, 2]
    theta = wrap_half_turn(np.arctan2(delta[:, 1], delta[:, 0]))
    return np.stack([centre[:, 0], centre[:, 1], opening, finger, theta], axis=1)


def wrap_half_turn(angle: np.ndarray) -> np.ndarray:
    """Map line angles (radians) into ``[-pi/2, pi/2)``: a line has no direction."""
    return (np.asarray(angle, dtype=np.float64) + np.pi / 2) % np.pi - np.pi / 2


def contacts_visible(
    grasps_camera: GraspSet,
    depth: np.ndarray,
    mask: np.ndarray,
    label: int,
    intrinsics: CameraIntrinsics,
    tolerance: float,
) -> np.ndarray:
    """Whether neither contact of each grasp is hidden behind another object.

    A contact is hidden when it projects outside the image, or when its
    (nearest) pixel shows another object (mask value neither 0 nor
    ``label``) more than ``tolerance`` in front of the contact. The grasped
    object itself hides nothing: a contact on the far side of a tall object
    is normal for a grasp from the side, and the gripper reaches it in 3-D.

    Parameters
    ----------
    grasps_camera : GraspSet
        Camera frame.
    depth : (H, W) float
        Clean rendered depth, metres.
    mask : (H, W) int
        Instance mask, 0 background, ``object_index + 1`` elsewhere.
    label : int
        Mask value of the grasped object.
    tolerance : float
        Metres.

    Returns
    -------
    (G,) bool
    """
    height, width = depth.shape

    def seen(points: np.ndarray) -> np.ndarray:
        if not len(points):
            return np.zeros(0, dtype=bool)
        in_front = points[:, 2] > 1e-6
        pixels = np.rint(intrinsics.project(np.where(in_front[:, None], points, 1.0))).astype(np.int64)
        inside = in_front & (pixels[:, 0] >= 0) & (pixels[:, 0] < width) & (pixels[:, 1] >= 0) & (pixels[:, 1] < height)
        rows, columns = pixels[inside, 1], pixels[inside, 0]
        covered = np.zeros(len(points), dtype=bool)
        covered[inside] = (
            (mask[rows, columns] != 0)
            & (mask[rows, columns] != label)
            & (depth[rows, columns] < points[inside, 2] - tolerance)
        )
        return inside & ~covered

    return seen(grasps_camera.contacts_a) & seen(grasps_camera.contacts_b)


def centres_in_image(grasps_camera: GraspSet, intrinsics: CameraIntrinsics) -> np.ndarray:
    """Whether each grasp centre is in front of the camera and inside the image; (G,) bool."""
    positions = grasps_camera.positions
    in_front = positions[:, 2] > 1e-6
    pixels = intrinsics.project(np.where(in_front[:, None], positions, 1.0))
    return (
        in_front
        & (pixels[:, 0] >= -0.5) & (pixels[:, 0] < intrinsics.width - 0.5)
        & (pixels[:, 1] >= -0.5) & (pixels[:, 1] < intrinsics.height - 0.5)
    )


def suppress(
    centres: np.ndarray,
    angles: np.ndarray,
    radius: float,
    accept: Callable[[int], bool] | None = None,
) -> np.ndarray:
    """Greedy non-maximum suppression on grasp centres.

    Candidates are visited from the closing direction most parallel to the
    image plane (largest angle to the optical axis) down, ties broken by
    input order; a candidate within ``radius`` of a kept grasp is
    suppressed. ``accept`` (e.g. a gripper collision test) is asked only
    about candidates that survive suppression, and a rejected candidate
    suppresses nothing, so the expensive test runs as rarely as possible and
    a colliding grasp never hides a free one.

    Parameters
    ----------
    centres : (G, 3) float
        Metres, any one frame.
    angles : (G,) float
        Angle of each closing line to the optical axis, radians.
    radius : float
        Metres; 0 keeps every accepted grasp.
    accept : callable(index) -> bool, optional

    Returns
    -------
    (K,) int64
        Indices of the kept grasps, in the order visited.
    """
    order = np.argsort(-np.asarray(angles, dtype=np.float64), kind="stable")
    centres = np.asarray(centres, dtype=np.float64)
    suppressed = np.zeros(len(centres), dtype=bool)  # within radius of a kept grasp
    kept: list[int] = []
    for index in order:
        if suppressed[index] or (accept is not None and not accept(int(index))):
            continue
        kept.append(int(index))
        if radius > 0:
            suppressed |= np.linalg.norm(centres - centres[index], axis=1) < radius
    return np.asarray(kept, dtype=np.int64)


def rectangle_corners(rectangles: np.ndarray) -> np.ndarray:
    """The four corners of each rectangle, in the OSGD text format's order.

    ``p0 -> p1`` is a finger plate edge (length ``w``, across the closing
    direction) and ``p1 -> p2`` runs along the closing direction (length
    ``h``), as the original OSGD files (REFERENCE section 2).

    Parameters
    ----------
    rectangles : (G, 5) float
        ``x, y, h, w, theta``.

    Returns
    -------
    (G, 4, 2) float64
        Pixel ``(x, y)`` of ``p0, p1, p2, p3``.
    """
    rectangles = np.asarray(rectangles, dtype=np.float64).reshape(-1, 5)
    x, y, h, w, theta = rectangles.T
    along = np.stack([np.cos(theta), np.sin(theta)], axis=1)  # closing direction
    across = np.stack([-np.sin(theta), np.cos(theta)], axis=1)
    centre = np.stack([x, y], axis=1)
    half_h = (h / 2)[:, None] * along
    half_w = (w / 2)[:, None] * across
    p0 = centre - half_h - half_w
    p1 = centre - half_h + half_w
    p2 = centre + half_h + half_w
    p3 = centre + half_h - half_w
    return np.stack([p0, p1, p2, p3], axis=1)


def rectangles_from_corners(corners: np.ndarray) -> np.ndarray:
    """Invert :func:`rectangle_corners`: (G, 4, 2) corners to (G, 5) rectangles."""
    corners = np.asarray(corners, dtype=np.float64).reshape(-1, 4, 2)
    centre = corners.mean(axis=1)
    plate = corners[:, 1] - corners[:, 0]
    closing = corners[:, 2] - corners[:, 1]
    h = np.hypot(closing[:, 0], closing[:, 1])
    w = np.hypot(plate[:, 0], plate[:, 1])
    theta = wrap_half_turn(np.arctan2(closing[:, 1], closing[:, 0]))
    return np.stack([centre[:, 0], centre[:, 1], h, w, theta], axis=1)
