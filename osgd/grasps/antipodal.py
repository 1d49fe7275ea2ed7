"""Antipodal contact pairs on a mesh (Dex-Net style, REFERENCE section 5).

For a model with no hand-made pairs: draw surface points, draw a closing
direction inside the friction cone about each point's inward normal, follow
it through the body to where it leaves, and keep the pair when the line
between the two contacts lies inside both friction cones (two-finger force
closure with Coulomb friction ``mu``: each contact can then push along the
line without slipping) and fits the gripper. Many more pairs are drawn than
kept; near-duplicates are thinned out, best quality first.

Quality: ``1 - max(angle_a, angle_b) / atan(mu)``, where ``angle_a`` and
``angle_b`` are the angles between the closing line and the two inward
normals: 1 for perfectly opposed flat faces, 0 at the edge of the friction
cone. It is in [0, 1] by construction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from osgd.grasps.geometry import unit
from osgd.raycast import dot_rows, plane_hit_distances

#: Rays start this far inside the surface so they do not hit their own face
#: (embree works in float32: about 1e-7 relative, 1e-5 m on a 0.3 m model).
_RAY_OFFSET = 1e-5


@dataclass(frozen=True)
class ContactPairs:
    """Contact pairs on one object, object frame, m.

    Attributes
    ----------
    contact_a, contact_b : (N, 3) float64
        Finger A's and finger B's contact; the closing axis points a -> b.
    quality : (N,) float64
        In [0, 1] (module text).
    """

    contact_a: np.ndarray
    contact_b: np.ndarray
    quality: np.ndarray

    def __len__(self) -> int:
        return len(self.quality)

    def take(self, indices: np.ndarray) -> ContactPairs:
        """The pairs at ``indices``, in that order."""
        return ContactPairs(self.contact_a[indices], self.contact_b[indices], self.quality[indices])


def _directions_in_cones(normals: np.ndarray, half_angle: float, rng: np.random.Generator) -> np.ndarray:
    """One direction per row, uniform over the cone about ``-normals``."""
    cos_theta = 1 - rng.random(len(normals)) * (1 - np.cos(half_angle))
    sin_theta = np.sqrt(np.clip(1 - cos_theta**2, 0, None))
    phi = rng.random(len(normals)) * 2 * np.pi
    axes = -normals
    # A perpendicular basis per row, from the object axis least aligned with it.
    reference = np.eye(3)[np.argmin(np.abs(axes), axis=1)]
    u = unit(reference - np.einsum("ij,ij->i", reference, axes)[:, None] * axes)
    v = np.cross(axes, u)
    directions = cos_theta[:, None] * axes + sin_theta[:, None] * (
        np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v
    )
    return directions


def sample_pairs(
    mesh: trimesh.Trimesh,
    rng: np.random.Generator,
    count: int,
    *,
    friction: float,
    max_distance: float,
    min_distance: float = 1e-3,
) -> ContactPairs:
    """Draw antipodal contact pairs.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Object frame, m, faces counter-clockwise seen from outside.
    rng : numpy.random.Generator
    count : int
        Surface points drawn (an upper bound on the pairs returned).
    friction : float
        Coulomb friction coefficient ``mu``; cone half-angle ``atan(mu)``.
    max_distance : float
        Largest contact distance kept, m (gripper opening less clearance).
    min_distance : float
        Smallest contact distance kept, m (thinner is a sliver or a seam).

    Returns
    -------
    ContactPairs
        In the order drawn.
    """
    half_angle = float(np.arctan(friction))
    points, faces = trimesh.sample.sample_surface(mesh, count, seed=rng)
    normals = unit(np.asarray(mesh.face_normals)[faces])
    directions = _directions_in_cones(normals, half_angle, rng)
    origins = points + _RAY_OFFSET * directions
    hit_faces, ray_index = mesh.ray.intersects_id(origins, directions, multiple_hits=False)
    empty = ContactPairs(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    if len(ray_index) == 0:
        return empty
    order = np.argsort(ray_index, kind="stable")
    ray_index, hit_faces = ray_index[order], hit_faces[order]
    contact_a = points[ray_index]
    direction = directions[ray_index]
    # embree's float32 hit points differ in their last bits between processors:
    # keep the face it hit and intersect that face's plane in float64.
    along = plane_hit_distances(origins[ray_index], direction, np.asarray(mesh.triangles)[hit_faces])
    locations = origins[ray_index] + along[:, None] * direction
    exit_normals = unit(np.asarray(mesh.face_normals)[hit_faces])
    distance = dot_rows(locations - contact_a, direction)
    angle_a = np.arccos(np.clip(dot_rows(direction, -normals[ray_index]), -1, 1))
    # The ray must leave the body through a face facing along it (an entering
    # hit means overlapping parts or an open mesh), inside that face's cone.
    angle_b = np.arccos(np.clip(dot_rows(direction, exit_normals), -1, 1))
    keep = np.isfinite(distance) & (angle_b <= half_angle) & (distance >= min_distance) & (distance <= max_distance)
    if not keep.any():
        return empty
    quality = 1 - np.maximum(angle_a[keep], angle_b[keep]) / half_angle
    return ContactPairs(contact_a[keep], locations[keep], np.clip(quality, 0.0, 1.0))


def thin_pairs(pairs: ContactPairs, min_distance: float, min_angle: float) -> np.ndarray:
    """Indices of pairs kept after dropping near-duplicates, best first.

    Greedy: pairs are visited by decreasing quality (ties by index) and a pair
    is dropped when a kept one has its centre within ``min_distance`` and its
    closing axis within ``min_angle`` (either sign).

    Parameters
    ----------
    pairs : ContactPairs
    min_distance : float
        m.
    min_angle : float
        rad.

    Returns
    -------
    (M,) int64
        Kept indices in order of decreasing quality.
    """
    centres = (pairs.contact_a + pairs.contact_b) / 2
    axes = unit(pairs.contact_b - pairs.contact_a)
    order = np.lexsort((np.arange(len(pairs)), -pairs.quality))
    cos_limit = np.cos(min_angle)
    kept: list[int] = []
    for index in order:
        if kept:
            close = np.linalg.norm(centres[kept] - centres[index], axis=1) < min_distance
            aligned = np.abs(axes[kept] @ axes[index]) > cos_limit
            if np.any(close & aligned):
                continue
        kept.append(int(index))
    return np.asarray(kept, dtype=np.int64)


def spread_order(pairs: ContactPairs) -> np.ndarray:
    """An order of the pairs that covers the whole object early.

    Farthest-point order of the pair centres, starting from the best pair:
    each next pair is the one farthest from every pair already taken (ties
    to the lower index). Taking the first few pairs of this order spreads
    the grasps over every part instead of piling them where the surfaces are
    flattest (which quality order alone would do).

    Returns
    -------
    (N,) int64
        A permutation of ``range(len(pairs))``.
    """
    count = len(pairs)
    if count == 0:
        return np.zeros(0, dtype=np.int64)
    centres = (pairs.contact_a + pairs.contact_b) / 2
    order = np.empty(count, dtype=np.int64)
    order[0] = int(np.lexsort((np.arange(count), -pairs.quality))[0])
    nearest = np.linalg.norm(centres - centres[order[0]], axis=1)
    for step in range(1, count):
        nearest[order[step - 1]] = -1.0
        order[step] = int(np.argmax(nearest))
        nearest = np.minimum(nearest, np.linalg.norm(centres - centres[order[step]], axis=1))
    return order
