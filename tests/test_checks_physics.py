"""The simulated pads obey the textbook: Coulomb slip and soft-finger torsion.

Real pybullet trials, bisected on the grip force (osgd/checks/calibration.py).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh
from helpers import bar_mesh, tool_of_mass
from test_checks import ACROSS_Y, trial

from osgd.checks.calibration import FRICTIONS, coulomb_probe, torsion_probe
from osgd.checks.hand import crowned_finger_vertices
from osgd.checks.params import ChecksStageParams
from osgd.gripper import PANDA

SOFT = ChecksStageParams(pad_contact="soft")
#: The simulated threshold within 15 % of the textbook's.
TOLERANCE = 0.15


def box_model(extents: list[float], mass: float, friction: float) -> dict:
    return tool_of_mass("test/box", trimesh.creation.box(extents=extents), mass, friction)


@pytest.mark.parametrize("mass", [0.2, 1.0])
@pytest.mark.parametrize("friction", FRICTIONS)
def test_a_held_box_slips_exactly_when_the_friction_is_below_its_weight(mass: float, friction: float) -> None:
    side = 0.04
    probe = coulomb_probe(box_model([side, side, side], mass, friction), friction, SOFT, PANDA, side)
    assert abs(probe.error) <= TOLERANCE, probe


@pytest.mark.parametrize("mass", [0.3, 0.6])
@pytest.mark.parametrize("friction", FRICTIONS)
@pytest.mark.parametrize("section", ["square", "round"])
def test_a_bar_held_off_its_centre_turns_when_its_torque_exceeds_the_pads_limit(
    mass: float, friction: float, section: str
) -> None:
    """Flat faces and a round rod alike: the pads' patch, not the object's shape, sets the limit."""
    bar = tool_of_mass("test/bar", bar_mesh(section), mass, friction)
    probe = torsion_probe(bar, friction, 0.04, SOFT, PANDA, 0.015)
    assert abs(probe.error) <= TOLERANCE, probe


def test_the_torsional_limit_follows_the_pad() -> None:
    """A pad half as wide needs twice the force for the same bar: the limit is the pad's, not the solver's."""
    thickness = 0.015
    bar = box_model([0.2, thickness, thickness], 0.3, 0.8)
    full = torsion_probe(bar, 0.8, 0.04, SOFT, PANDA, thickness)
    narrow_pads = dataclasses.replace(PANDA, pad_radius=PANDA.pad_radius / 2)
    narrow = torsion_probe(bar, 0.8, 0.04, SOFT, narrow_pads, thickness)
    assert narrow.measured == pytest.approx(2 * full.measured, rel=TOLERANCE)


def test_the_rigid_pads_of_the_old_check_miss_the_torsional_limit() -> None:
    """The comparison the soft pads were built for: flat rigid boxes are off by far more than 15 %."""
    thickness = 0.015
    bar = box_model([0.2, thickness, thickness], 0.3, 0.4)
    rigid = torsion_probe(bar, 0.4, 0.04, ChecksStageParams(pad_contact="rigid"), PANDA, thickness)
    assert abs(rigid.error) > 0.5, rigid


def test_the_crowned_pad_keeps_the_opening_of_the_flat_finger() -> None:
    half = np.array([PANDA.finger_thickness / 2, PANDA.finger_width / 2, PANDA.finger_depth / 2])
    vertices = crowned_finger_vertices(PANDA, half, 1.0)
    assert vertices[:, 0].max() == pytest.approx(half[0])  # the apex is where the flat face was
    apex_region = vertices[vertices[:, 0] > half[0] - PANDA.pad_crown / 2]
    assert np.abs(apex_region[:, 1:]).max() < PANDA.pad_radius  # the proud part is the patch
    mirrored = crowned_finger_vertices(PANDA, half, -1.0)
    assert mirrored[:, 0].min() == pytest.approx(-half[0])


def test_both_criteria_are_stored_and_the_stage_says_which_one_stable_means() -> None:
    """A block held on the lift but dropped by a violent shake: lift_stable, not shake_stable."""
    block = box_model([0.12, 0.04, 0.04], 0.3, 0.3)
    shaken = ChecksStageParams(shake_distance=0.2)  # a 13 g shake
    lift = trial(block, [0.0, 0.0, 0.0], ACROSS_Y, 0.05,
                 shaken.model_copy(update={"criterion": "lift", "store_shake": True}))
    shake = trial(block, [0.0, 0.0, 0.0], ACROSS_Y, 0.05, shaken.model_copy(update={"criterion": "shake"}))
    assert (lift.lift_stable, lift.shake_stable, lift.fail_reason) == (True, False, "dropped_on_shake")
    assert (shake.lift_stable, shake.shake_stable) == (True, False)
    assert lift.stable and not shake.stable


def test_a_light_thin_object_stays_between_the_pads_when_its_trial_runs_at_a_finer_step() -> None:
    # A 4 g bar, 4.7 mm thick (the authors' pen_003), pinched across its thickness by 70 N: friction holds it
    # against any shake. At 1/240 s the 0.1 kg fingers squeeze it out of the grasp; with max_mass_ratio the
    # trial runs at a third of the step, and it is held.
    bar = box_model([0.12, 0.0047, 0.0087], 0.004, 0.5)
    coarse_params = SOFT.model_copy(update={"store_shake": True})
    coarse = [trial(bar, [offset, 0.0, 0.0], ACROSS_Y, 0.03, coarse_params) for offset in (-0.03, 0.0, 0.03)]
    fine_params = SOFT.model_copy(update={"max_mass_ratio": 10.0, "store_shake": True})
    fine = [trial(bar, [offset, 0.0, 0.0], ACROSS_Y, 0.03, fine_params) for offset in (-0.03, 0.0, 0.03)]
    assert not any(result.lift_stable and result.shake_stable for result in coarse)
    assert all(result.shake_stable is not None for result in coarse)
    assert all(result.lift_stable and result.shake_stable for result in fine)
    assert fine[0].sim_steps > 2 * coarse[0].sim_steps


def test_only_light_objects_get_a_finer_step() -> None:
    from osgd.checks.trial import trial_params  # noqa: PLC0415

    params = SOFT.model_copy(update={"max_mass_ratio": 10.0})  # fingers of 0.1 kg: objects under 10 g
    assert trial_params(params, 0.02) is params
    assert trial_params(params, 0.01) is params
    assert trial_params(params, 0.004).timestep == pytest.approx(params.timestep / 3)
    assert trial_params(SOFT, 0.004) is SOFT  # off by default: the procedural pipelines keep their keys
    assert "max_mass_ratio" not in SOFT.key_dict()
