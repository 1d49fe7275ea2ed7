"""The checks stage's parameters: the ``[checks]`` section of a pipeline config.

Every threshold and duration of the grasp trial (:mod:`osgd.checks.trial`)
is here, with its default and where that default comes from; ``docs/checks.md``
explains the trial they parameterise. Lengths in metres, angles in radians,
times in seconds, forces in newtons.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from osgd.stage import StageParams


class ChecksStageParams(StageParams):
    """Parameters of the simulated grasp trial."""

    # -- simulation --------------------------------------------------------
    timestep: float = Field(
        1.0 / 240.0, gt=0.0, le=0.02, description="seconds per physics step (pybullet's default 1/240 s)"
    )
    solver_iterations: int = Field(
        100, ge=1, le=300,
        description="constraint solver iterations per step (pybullet's default is 50); with fewer the motors "
        "fall short of their force limit on light thin objects (pens, forks) and a pad sinks into the hull "
        "(docs/checks.md)",
    )
    max_mass_ratio: float = Field(
        0.0, ge=0.0, json_schema_extra={"omit_default": True},
        description="above 0: a trial of an object lighter than finger_mass / max_mass_ratio runs at "
        "timestep / ceil(finger_mass / (max_mass_ratio x mass)), so that the solver never resolves a pinch "
        "across a larger mass ratio per step (Bullet's manual: keep mass ratios near 1:10); at 1/240 s a pen of a "
        "few grams squirts out from between the 0.1 kg fingers (docs/checks.md); 0: the timestep for every "
        "object",
    )
    contact_erp: float | None = Field(
        0.8, gt=0.0, le=1.0,
        description="pybullet's contactERP, the share of contact penetration corrected per step; None keeps "
        "pybullet's default (0.2). 0.8 keeps the pads from sinking through light thin objects under the "
        "grip force (docs/checks.md)",
    )
    gravity: float = Field(9.81, ge=0.0, description="magnitude of gravity once the hand has closed, m/s^2")
    # -- the hand ------------------------------------------------------------
    finger_friction: float | None = Field(
        None, gt=0.0, le=5.0,
        description="lateral friction of the finger pads; None takes the gripper's pad_friction (1.0, "
        "osgd.gripper): pybullet multiplies it with the object's, so 1.0 leaves the models table's friction "
        "in charge",
    )
    pad_contact: Literal["soft", "rigid"] = Field(
        "soft",
        description="'soft': crowned rubber pads with torsional friction and compliance, the soft-finger contact "
        "of osgd.gripper; 'rigid': flat rigid boxes with no torsional friction "
        "(docs/checks.md)",
    )
    palm_mass: float = Field(0.5, gt=0.0, description="mass of the palm, kg")
    finger_mass: float = Field(
        0.1, gt=0.0,
        description="mass of each finger, kg; heavier than a real pad (~20 g) because with light fingers the "
        "solver does not bring the motor to its force limit (docs/checks.md)",
    )
    grip_force: float | None = Field(
        None, gt=0.0,
        description="force limit of each finger, N; None takes the gripper's grip_force (70 N, osgd.gripper)",
    )
    hand_force: float = Field(
        500.0, gt=0.0, description="force limit of the constraint that moves the hand along its path, N"
    )
    # -- approach ------------------------------------------------------------
    approach_distance: float = Field(
        0.05, ge=0.0, le=0.5,
        description="the pre-grasp pose is backed off this far against the approach direction, m",
    )
    approach_spacing: float = Field(
        0.002, gt=0.0, le=0.02,
        description="distance between the poses tested for collision along the approach, m",
    )
    approach_penetration: float = Field(
        0.002, ge=0.0, le=0.01,
        description="penetration of the object into the hand tolerated on the approach, m (the grasps stage "
        "accepts 1 mm; 2 mm leaves room for pybullet's hull of the convex parts)",
    )
    approach_geometry: Literal["auto", "hulls", "mesh"] = Field(
        "auto", json_schema_extra={"omit_default": True},
        description="what the approach sweep tests the hand against: 'hulls', the convex parts pybullet "
        "simulates, or 'mesh', samples of the model's own surface (one per approach_surface_spacing^2 of area "
        "plus every vertex), as the grasps stage's collision test; 'auto': 'mesh' for users' meshes, 'hulls' "
        "for the others: the hulls are larger than the mesh, so most grasps that fail the approach on the hulls "
        "are free of the mesh (docs/checks.md, docs/models.md)",
    )
    approach_surface_spacing: float = Field(
        0.001, gt=0.0, le=0.005, json_schema_extra={"omit_default": True},
        description="nominal distance between the surface samples of the 'mesh' approach test, m; a finger "
        "is 10 mm thick, so a surface crossing it leaves samples inside",
    )
    # -- closing -------------------------------------------------------------
    close_speed: float = Field(0.2, gt=0.0, description="speed of each finger while closing, m/s")
    close_duration: float = Field(
        0.3, gt=0.0, description="longest time given to the fingers to close, s (they stop earlier once still)"
    )
    settle_speed: float = Field(
        0.002, gt=0.0, description="the fingers count as closed once both move slower than this, m/s"
    )
    contact_distance: float = Field(
        0.001, ge=0.0, le=0.01,
        description="a finger touches the object when their closest distance is at most this, m",
    )
    min_opening: float = Field(
        0.001, ge=0.0,
        description="an object counts as between the pads only while they are at least this far apart, m",
    )
    # -- lift ----------------------------------------------------------------
    lift_height: float = Field(
        0.10, ge=0.0, description="how far the hand rises after closing, m (VGN's 10 cm, REFERENCE section 5)"
    )
    lift_duration: float = Field(0.25, gt=0.0, description="time taken by the lift, s")
    hold_duration: float = Field(
        0.1, ge=0.0,
        description="longest time the hand stays still after the lift, s (it ends earlier once the object is "
        "still in the hand, hold_still_duration)",
    )
    hold_still_duration: float = Field(
        1.0 / 30.0, ge=0.0,
        description="the hold ends early once the object's pose in the hand has stayed within "
        "hold_still_distance and hold_still_rotation for this long, s (tested at the trial's grip-test "
        "interval, osgd.checks.trial); 0 always holds hold_duration",
    )
    hold_still_distance: float = Field(
        1e-4, ge=0.0,
        description="the object counts as still in the hand while its centre of mass has moved less than this "
        "relative to the hand, m (0.1 mm, far inside max_slip_distance)",
    )
    hold_still_rotation: float = Field(
        0.002, ge=0.0,
        description="and has turned less than this relative to the hand, rad (0.1 deg, far inside "
        "max_slip_rotation)",
    )
    # -- shake ---------------------------------------------------------------
    shake_distance: float = Field(
        0.02, ge=0.0,
        description="amplitude of each linear shake, m (with the default period a peak acceleration of "
        "about 1.3 g)",
    )
    shake_angle: float = Field(
        0.35, ge=0.0, le=3.2, description="amplitude of each rotational shake about the grasp centre, rad (20 deg)"
    )
    shake_period: float = Field(
        0.25, gt=0.0,
        description="duration of one shake: one full sine period along one axis, s; three linear and three "
        "rotational shakes follow each other",
    )
    # -- success -------------------------------------------------------------
    criterion: Literal["lift", "shake"] = Field(
        "lift",
        description="what the checks table's 'stable' means: 'lift' (closed, lifted and held, the paper's "
        "check) or 'shake' (held through the shakes too, as ACRONYM); both outcomes are stored where the "
        "shakes run (store_shake, docs/checks.md)",
    )
    store_shake: bool = Field(
        False, json_schema_extra={"omit_default": True},
        description="under criterion 'lift', run the shakes as well and store their outcome in shake_stable; "
        "false skips them, since they cannot change 'stable' under 'lift': shake_stable is then null for the "
        "grasps held on the lift, and their trials are a fifth as long; criterion 'shake' always runs them",
    )
    max_slip_distance: float = Field(
        0.02, ge=0.0,
        description="largest displacement of the object's centre of mass relative to the hand for a held "
        "grasp, m",
    )
    max_slip_rotation: float = Field(
        0.35, ge=0.0, le=3.2,
        description="largest rotation of the object relative to the hand for a held grasp, rad (20 deg)",
    )

    @property
    def shakes(self) -> bool:
        """Whether a trial held on the lift goes on to the shakes."""
        return self.criterion == "shake" or self.store_shake

    def approach_for(self, source: str | None) -> Literal["hulls", "mesh"]:
        """The approach geometry of a model from ``source`` (models' ``source`` column): ``auto`` resolved."""
        if self.approach_geometry != "auto":
            return self.approach_geometry
        return "mesh" if source == "user" else "hulls"
