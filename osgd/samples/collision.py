"""Would the gripper, placed at a grasp, run into another object of the pile?

The pile is loaded into a headless pybullet world with :mod:`osgd.physics`
(static bodies, each model's collision compound at its scene pose); the
gripper is the three boxes of :meth:`osgd.gripper.Gripper.boxes` at the
grasp's opening, placed at the grasp's 3-D pose. A grasp collides when any
box comes closer than ``-tolerance`` (i.e. penetrates by more than the
tolerance) to an object other than the one grasped. The floor is not
tested: the finger boxes reach ``finger_depth / 2`` past the grasp centre,
so a grasp on a thin tool lying on the table would always touch it.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from osgd.gripper import Gripper
from osgd.physics import create_object_body, physics_client, pybullet_module


class PileCollider:
    """Gripper-versus-pile tests in one pybullet world.

    Use :func:`pile_collider` to make one.

    Parameters
    ----------
    client : int
        pybullet client holding the pile.
    bodies : list of int
        Body id of each scene object, in scene order.
    gripper : Gripper
    tolerance : float
        Penetration allowed, metres.
    """

    def __init__(self, client: int, bodies: list[int], gripper: Gripper, tolerance: float) -> None:
        self.client = client
        self.bodies = bodies
        self.gripper = gripper
        self.tolerance = tolerance
        self._grippers: dict[float, int] = {}

    def collides(self, object_index: int, position: np.ndarray, rotation: np.ndarray, opening: float) -> bool:
        """Whether the gripper at this pose touches another object.

        Parameters
        ----------
        object_index : int
            The grasped object (not tested).
        position : (3,) float
            Grasp centre, world frame, metres.
        rotation : (3, 3) float
            Gripper frame in the world frame.
        opening : float
            Finger opening, metres.
        """
        pybullet = pybullet_module()
        others = [body for index, body in enumerate(self.bodies) if index != object_index]
        if not others:
            return False
        body = self._gripper_body(float(opening))
        pybullet.resetBasePositionAndOrientation(
            body,
            np.asarray(position, dtype=np.float64).tolist(),
            Rotation.from_matrix(rotation).as_quat().tolist(),
            physicsClientId=self.client,
        )
        for other in others:
            points = pybullet.getClosestPoints(body, other, 0.0, physicsClientId=self.client)
            if any(point[8] < -self.tolerance for point in points):
                return True
        return False

    def _gripper_body(self, opening: float) -> int:
        """A static gripper body per opening, made once and moved about.

        (Removing a body made from a shape array fails in pybullet 3.2.7,
        so bodies are kept for the life of the world.)
        """
        pybullet = pybullet_module()
        body = self._grippers.get(opening)
        if body is None:
            boxes = self.gripper.boxes(opening)
            shape = pybullet.createCollisionShapeArray(
                shapeTypes=[pybullet.GEOM_BOX] * len(boxes),
                halfExtents=[half.tolist() for _, _, half in boxes],
                collisionFramePositions=[centre.tolist() for _, centre, _ in boxes],
                physicsClientId=self.client,
            )
            body = pybullet.createMultiBody(baseMass=0.0, baseCollisionShapeIndex=shape, physicsClientId=self.client)
            self._grippers[opening] = body
        return body

@contextmanager
def pile_collider(
    models: Mapping[str, Mapping[str, Any]],
    objects: Sequence[Mapping[str, Any]],
    gripper: Gripper,
    tolerance: float,
) -> Iterator[PileCollider]:
    """A :class:`PileCollider` for one scene, its world torn down on exit.

    Parameters
    ----------
    models : mapping of model id to ``models`` row (dict)
    objects : sequence of scene objects (dicts with ``model_id``,
        ``position``, ``quaternion``: the mesh-frame pose in the world)
    gripper : Gripper
    tolerance : float
        Penetration allowed, metres.
    """
    with physics_client(gravity=0.0) as client:
        bodies = [
            create_object_body(
                client,
                models[obj["model_id"]],
                np.asarray(obj["position"], dtype=np.float64),
                np.asarray(obj["quaternion"], dtype=np.float64),
                mass=0.0,
            ).body_id
            for obj in objects
        ]
        yield PileCollider(client, bodies, gripper, tolerance)
