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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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
    """

    max_opening: float = 0.08
    finger_width: float = 0.02
    finger_depth: float = 0.045
    finger_thickness: float = 0.01
    palm_width: float = 0.06
    palm_thickness: float = 0.03
    clearance: float = 0.01
    grip_force: float = 70.0

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


#: The default gripper, close to a Franka Emika Panda hand.
PANDA = Gripper()
