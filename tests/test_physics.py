"""Bodies made from models rows: mesh-frame poses, compound shapes, mass."""

from __future__ import annotations

import json

import numpy as np
import pybullet
import pytest
import trimesh
from helpers import fixture_models, hammer_parts, model_row
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from osgd.physics import create_object_body, get_mesh_pose, physics_client, reduced_hull, set_mesh_pose


def test_mesh_pose_round_trips_through_the_inertial_frame() -> None:
    hammer = model_row("hammer", "hammer", hammer_parts())
    # The hammer's centre of mass sits well away from its mesh origin, so a
    # body placed by its inertial frame would land visibly elsewhere.
    assert np.linalg.norm(hammer["center_of_mass"]) > 0.01
    rng = np.random.default_rng(3)
    with physics_client() as client:
        body = create_object_body(client, hammer)
        for _ in range(5):
            position = rng.uniform(-1, 1, 3)
            quaternion = Rotation.random(random_state=rng).as_quat()
            set_mesh_pose(body, position, quaternion)
            got_position, got_quaternion = get_mesh_pose(body)
            np.testing.assert_allclose(got_position, position, atol=1e-9)
            assert abs(abs(np.dot(got_quaternion, quaternion)) - 1) < 1e-6


def test_posed_body_occupies_the_posed_mesh() -> None:
    hammer = model_row("hammer", "hammer", hammer_parts())
    rotation = Rotation.from_euler("xyz", [0.3, -0.7, 1.1])
    position = np.array([0.2, -0.1, 0.5])
    # Points in the object frame: inside the head, inside the handle, and in
    # the empty notch beside the handle 2 cm from both parts.
    probes = {"head": [0.105, 0.03, 0.0], "handle": [-0.1, 0.0, 0.0], "notch": [0.06, 0.04, 0.0]}
    with physics_client() as client:
        body = create_object_body(client, hammer, position, rotation.as_quat())
        sphere = pybullet.createCollisionShape(pybullet.GEOM_SPHERE, radius=0.001, physicsClientId=client)
        distances = {}
        for name, point in probes.items():
            world = rotation.apply(point) + position
            probe = pybullet.createMultiBody(0, sphere, basePosition=world.tolist(), physicsClientId=client)
            contacts = pybullet.getClosestPoints(body.body_id, probe, 0.1, physicsClientId=client)
            distances[name] = min(contact[8] for contact in contacts)
    assert distances["head"] < 0
    assert distances["handle"] < 0
    assert 0.01 < distances["notch"] < 0.03


def test_compound_keeps_the_concave_notch_open() -> None:
    hammer = model_row("hammer", "hammer", hammer_parts())
    with physics_client() as client:
        create_object_body(client, hammer, np.array([0.0, 0.0, 1.0]))
        pybullet.performCollisionDetection(physicsClientId=client)

        def hit(x: float, y: float) -> bool:
            return pybullet.rayTest([x, y, 0.5], [x, y, 1.5], physicsClientId=client)[0][0] >= 0

        # Beside the handle, inside the convex hull of handle + head: empty space.
        assert not hit(0.0, 0.035)
        assert hit(0.105, 0.035)  # the head
        assert hit(0.0, 0.0)  # the handle


def test_one_mesh_cut_two_ways_collides_as_each_cut_in_one_process() -> None:
    # The model id names the mesh; the hull of the whole hammer (another
    # decomposition of it) fills the notch that the exact parts leave open.
    hammer = model_row("hammer", "hammer", hammer_parts())
    hull = trimesh.util.concatenate([mesh for _, mesh in hammer_parts()]).convex_hull
    filled = {**hammer, "decomposition": json.dumps({"method": "convex_hull"}),
              "convex_parts": [{"vertices": hull.vertices.tolist(), "faces": hull.faces.tolist()}]}
    notch = []
    for row in (hammer, filled, hammer):
        with physics_client() as client:
            create_object_body(client, row, np.array([0.0, 0.0, 1.0]))
            pybullet.performCollisionDetection(physicsClientId=client)
            notch.append(pybullet.rayTest([0.0, 0.035, 0.5], [0.0, 0.035, 1.5], physicsClientId=client)[0][0] >= 0)
    assert notch == [False, True, False]


@pytest.mark.parametrize("row", fixture_models(), ids=lambda row: row["name"])
def test_mass_and_friction_reach_pybullet(row: dict) -> None:
    with physics_client() as client:
        body = create_object_body(client, row)
        info = pybullet.getDynamicsInfo(body.body_id, -1, physicsClientId=client)
    assert info[0] == pytest.approx(row["mass"])
    assert info[1] == pytest.approx(row["friction"][0])


