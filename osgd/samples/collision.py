"""Would the gripper, placed at a grasp, run into another object of the pile?

The pile is loaded into a headless pybullet world with :mod:`osgd.physics`
(static bodies, each model's collision compound at its scene pose); the
gripper is the three boxes of :meth:`osgd.gripper.Gripper.boxes` at the
grasp's opening, placed at the grasp's 3-D pose. A grasp collides when any
box comes closer than ``-tolerance`` (i.e. penetrates by more than the
tolerance) to an object other than the one grasped. The floor is not
tested: the finger boxes reach ``finger_depth / 2`` past the grasp centre,
so a grasp on a thin tool lying on the table would always touch it.

Each worker process keeps one such world (:func:`worker_pile_world`, an
:class:`osgd.physics.PileWorld`): a static body per model and copy is made
the first time a pile needs it and moved into place for every later pile,
and the gripper bodies are kept per opening, so a sample does not load its
pile's collision compounds anew. The world is never stepped:
only the bodies of the pile at hand are ever asked about, so bodies parked
where an earlier pile left them change nothing.
"""

from __future__ import annotations

import atexit
import functools
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from osgd.gripper import Gripper
from osgd.physics import PileWorld, pybullet_module

#: How close, m, an object's axis-aligned box must come to the gripper's for pybullet to be asked: well over
#: the penetration tolerance and pybullet's collision margins (about 1 mm on convex hulls, docs/checks.md).
BOUNDS_MARGIN = 0.01


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
    gripper_bodies : dict, optional
        Gripper bodies by gripper, then by opening, kept by a :class:`PileWorld`.
    bounds : (N, 2, 3) float, optional
        Each object's axis-aligned box in the world (min, max corner), m: the
        pybullet query is made only for objects whose box comes within
        :data:`BOUNDS_MARGIN` of the gripper's, which cannot touch it otherwise.
    """

    def __init__(self, client: int, bodies: list[int], gripper: Gripper, tolerance: float,
                 gripper_bodies: dict[Gripper, dict[float, int]] | None = None,
                 bounds: np.ndarray | None = None) -> None:
        self.client = client
        self.bodies = bodies
        self.gripper = gripper
        self.tolerance = tolerance
        # This gripper's bodies by opening (the gripper is hashed once, not per query).
        self._grippers = ({} if gripper_bodies is None else gripper_bodies).setdefault(gripper, {})
        self.bounds = bounds
        #: Gripper bodies moved into this pile, to be parked again when it is done.
        self.moved_grippers: set[int] = set()

    def collides(self, object_index: int, position: np.ndarray, rotation: np.ndarray, opening: float,
                 quaternion: np.ndarray | None = None, near: np.ndarray | None = None) -> bool:
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
        quaternion : (4,) float, optional
            ``rotation`` as ``(x, y, z, w)``, when the caller has it (:attr:`GraspSet.quaternions`).
        near : (N,) bool, optional
            This grasp's row of :meth:`near_objects`, when the caller has it.
        """
        pybullet = pybullet_module()
        if near is None:
            near = self.near_objects(np.asarray(position)[None], np.asarray(rotation)[None], np.array([opening]))[0]
        others = [body for index, body in enumerate(self.bodies) if index != object_index and near[index]]
        if not others:
            return False
        if quaternion is None:
            quaternion = Rotation.from_matrix(rotation).as_quat()
        body = self._gripper_body(float(opening))
        self.moved_grippers.add(body)
        pybullet.resetBasePositionAndOrientation(
            body,
            np.asarray(position, dtype=np.float64).tolist(),
            np.asarray(quaternion, dtype=np.float64).tolist(),
            physicsClientId=self.client,
        )
        for other in others:
            points = pybullet.getClosestPoints(body, other, 0.0, physicsClientId=self.client)
            if any(point[8] < -self.tolerance for point in points):
                return True
        return False

    def near_objects(self, positions: np.ndarray, rotations: np.ndarray, openings: np.ndarray) -> np.ndarray:
        """Which objects' boxes come within :data:`BOUNDS_MARGIN` of the gripper's, per grasp.

        Parameters
        ----------
        positions : (G, 3) float
        rotations : (G, 3, 3) float
        openings : (G,) float

        Returns
        -------
        (G, N) bool
            All true without ``bounds``.
        """
        if self.bounds is None:
            return np.ones((len(positions), len(self.bodies)), dtype=bool)
        corners = self.gripper.box_corners(openings)
        world = np.einsum("gij,gkj->gki", np.asarray(rotations, dtype=np.float64), corners)
        world += np.asarray(positions, dtype=np.float64)[:, None, :]
        low, high = world.min(axis=1) - BOUNDS_MARGIN, world.max(axis=1) + BOUNDS_MARGIN
        return np.all((self.bounds[None, :, 0] <= high[:, None]) & (self.bounds[None, :, 1] >= low[:, None]), axis=2)

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

@functools.cache
def worker_pile_world() -> PileWorld:
    """This process's :class:`osgd.physics.PileWorld` for the gripper collisions, disconnected at exit."""
    world = PileWorld()
    atexit.register(world.close)
    return world


@contextmanager
def pile_collider(
    models: Mapping[str, Mapping[str, Any]],
    objects: Sequence[Mapping[str, Any]],
    gripper: Gripper,
    tolerance: float,
    world: PileWorld | None = None,
) -> Iterator[PileCollider]:
    """A :class:`PileCollider` for one scene, in this worker's :class:`PileWorld`.

    Parameters
    ----------
    models : mapping of model id to ``models`` row (dict)
    objects : sequence of scene objects (dicts with ``model_id``,
        ``position``, ``quaternion``: the mesh-frame pose in the world)
    gripper : Gripper
    tolerance : float
        Penetration allowed, metres.
    world : PileWorld, optional
        Default: :func:`worker_pile_world`.
    """
    world = world or worker_pile_world()
    bodies = world.place(models, objects)
    collider = PileCollider(world.client, bodies, gripper, tolerance, world.gripper_bodies,
                            world.bounds(models, objects))
    try:
        yield collider
    finally:
        world.park([*bodies, *collider.moved_grippers])
