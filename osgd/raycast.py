"""Ray-triangle distances that come out the same on every x86-64 processor.

embree (through embreex, or trimesh's ray module) answers two questions for a
ray: *which* triangle it hits first, and *where*. It answers the second in
float32 with SIMD kernels picked at run time for the processor (SSE, AVX2,
AVX-512), so the distance differs in its last bits from one machine to
another, and a shard built from it is not byte-identical across machines
(found when the golden pipeline, recorded on an AVX2 machine, was rebuilt on
an AVX-512 one). The stages therefore keep embree's answer to *which* and
compute *where* again here, in float64, with element-wise IEEE operations
only: each of them is correctly rounded whatever the SIMD width, and numpy
never fuses a multiply and an add across two ufunc calls.
"""

from __future__ import annotations

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
