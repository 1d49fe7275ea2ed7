"""Textbook probes of the simulated hand: when a held box slips, when a held bar turns.

Two experiments with closed-form answers measure the pad contact of
:mod:`osgd.checks.hand` (``tests/test_checks_physics.py`` asserts them,
``python -m osgd.checks.validate --physics`` prints them for both pad models):

- **Coulomb slip.** A box held between the pads by its middle, lifted slowly
  and held: it stays when ``2 * mu * F >= m * g`` and slips otherwise. The
  probe finds the smallest grip force ``F`` that holds, by bisection, and
  compares it with ``m * g / (2 * mu)``.
- **Torsional slip.** A bar held at a distance ``d`` from its centre of mass,
  across its thickness, with the closing axis horizontal: gravity twists it
  about the closing axis with ``m * g * d``, which only the pads' torsional
  friction resists (:meth:`osgd.gripper.Gripper.torsional_limit`). The probe
  finds the smallest grip force that holds and compares it with
  ``m * g * d / (2 * mu * torsion_radius)``.

Both use the ``lift`` criterion with a slow lift (a peak acceleration of
1 % of g) and a long hold, so the load is the object's weight alone.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from osgd.checks.params import ChecksStageParams
from osgd.checks.trial import run_trial
from osgd.gripper import Gripper

#: The slow lift and long hold of the probes: 2 cm in 1 s, then 0.5 s still.
PROBE_OVERRIDES: dict[str, Any] = {"lift_height": 0.02, "lift_duration": 1.0, "hold_duration": 0.5}

#: Pad-object friction coefficients and masses the tests probe.
FRICTIONS: tuple[float, ...] = (0.4, 0.8)


@dataclass(frozen=True)
class Probe:
    """The threshold grip force of one experiment.

    Attributes
    ----------
    expected : float
        The closed-form force at which the object starts to slip, N.
    measured : float
        The smallest grip force the simulation holds it with, N (bisection
        to 1 % of ``expected``).
    """

    expected: float
    measured: float

    @property
    def error(self) -> float:
        """Relative error of the measured threshold."""
        return self.measured / self.expected - 1.0


def _top_down_across_y() -> np.ndarray:
    """Gripper quaternion in the object frame: approach along -z, closing across y."""
    x = np.array([0.0, 1.0, 0.0])
    z = np.array([0.0, 0.0, -1.0])
    return Rotation.from_matrix(np.column_stack([x, np.cross(z, x), z])).as_quat()


def threshold_force(holds: Callable[[float], bool], expected: float, tolerance: float = 0.01) -> float:
    """Smallest grip force that ``holds``, by bisection on ``[expected / 4, 4 * expected]``.

    Returns
    -------
    float
        The force, N; ``4 * expected`` (or ``expected / 4``) when the object
        is never (or always) held in the bracket.
    """
    low, high = expected / 4, expected * 4
    if holds(low):
        return low
    if not holds(high):
        return high
    while high - low > tolerance * expected:
        middle = (low + high) / 2
        low, high = (low, middle) if holds(middle) else (middle, high)
    return high


def _holds(model: Mapping[str, Any], centre: np.ndarray, width: float, params: ChecksStageParams,
           gripper: Gripper) -> Callable[[float], bool]:
    quaternion = _top_down_across_y()

    def holds(force: float) -> bool:
        probe = params.model_copy(update={**PROBE_OVERRIDES, "grip_force": force, "criterion": "lift"})
        result = run_trial(model, centre, quaternion, width, probe, gripper, np.random.default_rng(0))
        return result.lift_stable

    return holds


def coulomb_probe(box: Mapping[str, Any], friction: float, params: ChecksStageParams, gripper: Gripper,
                  thickness: float, gravity: float = 9.81) -> Probe:
    """Threshold grip force of a box held by its middle (module docstring).

    Parameters
    ----------
    box : mapping
        A ``models`` row of a box centred on its origin, ``thickness`` across y.
    friction : float
        Its lateral friction (the pair coefficient with pads of friction 1).
    """
    expected = float(box["mass"]) * gravity / (2 * friction * gripper.pad_friction)
    holds = _holds(box, np.zeros(3), thickness + 0.02, params, gripper)
    return Probe(expected, threshold_force(holds, expected))


def torsion_probe(bar: Mapping[str, Any], friction: float, offset: float, params: ChecksStageParams,
                  gripper: Gripper, thickness: float, gravity: float = 9.81) -> Probe:
    """Threshold grip force of a bar along x held ``offset`` m from its centre (module docstring)."""
    torque = float(bar["mass"]) * gravity * offset
    expected = torque / gripper.torsional_limit(friction, grip_force=1.0)
    holds = _holds(bar, np.array([offset, 0.0, 0.0]), thickness + 0.02, params, gripper)
    return Probe(expected, threshold_force(holds, expected))
