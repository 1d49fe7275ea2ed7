"""Mass, centre of mass and inertia of a model from its volume and density.

A closed mesh (watertight, consistent winding) gives them exactly through its
own volume integrals. An open mesh (many authored models are surface soups)
has no volume; its mass properties then come from the convex parts of its
collision compound, which is also what the physics engine simulates.

Either estimate assumes a solid of one density; an authored mesh that is
bulkier than the real tool (thick pliers handles, hulls that fill the gap
between them) would weigh several times the real thing. :func:`clamp_mass`
brings the mass into the category's real range, lowering or raising the
effective density uniformly, so the centre of mass stays and the inertia
scales with the mass.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh


@dataclass(frozen=True)
class MassProperties:
    """Rigid-body properties in the object frame.

    Attributes
    ----------
    mass : float
        kg.
    center_of_mass : (3,) float64
        Object frame, m.
    inertia : (3, 3) float64
        About the centre of mass, object axes, kg m^2.
    volume : float
        m^3.
    source : str
        ``"mesh"`` or ``"convex_parts"``.
    """

    mass: float
    center_of_mass: np.ndarray
    inertia: np.ndarray
    volume: float
    source: str


def _shifted_inertia(inertia_about_own_centre: np.ndarray, mass: float, offset: np.ndarray) -> np.ndarray:
    """Parallel-axis theorem: inertia about a point ``offset`` away from the body's centre of mass."""
    return inertia_about_own_centre + mass * (float(offset @ offset) * np.eye(3) - np.outer(offset, offset))


def mesh_mass_properties(mesh: trimesh.Trimesh, density: float) -> MassProperties:
    """Mass properties of a closed mesh of uniform ``density`` (kg/m^3, mesh in metres)."""
    mesh = mesh.copy()
    mesh.density = density
    return MassProperties(
        mass=float(mesh.mass),
        center_of_mass=np.asarray(mesh.center_mass, dtype=np.float64),
        inertia=np.asarray(mesh.moment_inertia, dtype=np.float64),
        volume=float(mesh.volume),
        source="mesh",
    )


def compound_mass_properties(parts: list[trimesh.Trimesh], density: float) -> MassProperties:
    """Mass properties of a union of convex parts, overlaps ignored (coacd cuts, so they barely overlap).

    Parameters
    ----------
    parts : list of trimesh.Trimesh
        Convex, closed, metres.
    density : float
        kg/m^3.
    """
    hulls = [part if part.is_volume else part.convex_hull for part in parts]
    hulls = [hull for hull in hulls if hull.volume > 0]
    if not hulls:
        raise ValueError("no convex part has a positive volume")
    masses = np.array([density * hull.volume for hull in hulls])
    centres = np.array([hull.center_mass for hull in hulls])
    total = float(masses.sum())
    centre = (masses[:, None] * centres).sum(axis=0) / total
    inertia = np.zeros((3, 3))
    for hull, mass, own_centre in zip(hulls, masses, centres, strict=True):
        # trimesh's moment_inertia is about the part's own centre of mass, for density 1.
        inertia += _shifted_inertia(hull.moment_inertia * density, float(mass), own_centre - centre)
    return MassProperties(total, centre, inertia, float(sum(hull.volume for hull in hulls)), "convex_parts")


def clamp_mass(properties: MassProperties, mass_range: tuple[float, float]) -> tuple[MassProperties, str | None]:
    """The properties with the mass clamped into ``mass_range`` (kg).

    Returns
    -------
    MassProperties
        Unchanged when the mass is inside the range; else the same body with
        a uniformly scaled density: mass clamped, inertia scaled with it.
    str or None
        A note saying what was clamped, or None.
    """
    low, high = mass_range
    target = float(np.clip(properties.mass, low, high))
    if target == properties.mass:
        return properties, None
    factor = target / properties.mass
    note = (f"mass {properties.mass:.3f} kg from the {properties.source.replace('_', ' ')} is outside the real "
            f"range {low:g}-{high:g} kg; clamped to {target:.3f} kg (effective density x{factor:.2f})")
    return MassProperties(target, properties.center_of_mass, properties.inertia * factor, properties.volume,
                          properties.source), note
