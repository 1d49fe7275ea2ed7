"""Geometry of grasps on one object: frames, surface samples, collisions.

Everything here is in the object frame, metres, and uses the gripper frame
of :mod:`osgd.gripper` (x closing axis from finger A to finger B, z approach
from the palm towards the object, y = z x x).

Collision test
--------------
python-fcl is not available, so a gripper pose collides with the object when
either

1. a sample of the object's surface lies deeper than ``margin`` inside one
   of the gripper's boxes (``Gripper.boxes``). The samples are every vertex
   plus random points, one per ``spacing**2`` of area, so any corner and any
   piece of surface larger than about ``spacing`` that enters a box deeper
   than ``margin`` is found; or
2. the centre of a box lies deeper than ``margin`` inside one of the model's
   convex parts (the collision compound the check stage simulates), which
   catches a box buried in the object with no surface crossing it.

The tolerance is therefore ``margin`` of penetration (pads resting on the
surface at the contacts are not a collision) and features thinner than about
``spacing`` that cross a box between samples. Defaults (``GraspsStageParams``):
margin 1 mm, spacing 2 mm; the finger boxes are 10 mm thick and 20 mm wide,
so a sheet of any thickness crossing a finger leaves tens of samples inside.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from osgd.gripper import Gripper


def unit(vectors: np.ndarray) -> np.ndarray:
    """Vectors scaled to length 1 along the last axis (zero stays zero)."""
    norms = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return np.divide(vectors, norms, out=np.zeros_like(vectors, dtype=np.float64), where=norms > 0)


def perpendicular_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``u, v`` with ``(axis, u, v)`` right-handed orthonormal.

    ``u`` is the object axis least aligned with ``axis``, made perpendicular,
    so the basis depends only on ``axis`` (deterministic approach angles).

    Parameters
    ----------
    axis : (3,) float
        Unit vector.
    """
    reference = np.eye(3)[int(np.argmin(np.abs(axis)))]
    u = unit(reference - np.dot(reference, axis) * axis)
    v = np.cross(axis, u)
    return u, v


def approach_directions(closing_axis: np.ndarray, count: int, start_angle: float = 0.0) -> np.ndarray:
    """``count`` approach directions evenly spaced around the closing axis.

    Parameters
    ----------
    closing_axis : (3,) float
        Unit vector, object frame.
    count : int
    start_angle : float
        Angle of the first direction from :func:`perpendicular_basis`'s
        ``u``, radians.

    Returns
    -------
    (count, 3) float64
        Unit vectors perpendicular to ``closing_axis``.
    """
    u, v = perpendicular_basis(closing_axis)
    angles = start_angle + 2 * np.pi * np.arange(count) / count
    return np.cos(angles)[:, None] * u + np.sin(angles)[:, None] * v


def gripper_rotations(closing_axis: np.ndarray, approaches: np.ndarray) -> np.ndarray:
    """Rotation matrices of the gripper frame in the object frame.

    Parameters
    ----------
    closing_axis : (3,) float
        Unit gripper ``x`` axis.
    approaches : (K, 3) float
        Unit gripper ``z`` axes, perpendicular to ``closing_axis``.

    Returns
    -------
    (K, 3, 3) float64
        Columns are the gripper's x, y, z axes in the object frame.
    """
    x_axes = np.broadcast_to(closing_axis, approaches.shape)
    y_axes = np.cross(approaches, x_axes)
    return np.stack([x_axes, y_axes, approaches], axis=-1)


def rotations_to_quaternions(rotations: np.ndarray) -> np.ndarray:
    """(K, 3, 3) rotation matrices to (K, 4) quaternions ``(x, y, z, w)``, ``w >= 0``."""
    quaternions = Rotation.from_matrix(rotations).as_quat()
    # q and -q are the same rotation; fixing the sign makes shards byte-stable.
    quaternions[quaternions[:, 3] < 0] *= -1
    return quaternions


@dataclass(frozen=True)
class ObjectSurface:
    """Samples of an object's surface with their part labels.

    Attributes
    ----------
    points : (P, 3) float64
        Object frame, m.
    normals : (P, 3) float64
        Outward face normals.
    faces : (P,) int64
        Face each sample lies on.
    parts : (P,) int64
        Part index of that face (``taxonomy.PARTS``, -1 unknown).
    tree : cKDTree
        Over ``points``.
    """

    points: np.ndarray
    normals: np.ndarray
    faces: np.ndarray
    parts: np.ndarray
    tree: cKDTree

    @classmethod
    def sample(
        cls,
        mesh: trimesh.Trimesh,
        face_parts: np.ndarray,
        spacing: float,
        rng: np.random.Generator,
        max_points: int,
    ) -> ObjectSurface:
        """Every vertex plus random points, one per ``spacing**2`` of area.

        Parameters
        ----------
        mesh : trimesh.Trimesh
            Object frame, m.
        face_parts : (F,) int
            Part index per face.
        spacing : float
            Nominal distance between samples, m; raised when the count would
            exceed ``max_points`` (then the tolerance of the collision test
            grows with it).
        rng : numpy.random.Generator
        max_points : int
        """
        areas = mesh.area_faces
        total = float(areas.sum())
        if total > 0 and len(mesh.vertices) + total / spacing**2 > max_points:
            spacing = float(np.sqrt(total / max(max_points - len(mesh.vertices), 1)))
        # Rounded at random so that the expected count is area / spacing**2
        # on every face; small faces are covered by their vertices.
        counts = np.floor(areas / spacing**2 + rng.random(len(areas))).astype(np.int64)
        faces = np.repeat(np.arange(len(areas)), counts)
        # Uniform points in each triangle: fold the unit square onto it.
        first, second = rng.random((2, len(faces)))
        folded = first + second > 1
        first[folded], second[folded] = 1 - first[folded], 1 - second[folded]
        corners = mesh.triangles[faces]
        points = corners[:, 0] + first[:, None] * (corners[:, 1] - corners[:, 0]) + second[:, None] * (
            corners[:, 2] - corners[:, 0]
        )
        # The vertices too, so that a sharp corner poking into a box is found
        # however small the area near it; each takes a face it belongs to.
        vertex_faces = np.full(len(mesh.vertices), -1, dtype=np.int64)
        vertex_faces[mesh.faces[::-1].ravel()] = np.repeat(np.arange(len(mesh.faces))[::-1], 3)
        used = np.flatnonzero(vertex_faces >= 0)
        # OBJ files often repeat a vertex per face; one sample per position is enough.
        _, first_use = np.unique(np.asarray(mesh.vertices)[used], axis=0, return_index=True)
        used = used[np.sort(first_use)]
        points = np.concatenate([points, np.asarray(mesh.vertices)[used]])
        faces = np.concatenate([faces, vertex_faces[used]])
        parts = np.asarray(face_parts, dtype=np.int64)[faces]
        return cls(points, np.asarray(mesh.face_normals)[faces], faces, parts, cKDTree(points))

    def near(self, centre: np.ndarray, radius: float) -> np.ndarray:
        """Indices of the samples within ``radius`` of ``centre``, sorted."""
        return np.sort(np.asarray(self.tree.query_ball_point(centre, radius), dtype=np.int64))


