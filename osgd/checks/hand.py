"""The simulated parallel-jaw gripper, built from :mod:`osgd.gripper`.

One pybullet multibody whose base is the palm and whose two links are the
fingers, each on a prismatic joint along the gripper's closing axis ``x``.
The base frame is the gripper frame of :mod:`osgd.gripper` (origin at the
grasp centre, ``x`` closing axis from finger A to finger B, ``z`` approach),
so a grasp row's pose is the base pose. Every size comes from a
:class:`~osgd.gripper.Gripper`; nothing here hard-codes a dimension.

Joint convention
----------------
Finger A's joint axis is ``+x`` and finger B's is ``-x``, with both link
frames placed where the fingers sit fully open; a joint value ``q >= 0`` is
how far that finger has moved in, so the pad-to-pad opening is
``max_opening - q_a - q_b``. A gear constraint (ratio -1 in pybullet's
convention: the two joints move together) couples the fingers like the
Panda's rack: without it, two force-limited fingers holding an object can
slide sideways together under any disturbance along ``x``.

The palm is the box :meth:`Gripper.boxes` gives at the maximum opening: a
real hand's palm does not shrink as it closes.

The hand is moved by a fixed constraint between its base and the world
(:meth:`SimulatedHand.move_to`), force-limited so that a stuck hand stalls
instead of tunnelling through the object.

Pads
----
Two pad models (``pad_contact``):

- ``"soft"`` (the default): the soft-finger contact of :mod:`osgd.gripper`.
  Each finger is the finger box with its inner face recessed by
  ``pad_crown`` and a crowned patch of ``pad_radius`` on it (one convex
  hull), whose apex lies where the flat face was, so openings are unchanged.
  The pad's spinning friction is :meth:`Gripper.torsion_radius`: pybullet
  combines it with the object's lateral friction into the torsional limit
  ``mu * torsion_radius * N`` per contact, the soft-finger law (the tests in
  ``tests/test_checks_physics.py`` measure it). Contact stiffness and damping
  give the pad its compliance.
- ``"rigid"``: plain finger boxes, no torsional friction, the solver's rigid
  contact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from osgd.gripper import Gripper
from osgd.physics import pybullet_module

#: Link indices of the fingers in the hand multibody (the palm is -1, the base).
FINGER_A = 0
FINGER_B = 1


@dataclass
class SimulatedHand:
    """A gripper instantiated in one pybullet client.

    Attributes
    ----------
    client : int
    body_id : int
    constraint_id : int
        The fixed constraint that moves the base.
    gripper : Gripper
    constraint_force : float
        Force limit of the moving constraint, N.
    """

    client: int
    body_id: int
    constraint_id: int
    gripper: Gripper
    constraint_force: float

    def opening(self) -> float:
        """Current pad-to-pad distance, m."""
        pybullet = pybullet_module()
        states = pybullet.getJointStates(self.body_id, [FINGER_A, FINGER_B], physicsClientId=self.client)
        return float(self.gripper.max_opening - states[0][0] - states[1][0])

    def finger_speed(self) -> float:
        """Largest absolute finger joint speed, m/s."""
        pybullet = pybullet_module()
        states = pybullet.getJointStates(self.body_id, [FINGER_A, FINGER_B], physicsClientId=self.client)
        return float(max(abs(states[0][1]), abs(states[1][1])))

    def reset(self, position: np.ndarray, quaternion: np.ndarray, opening: float) -> None:
        """Teleport the hand at rest to a pose with the fingers at ``opening``.

        Parameters
        ----------
        position : (3,) float
            Gripper-frame origin in the world, m.
        quaternion : (4,) float
            Gripper-frame orientation in the world, (x, y, z, w).
        opening : float
            Pad-to-pad distance, m; clipped to ``[0, max_opening]``.
        """
        pybullet = pybullet_module()
        travel = (self.gripper.max_opening - float(np.clip(opening, 0.0, self.gripper.max_opening))) / 2
        pybullet.resetBasePositionAndOrientation(
            self.body_id, list(map(float, position)), list(map(float, quaternion)), physicsClientId=self.client
        )
        pybullet.resetBaseVelocity(self.body_id, [0, 0, 0], [0, 0, 0], physicsClientId=self.client)
        for finger in (FINGER_A, FINGER_B):
            pybullet.resetJointState(self.body_id, finger, travel, 0.0, physicsClientId=self.client)
        self.move_to(position, quaternion)

    def move_to(self, position: np.ndarray, quaternion: np.ndarray) -> None:
        """Set the target pose the moving constraint pulls the hand to."""
        pybullet = pybullet_module()
        pybullet.changeConstraint(
            self.constraint_id,
            jointChildPivot=list(map(float, position)),
            jointChildFrameOrientation=list(map(float, quaternion)),
            maxForce=self.constraint_force,
            physicsClientId=self.client,
        )

    def close_fingers(self, speed: float, force: float) -> None:
        """Drive both fingers towards fully closed at ``speed`` (m/s each),
        each pushing with at most ``force`` (N).

        Position control towards the closed position (rather than a velocity
        motor) stops the fingers at opening 0 when they meet nothing.
        """
        pybullet = pybullet_module()
        closed = self.gripper.max_opening / 2
        for finger in (FINGER_A, FINGER_B):
            pybullet.setJointMotorControl2(
                self.body_id, finger, pybullet.POSITION_CONTROL, targetPosition=closed,
                maxVelocity=speed, force=force, physicsClientId=self.client,
            )

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """World pose of the gripper frame: position (3,), quaternion (4,) (x, y, z, w)."""
        pybullet = pybullet_module()
        position, quaternion = pybullet.getBasePositionAndOrientation(self.body_id, physicsClientId=self.client)
        return np.asarray(position, dtype=np.float64), np.asarray(quaternion, dtype=np.float64)


#: Pad models of :func:`create_hand`.
PAD_CONTACTS: tuple[str, ...] = ("soft", "rigid")

#: pybullet's collision margin around a convex hull shape, m: the closest
#: distance from a hull is 1 mm shorter than from the box primitive of the
#: same vertices (a box's margin lies inside its extents). The crowned finger
#: is built this much smaller so that its contact surface is the gripper's.
CONVEX_HULL_MARGIN = 0.001


def crowned_finger_vertices(
    gripper: Gripper, half_extents: np.ndarray, inner_sign: float, margin: float = 0.0
) -> np.ndarray:
    """Vertices whose convex hull is a finger with a crowned pad.

    Parameters
    ----------
    gripper : Gripper
        Gives ``pad_radius`` and ``pad_crown``.
    half_extents : (3,) float
        Half extents of the finger box, m (link frame at the box's centre).
    inner_sign : float
        ``+1`` when the pad faces ``+x`` (finger A), ``-1`` for finger B.
    margin : float
        Shrink every face by this much, m (the collision margin the physics
        engine adds back).

    Returns
    -------
    (V, 3) float64
        The box's corners with its inner face moved back by ``pad_crown``,
        then rings of a spherical cap whose apex is at the box's original
        inner face; the cap's radius is ``pad_radius``, or the face's half
        size where that is smaller. Everything is ``margin`` smaller.
    """
    # The crown stays within the finger's face; the torsional law uses pad_radius whatever its size.
    crown, radius = gripper.pad_crown, min(gripper.pad_radius, float(min(half_extents[1:])) - margin)
    inner = half_extents[0] - margin
    corners = np.array([[x, y, z] for x in (-inner, inner - crown) for y in (-1, 1) for z in (-1, 1)],
                       dtype=np.float64)
    corners[:, 1:] *= half_extents[1:] - margin
    sphere = (radius**2 + crown**2) / (2 * crown)
    rings = [np.array([[inner, 0.0, 0.0]])]
    angles = np.linspace(0.0, 2 * np.pi, 16, endpoint=False)
    for ring_radius in np.linspace(radius / 4, radius, 4):
        height = np.sqrt(sphere**2 - ring_radius**2) - (sphere - crown)
        rings.append(np.column_stack([
            np.full(len(angles), inner - crown + height),
            ring_radius * np.cos(angles), ring_radius * np.sin(angles),
        ]))
    vertices = np.concatenate([corners, *rings])
    vertices[:, 0] *= inner_sign
    return vertices


def _finger_shape(client: int, gripper: Gripper, half: np.ndarray, inner_sign: float, pad_contact: str) -> int:
    pybullet = pybullet_module()
    if pad_contact == "rigid":
        return pybullet.createCollisionShape(pybullet.GEOM_BOX, halfExtents=half.tolist(), physicsClientId=client)
    vertices = crowned_finger_vertices(gripper, half, inner_sign, CONVEX_HULL_MARGIN)
    return pybullet.createCollisionShape(pybullet.GEOM_MESH, vertices=vertices.tolist(), physicsClientId=client)


def _pad_dynamics(client: int, body: int, finger: int, gripper: Gripper, friction: float, pad_contact: str) -> None:
    pybullet = pybullet_module()
    if pad_contact == "rigid":
        pybullet.changeDynamics(body, finger, lateralFriction=friction, physicsClientId=client)
        return
    pybullet.changeDynamics(
        body, finger, lateralFriction=friction, spinningFriction=gripper.torsion_radius(), rollingFriction=0.0,
        contactStiffness=gripper.pad_stiffness, contactDamping=gripper.pad_damping, physicsClientId=client,
    )


def create_hand(
    client: int,
    gripper: Gripper,
    *,
    palm_mass: float,
    finger_mass: float,
    finger_friction: float | None = None,
    constraint_force: float,
    pad_contact: str = "soft",
) -> SimulatedHand:
    """Build the hand at the world origin, fully open.

    Parameters
    ----------
    client : int
        pybullet physics client.
    gripper : Gripper
        The one gripper definition; every box comes from ``gripper.boxes``.
    palm_mass, finger_mass : float
        kg.
    finger_friction : float, optional
        Lateral friction of the pads; pybullet multiplies it with the
        object's coefficient. Default: the gripper's ``pad_friction``.
    constraint_force : float
        Force limit of the constraint that moves the hand, N.
    pad_contact : {"soft", "rigid"}
        The pad model (module docstring).
    """
    pybullet = pybullet_module()
    if pad_contact not in PAD_CONTACTS:
        raise ValueError(f"pad_contact {pad_contact!r}: expected one of {', '.join(PAD_CONTACTS)}")
    friction = gripper.pad_friction if finger_friction is None else finger_friction
    boxes = {name: (centre, half) for name, centre, half in gripper.boxes(gripper.max_opening)}
    palm_centre, palm_half = boxes["palm"]
    palm_shape = pybullet.createCollisionShape(
        pybullet.GEOM_BOX, halfExtents=palm_half.tolist(), collisionFramePosition=palm_centre.tolist(),
        physicsClientId=client,
    )
    finger_shapes, finger_positions = [], []
    for name, inner_sign in (("finger_a", 1.0), ("finger_b", -1.0)):
        centre, half = boxes[name]
        finger_shapes.append(_finger_shape(client, gripper, half, inner_sign, pad_contact))
        finger_positions.append(centre.tolist())
    body = pybullet.createMultiBody(
        baseMass=palm_mass,
        baseCollisionShapeIndex=palm_shape,
        # The inertial frame stays at the gripper frame (not at the palm's
        # centre) because pybullet's base pose calls work on the inertial
        # frame; the constraint-driven hand does not need a true centre of mass.
        baseInertialFramePosition=[0.0, 0.0, 0.0],
        linkMasses=[finger_mass, finger_mass],
        linkCollisionShapeIndices=finger_shapes,
        linkVisualShapeIndices=[-1, -1],
        linkPositions=finger_positions,
        linkOrientations=[[0, 0, 0, 1], [0, 0, 0, 1]],
        linkInertialFramePositions=[[0, 0, 0], [0, 0, 0]],
        linkInertialFrameOrientations=[[0, 0, 0, 1], [0, 0, 0, 1]],
        linkParentIndices=[0, 0],
        linkJointTypes=[pybullet.JOINT_PRISMATIC, pybullet.JOINT_PRISMATIC],
        linkJointAxis=[[1, 0, 0], [-1, 0, 0]],
        physicsClientId=client,
    )
    for finger in (FINGER_A, FINGER_B):
        pybullet.changeDynamics(
            body, finger, jointLowerLimit=0.0, jointUpperLimit=gripper.max_opening / 2, physicsClientId=client,
        )
        _pad_dynamics(client, body, finger, gripper, friction, pad_contact)
        # Velocity motors hold the joints still until a trial drives them.
        pybullet.setJointMotorControl2(body, finger, pybullet.VELOCITY_CONTROL, targetVelocity=0.0,
                                       force=gripper.grip_force, physicsClientId=client)
    gear = pybullet.createConstraint(
        body, FINGER_A, body, FINGER_B, pybullet.JOINT_GEAR, [1, 0, 0], [0, 0, 0], [0, 0, 0],
        physicsClientId=client,
    )
    pybullet.changeConstraint(gear, gearRatio=-1, erp=0.1, maxForce=10 * gripper.grip_force, physicsClientId=client)
    mover = pybullet.createConstraint(
        body, -1, -1, -1, pybullet.JOINT_FIXED, [0, 0, 0], [0, 0, 0], [0, 0, 0], physicsClientId=client,
    )
    return SimulatedHand(client, body, mover, gripper, constraint_force)
