"""The one definition of the parallel-jaw gripper.

Used by the annotate stage (collision-free approaches), the check stage (the
simulated gripper), the render stage (rectangle size, gripper collision with
the pile) and the robot evaluation.

Gripper frame
-------------
Right-handed, origin at the grasp centre (midway between the two finger pads):

- ``x``: the closing axis, from finger A towards finger B;
- ``z``: the approach axis, from the palm towards the object (the gripper
  moves along +z to reach the grasp);
- ``y``: ``z x x``, across the finger pads (the rectangle's ``w``).

The default dimensions are close to a Franka Emika Panda hand (maximum
opening 0.08 m, as ACRONYM's gripper; REFERENCE section 5).

Finger pads
-----------
A real fingertip is a rubber patch, not a rigid box: pressed on an object it
flattens into a contact patch that resists sliding (Coulomb friction) and
twisting about the closing axis (torsional friction). The grasping textbooks
call this a *soft-finger contact* (Murray, Li and Sastry, *A Mathematical
Introduction to Robotic Manipulation*, 1994, section 5.2): a point contact
with friction whose torque about the contact normal is bounded by
``|tau| <= gamma * N``. For a patch of radius ``a`` under uniform pressure
``gamma = (2/3) * mu * a`` (Johnson, *Contact Mechanics*, 1985, section 5.1,
the torque of a sliding disc), which :meth:`Gripper.torsion_radius` gives.

The pad data:

- ``pad_radius`` 10 mm: the patch is the disc inscribed in the 20 mm wide
  Franka Hand fingertip (Franka Emika, *Franka Hand product manual*:
  fingertips 20 mm wide, 70 N continuous and 140 N peak force). Its
  ``(2/3) a`` = 6.7 mm lies between a line contact across the pad (5 mm)
  and the whole 20 x 20 mm pad pressed flat (7.7 mm);
- ``pad_friction`` 1.0: pybullet multiplies the two bodies' coefficients, so
  1.0 leaves the pair coefficient stored per object in the ``models`` table
  (0.3 to 0.8 by material, ``osgd/models/categories.py``) in charge. The
  payload rule of gripper makers is the same Coulomb law the checks tests
  verify: Robotiq's *Hand-E instruction manual*, section 6, "W = 2 F Cf /
  Sf", with Cf 0.3 tested for its silicone fingertips on oily steel;
- ``pad_stiffness`` 4.7e5 N/m: a 2 mm rubber layer of Young's modulus 3 MPa
  (Shore 60A) over the patch's area, ``k = E * pi * a**2 / t``; at 70 N the
  pad gives 0.15 mm;
- ``pad_damping`` 430 N s/m: about critical for the 0.1 kg simulated finger
  on that spring, ``2 * sqrt(k * m)``;
- ``pad_crown`` 0.5 mm: the patch stands this far proud of the finger's flat
  face, a crowned pad, so that the contact sits at the patch and carries its
  torsional friction (a flat rigid face on a flat face or a round shaft
  touches at its corners or along a line instead).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The corners of the box ``[-1, 1]^3``, x slowest: a box's corners are ``centre + half * UNIT_BOX_CORNERS``.
UNIT_BOX_CORNERS = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])


@dataclass(frozen=True)
class Gripper:
    """A parallel-jaw gripper; every length in metres, force in newtons.

    Attributes
    ----------
    max_opening : float
        Largest distance between the finger pads.
    finger_width : float
        Extent of a finger pad along the gripper ``y`` axis; the rectangle's
        ``w`` in the image.
    finger_depth : float
        Extent of a finger along the approach axis ``z``, from its tip to the
        palm.
    finger_thickness : float
        Extent of a finger along the closing axis ``x``.
    palm_width : float
        Extent of the palm along ``y``.
    palm_thickness : float
        Extent of the palm along ``z``.
    clearance : float
        Opening added to the contact distance when a grasp is pre-shaped.
    grip_force : float
        Force limit of each finger when closing. The default is the Franka
        Emika Panda hand's rated continuous force (70 N; 140 N peak). At
        40 N the check stage dropped most grasps of objects over 0.5 kg.
    pad_radius : float
        Radius of each pad's contact patch, m.
    pad_crown : float
        How far the patch's centre stands proud of the finger's inner face, m.
    pad_friction : float
        Lateral friction coefficient of the pads (a multiplier of the
        object's coefficient in pybullet).
    pad_stiffness : float
        Normal stiffness of a pad, N/m.
    pad_damping : float
        Normal damping of a pad, N s/m.
    """

    max_opening: float = 0.08
    finger_width: float = 0.02
    finger_depth: float = 0.045
    finger_thickness: float = 0.01
    palm_width: float = 0.06
    palm_thickness: float = 0.03
    clearance: float = 0.01
    grip_force: float = 70.0
    pad_radius: float = 0.010
    pad_crown: float = 0.0005
    pad_friction: float = 1.0
    pad_stiffness: float = 4.7e5
    pad_damping: float = 430.0

    def torsion_radius(self) -> float:
        """The soft-finger torsional coefficient per unit friction coefficient, m.

        A pad pressed with normal force ``N`` on an object of friction
        coefficient ``mu`` resists a torque about the closing axis of at most
        ``mu * torsion_radius() * N``: ``(2/3) * pad_radius``, a disc under
        uniform pressure.
        """
        return 2.0 * self.pad_radius / 3.0

    def torsional_limit(self, friction: float, grip_force: float | None = None) -> float:
        """Largest torque about the closing axis the two pads hold, N m.

        Parameters
        ----------
        friction : float
            The pad-object friction coefficient.
        grip_force : float, optional
            Normal force of each pad, N; the gripper's ``grip_force`` by default.
        """
        force = self.grip_force if grip_force is None else grip_force
        return 2.0 * friction * self.pad_friction * self.torsion_radius() * force

    def boxes(self, opening: float) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """Collision boxes of the gripper pre-shaped to ``opening``.

        Parameters
        ----------
        opening : float
            Distance between the finger pads, metres; clipped to
            ``[0, max_opening]``.

        Returns
        -------
        list of (name, centre, half_extents)
            ``name`` is ``"finger_a"``, ``"finger_b"`` or ``"palm"``;
            ``centre`` (3,) float64 and ``half_extents`` (3,) float64 are in
            the gripper frame.
        """
        opening = float(np.clip(opening, 0.0, self.max_opening))
        finger_half = np.array(
            [self.finger_thickness / 2, self.finger_width / 2, self.finger_depth / 2]
        )
        # The pads' inner faces sit at x = -/+ opening/2; the finger tips at
        # z = +finger_depth/2 so the grasp centre is mid-way down the pads.
        finger_x = opening / 2 + self.finger_thickness / 2
        finger_z = 0.0
        palm_span = opening + 2 * self.finger_thickness
        palm_half = np.array([palm_span / 2, self.palm_width / 2, self.palm_thickness / 2])
        palm_z = -(self.finger_depth / 2 + self.palm_thickness / 2)
        return [
            ("finger_a", np.array([-finger_x, 0.0, finger_z]), finger_half),
            ("finger_b", np.array([finger_x, 0.0, finger_z]), finger_half.copy()),
            ("palm", np.array([0.0, 0.0, palm_z]), palm_half),
        ]

    def box_corners(self, openings: np.ndarray) -> np.ndarray:
        """The corners of the boxes of :meth:`boxes`, for many openings at once.

        Value for value the corners ``centre + half * (+-1, +-1, +-1)`` of
        ``boxes(opening)`` for each opening, with the same operations
        (one call per grasp is slow; the whole set is computed at once).

        Parameters
        ----------
        openings : (G,) float
            Metres; clipped to ``[0, max_opening]``.

        Returns
        -------
        (G, 24, 3) float64
            Gripper frame: the 8 corners of finger A, finger B and the palm,
            each in the order of :data:`UNIT_BOX_CORNERS`.
        """
        openings = np.clip(np.asarray(openings, dtype=np.float64).reshape(-1), 0.0, self.max_opening)
        count = len(openings)
        centres = np.zeros((count, 3, 3))
        centres[:, 1, 0] = openings / 2 + self.finger_thickness / 2
        centres[:, 0, 0] = -centres[:, 1, 0]
        centres[:, 2, 2] = -(self.finger_depth / 2 + self.palm_thickness / 2)
        halves = np.empty((count, 3, 3))
        halves[:, :2] = [self.finger_thickness / 2, self.finger_width / 2, self.finger_depth / 2]
        halves[:, 2, 0] = (openings + 2 * self.finger_thickness) / 2
        halves[:, 2, 1:] = [self.palm_width / 2, self.palm_thickness / 2]
        return (centres[:, :, None, :] + halves[:, :, None, :] * UNIT_BOX_CORNERS).reshape(count, 24, 3)


#: The default gripper, close to a Franka Emika Panda hand.
PANDA = Gripper()
