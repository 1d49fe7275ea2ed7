"""osgd.raycast: float64 ray-plane distances and fixed-order products."""

from __future__ import annotations

import numpy as np
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from osgd.raycast import dot_rows, plane_hit_distances, rotate_rows


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_distance_recovers_the_point_on_the_triangle(seed: int) -> None:
    rng = np.random.default_rng(seed)
    triangles = rng.normal(size=(64, 3, 3))
    weights = rng.dirichlet(np.ones(3), size=64)
    points = np.einsum("nk,nkj->nj", weights, triangles)
    directions = rng.normal(size=(64, 3))
    along = rng.uniform(0.01, 3.0, size=64)
    origins = points - along[:, None] * directions
    distances = plane_hit_distances(origins, directions, triangles)
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    # Rays nearly parallel to their plane are ill-conditioned: judge the others.
    sine = np.abs(dot_rows(normals, directions)) / (
        np.linalg.norm(normals, axis=1) * np.linalg.norm(directions, axis=1))
    well_posed = sine > 1e-3
    np.testing.assert_allclose(distances[well_posed], along[well_posed], rtol=1e-9)


def test_a_ray_parallel_to_the_plane_has_no_distance() -> None:
    triangle = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    assert np.isnan(plane_hit_distances(np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]), triangle))[0]


def test_embree_hits_refined_agree_with_embree_to_float32_precision() -> None:
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    rng = np.random.default_rng(0)
    origins = rng.normal(size=(200, 3)) * 0.01 + np.array([0.0, 0.0, -0.3])
    directions = np.array([0.0, 0.0, 1.0]) + rng.normal(size=(200, 3)) * 0.05
    locations, ray_index, faces = mesh.ray.intersects_location(origins, directions, multiple_hits=False)
    distances = plane_hit_distances(origins[ray_index], directions[ray_index], mesh.triangles[faces])
    refined = origins[ray_index] + distances[:, None] * directions[ray_index]
    assert len(ray_index) > 100
    np.testing.assert_allclose(refined, locations, atol=1e-6)
    # The refined point lies on its triangle's plane to float64 precision.
    offsets = dot_rows(np.asarray(mesh.face_normals)[faces], refined - mesh.triangles[faces][:, 0])
    assert np.max(np.abs(offsets)) < 1e-15


def test_fixed_order_products_equal_the_usual_ones() -> None:
    rng = np.random.default_rng(1)
    vectors, others = rng.normal(size=(100, 3)), rng.normal(size=(100, 3))
    rotation = Rotation.random(random_state=2).as_matrix()
    np.testing.assert_allclose(rotate_rows(vectors, rotation), vectors @ rotation.T, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(dot_rows(vectors, others), np.einsum("ij,ij->i", vectors, others), atol=1e-14)