def test_a_dropped_body_comes_to_rest_on_the_floor() -> None:
    block = fixture_models()[2]
    with physics_client() as client:
        pybullet.createMultiBody(0, pybullet.createCollisionShape(pybullet.GEOM_PLANE, physicsClientId=client),
                                 physicsClientId=client)
        body = create_object_body(client, block, np.array([0.0, 0.0, 0.3]))
        for _ in range(480):
            pybullet.stepSimulation(physicsClientId=client)
        position, _ = get_mesh_pose(body)
    # The block is 4 cm tall and centred on its mesh origin.
    assert position[2] == pytest.approx(0.02, abs=0.005)


def _rough_cylinder(rng: np.random.Generator, points: int = 3000) -> np.ndarray:
    """A scanned-looking part: a 12 cm bar of radius 1 cm, its surface points jittered by 0.1 mm."""
    angle = rng.uniform(0, 2 * np.pi, points)
    along = rng.uniform(-0.06, 0.06, points)
    surface = np.column_stack([along, 0.01 * np.cos(angle), 0.01 * np.sin(angle)])
    return surface + rng.normal(0, 1e-4, surface.shape)


def test_reduced_hull_keeps_few_of_the_parts_own_corners_and_says_how_far_it_shrank() -> None:
    rng = np.random.default_rng(5)
    part = Rotation.random(random_state=rng).apply(_rough_cylinder(rng)) + np.array([0.3, -0.2, 0.1])
    corners, faces, shrink = reduced_hull(part, 32)
    assert len(corners) == 32
    assert faces.max() < len(corners)
    # its corners are corners of the part, so it lies inside the part
    assert all(np.min(np.linalg.norm(part - corner, axis=1)) == 0 for corner in corners)
    # shrink: how far the part reaches beyond the reduced hull's planes, less than the 1 cm radius
    reduced = ConvexHull(corners)
    assert np.max(part @ reduced.equations[:, :3].T + reduced.equations[:, 3]) == pytest.approx(shrink)
    assert 0 < shrink < 0.01
    assert 0.5 * ConvexHull(part).volume < reduced.volume < ConvexHull(part).volume


def test_reduced_hull_leaves_a_small_part_as_it_is() -> None:
    cube = np.array([[x, y, z] for x in (0, 0.02) for y in (0, 0.03) for z in (0, 0.01)], dtype=float)
    corners, faces, shrink = reduced_hull(cube, 32)
    assert shrink == 0.0
    assert sorted(map(tuple, corners)) == sorted(map(tuple, cube))
    assert len(faces) == 12


def test_a_body_of_reduced_hulls_lies_within_the_body_of_the_stored_parts() -> None:
    rng = np.random.default_rng(2)
    bar = trimesh.convex.convex_hull(_rough_cylinder(rng))
    row = model_row("bar", "screwdriver", [("handle", bar)])
    with physics_client() as client:
        stored = create_object_body(client, row, np.array([0.0, 0.0, 1.0]))
        reduced = create_object_body(client, row, np.array([0.0, 0.0, 1.0]), max_hull_vertices=16)
        low, high = (np.array(corner) for corner in pybullet.getAABB(stored.body_id, physicsClientId=client))
        inner_low, inner_high = (np.array(corner)
                                 for corner in pybullet.getAABB(reduced.body_id, physicsClientId=client))
    assert np.all(inner_low >= low - 1e-6) and np.all(inner_high <= high + 1e-6)
    assert np.all(inner_high - inner_low > high - low - 0.008)


def test_a_body_in_maximal_coordinates_has_the_pose_mass_and_inertia_of_the_multibody() -> None:
    # pybullet 3.2 sets a rigid body's mass to 0 when changeDynamics gives its inertia alone: the body turned
    # NaN on its first step.
    row = fixture_models()[0]
    quaternion = Rotation.from_euler("xyz", [0.3, -0.5, 1.1]).as_quat()
    rests = []
    for maximal in (False, True):
        with physics_client() as client:
            pybullet.createMultiBody(0, pybullet.createCollisionShape(pybullet.GEOM_PLANE, physicsClientId=client),
                                     useMaximalCoordinates=maximal, physicsClientId=client)
            body = create_object_body(client, row, np.array([0.1, 0.2, 0.3]), quaternion,
                                      maximal_coordinates=maximal)
            position, placed = get_mesh_pose(body)
            np.testing.assert_allclose(position, [0.1, 0.2, 0.3], atol=1e-6)
            assert abs(abs(np.dot(placed, quaternion)) - 1) < 1e-6
            mass, _, inertia = pybullet.getDynamicsInfo(body.body_id, -1, physicsClientId=client)[:3]
            assert mass == pytest.approx(row["mass"])
            np.testing.assert_allclose(sorted(inertia), sorted(np.linalg.eigvalsh(np.reshape(row["inertia"], (3, 3)))),
                                       rtol=1e-6)
            for _ in range(480):
                pybullet.stepSimulation(physicsClientId=client)
            rests.append(pybullet.getAABB(body.body_id, physicsClientId=client)[0][2])
    # Both fell 0.3 m onto the floor and lie on it.
    assert all(np.isfinite(rests)) and abs(rests[0] - rests[1]) < 0.002 and max(rests) < 0.003
