"""Ray-triangle distances that come out the same on every x86-64 processor.

embree (through embreex, or trimesh's ray module) answers two questions for a
ray: *which* triangle it hits first, and *where*. It answers the second in
float32 with SIMD kernels picked at run time for the processor (SSE, AVX2,
AVX-512), so the distance differs in its last bits from one machine to
another, and a shard built from it is not byte-identical across machines.
The stages therefore keep embree's answer to *which* and
compute *where* again here, in float64, with element-wise IEEE operations
only: each of them is correctly rounded whatever the SIMD width, and numpy
never fuses a multiply and an add across two ufunc calls.

Asking embree needs a scene (a mesh and its BVH) per mesh; building it costs
about a hundred casts, so :class:`EmbreeScenes` keeps them per process, each
mesh in its own frame, the rays turned into that frame.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Any

import numpy as np


def dot_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products in a fixed order of operations.

    Parameters
    ----------
    a, b : (N, 3) float64

    Returns
    -------
    (N,) float64
        ``a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]``, summed
        left to right (``einsum`` and ``sum`` may regroup by SIMD width).
    """
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def rotate_rows(vectors: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """``vectors @ rotation.T`` in a fixed order of operations.

    Parameters
    ----------
    vectors : (N, 3) float64
    rotation : (3, 3) float64

    Returns
    -------
    (N, 3) float64
        Each row turned by ``rotation`` (a BLAS matrix product may accumulate
        in another order, or fused, depending on the processor).
    """
    vectors = np.asarray(vectors, dtype=np.float64)
    rotation = np.asarray(rotation, dtype=np.float64)
    return vectors[:, 0:1] * rotation[:, 0] + vectors[:, 1:2] * rotation[:, 1] + vectors[:, 2:3] * rotation[:, 2]


def rotate_grid_rays(x: np.ndarray, y: np.ndarray, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`rotate_rows` of the rays ``(x[c], y[r], 1)`` of a pixel grid, value for value, from row and column terms.

    Each component of a turned ray is ``x * R[i, 0] + y * R[i, 1] + R[i, 2]``,
    the operations of :func:`rotate_rows` in its order (``1 * R[i, 2]`` is
    ``R[i, 2]`` exactly), so the products are made once per column and once
    per row and only the sums once per pixel. The components come
    apart, as contiguous (H, W) arrays: tests on them run several times
    faster than on the columns of an (H, W, 3) array.

    Parameters
    ----------
    x : (W,) float64
        The rays' ``x`` per column (``(column - cx) / fx``).
    y : (H,) float64
        Their ``y`` per row.
    rotation : (3, 3) float64

    Returns
    -------
    tuple of three (H, W) float64
        The turned rays' x, y and z components.
    """
    rotation = np.asarray(rotation, dtype=np.float64)
    x, y = np.asarray(x, dtype=np.float64)[None, :], np.asarray(y, dtype=np.float64)[:, None]
    return tuple(x * rotation[axis, 0] + y * rotation[axis, 1] + rotation[axis, 2] for axis in range(3))


def plane_hit_distances(origins: np.ndarray, directions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Ray parameter where each ray meets the plane of the triangle it hit.

    Parameters
    ----------
    origins : (N, 3) float64
        Ray origins, any frame, metres.
    directions : (N, 3) float64
        Ray directions in the same frame (need not be unit length: the result
        is in units of the direction's length).
    triangles : (N, 3, 3) float64
        The triangle each ray hit (as reported by the ray caster), vertices
        in the same frame.

    Returns
    -------
    (N,) float64
        ``t`` with ``origins + t * directions`` on the triangle's plane; NaN
        for a ray parallel to that plane.
    """
    origins = np.asarray(origins, dtype=np.float64)
    directions = np.asarray(directions, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.float64)
    edge_1 = triangles[:, 1] - triangles[:, 0]
    edge_2 = triangles[:, 2] - triangles[:, 0]
    normals = np.stack(
        [
            edge_1[:, 1] * edge_2[:, 2] - edge_1[:, 2] * edge_2[:, 1],
            edge_1[:, 2] * edge_2[:, 0] - edge_1[:, 0] * edge_2[:, 2],
            edge_1[:, 0] * edge_2[:, 1] - edge_1[:, 1] * edge_2[:, 0],
        ],
        axis=1,
    )
    along = dot_rows(normals, directions)
    with np.errstate(divide="ignore", invalid="ignore"):
        distances = dot_rows(normals, triangles[:, 0] - origins) / along
    return np.where(along != 0.0, distances, np.nan)


#: Embree scenes kept per process by :class:`EmbreeScenes` (each holds a mesh and its BVH, about 100 bytes
#: per triangle: 64 of the authors' largest meshes take about 300 MB). 128, so that all 75 of the authors'
#: models stay built.
EMBREE_SCENES_KEPT = 128


class EmbreeScenes:
    """Embree scenes of meshes in their own frame, built once per mesh key and reused.

    Building the scene (its BVH) costs about 100 times casting an object's
    rays at it, so the ``capacity`` most recently used are kept. Equal keys must mean
    equal meshes (the samples stage's renderer and silhouettes, and the
    scenes stage's top-down views, key them by model id).
    """

    def __init__(self, capacity: int = EMBREE_SCENES_KEPT) -> None:
        self.capacity = capacity
        self._scenes: OrderedDict[str, Any] = OrderedDict()

    def __len__(self) -> int:
        return len(self._scenes)

    def clear(self) -> None:
        """Drop every scene (their memory with them)."""
        self._scenes.clear()

    def scene(self, key: str, vertices: np.ndarray, faces: np.ndarray) -> Any:
        """The embree scene of the mesh called ``key``, in the mesh's own frame.

        Parameters
        ----------
        key : str
            Names the mesh: equal keys must mean equal meshes.
        vertices : (V, 3) float
            Read only when ``key`` has no scene yet, as are ``faces``.
        faces : (F, 3) int

        Returns
        -------
        embreex.rtcore_scene.EmbreeScene
            Its ``run(origins, directions)`` answers the first triangle each
            float32 ray hits (-1: none).
        """
        scene = self._scenes.pop(key, None)
        if scene is None:
            from embreex import mesh_construction, rtcore_scene  # noqa: PLC0415

            scene = rtcore_scene.EmbreeScene()
            mesh_construction.TriangleMesh(scene, np.asarray(vertices, dtype=np.float32).reshape(-1, 3),
                                           np.asarray(faces, dtype=np.int32).reshape(-1, 3))
        self._scenes[key] = scene
        while len(self._scenes) > self.capacity:
            self._scenes.popitem(last=False)
        return scene
