"""Bodies made from models rows: mesh-frame poses, compound shapes, mass."""

from __future__ import annotations

import numpy as np
import pybullet
import pytest
from helpers import fixture_models, hammer_parts, model_row
from scipy.spatial.transform import Rotation

from osgd.physics import create_object_body, get_mesh_pose, physics_client, set_mesh_pose


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