def convex_planes(convex_parts: list[tuple[np.ndarray, np.ndarray]]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Half-spaces ``normals @ p <= offsets`` of each convex part's hull.

    Parameters
    ----------
    convex_parts : list of (vertices (V, 3), faces (F, 3))
        Object frame, m.

    Returns
    -------
    list of (normals (H, 3), offsets (H,))
    """
    planes = []
    for vertices, _faces in convex_parts:
        if len(vertices) < 4:
            continue
        try:
            hull = trimesh.convex.convex_hull(vertices)
        except Exception:  # qhull fails on flat parts, and a flat part cannot bury a box
            continue
        normals = np.asarray(hull.face_normals)
        offsets = np.einsum("ij,ij->i", normals, hull.triangles[:, 0])
        planes.append((normals, offsets))
    return planes


class GripperCollision:
    """The collision test of the module text, for one object.

    Parameters
    ----------
    surface : ObjectSurface
    planes : list of (normals, offsets)
        From :func:`convex_planes`.
    gripper : Gripper
    margin : float
        Tolerated penetration, m.
    """

    def __init__(
        self,
        surface: ObjectSurface,
        planes: list[tuple[np.ndarray, np.ndarray]],
        gripper: Gripper,
        margin: float,
    ) -> None:
        self.surface = surface
        self.planes = planes
        self.gripper = gripper
        self.margin = margin

    def reach(self, width: float) -> float:
        """Radius of a sphere about the grasp centre holding every box, m."""
        return max(
            float(np.linalg.norm(np.abs(centre) + half)) for _name, centre, half in self.gripper.boxes(width)
        )

    def free(self, centre: np.ndarray, rotations: np.ndarray, width: float, nearby: np.ndarray) -> np.ndarray:
        """Which of K gripper poses at one centre are collision-free.

        Parameters
        ----------
        centre : (3,) float
            Grasp centre, object frame, m.
        rotations : (K, 3, 3) float
            From :func:`gripper_rotations`: one closing axis, K approaches.
        width : float
            Opening, m.
        nearby : (N,) int
            Surface samples within :meth:`reach` of ``centre``
            (:meth:`ObjectSurface.near`).

        Returns
        -------
        (K,) bool
        """
        boxes = self.gripper.boxes(width)
        offsets = self.surface.points[nearby] - centre
        # The closing axis is the same for every pose: the x coordinate, and
        # with it which samples lie in each box's slab, is computed once.
        along = offsets @ rotations[0][:, 0]
        hit = np.zeros(len(rotations), dtype=bool)
        for _name, box_centre, half in boxes:
            slab = offsets[np.abs(along - box_centre[0]) < half[0] - self.margin]
            if len(slab) == 0:
                continue
            across = np.matmul(slab[None], rotations[:, :, 1:])  # (K, S, 2): y and z
            inside = np.all(np.abs(across - box_centre[1:]) < half[1:] - self.margin, axis=-1)
            hit |= inside.any(axis=-1)
        if self.planes:
            box_centres = np.stack([box_centre for _name, box_centre, _half in boxes])
            # (K, boxes, 3): each box centre in the object frame.
            probes = centre + np.einsum("kij,bj->kbi", rotations, box_centres)
            for normals, offsets in self.planes:
                depth = np.max(probes @ normals.T - offsets, axis=-1)
                hit |= np.any(depth < -self.margin, axis=-1)
        return ~hit


def local_points(points: np.ndarray, centre: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """Object-frame points in each of K gripper frames.

    Parameters
    ----------
    points : (N, 3) float
    centre : (3,) float
    rotations : (K, 3, 3) float

    Returns
    -------
    (K, N, 3) float64
    """
    return np.einsum("nj,kji->kni", points - centre, rotations)


def closing_region(gripper: Gripper, width: float, grow: float = 0.0) -> np.ndarray:
    """Half extents of the box between the finger pads, gripper frame.

    The region the pads sweep when they close: ``|x| <= width / 2``,
    ``|y| <= finger_width / 2``, ``|z| <= finger_depth / 2``, each grown by
    ``grow``. Returns (3,) float64.
    """
    return np.array([width / 2, gripper.finger_width / 2, gripper.finger_depth / 2]) + grow
