"""A procedural generator of the 10 tool categories, with a part label on every face.

Each category has a builder that draws a handful of shape parameters
(lengths, widths, profiles, head shapes, tine counts, jaw shapes...) from a
``numpy.random.Generator`` and returns convex *primitives*, each tagged with
a part name from :data:`osgd.contract.taxonomy.PARTS` and a sign (added or carved
out). :func:`generate` joins the primitives with manifold3d booleans, which
gives a watertight, single-body mesh, and labels each face with the part of
the primitive whose surface it lies on.

Frame of every generated tool: metres, the tool's long axis along x (handle
at -x, working end at +x), its width along y, its thickness along z, the
origin at the centre of the bounding box. The longest extent is the length
drawn from the category's real-size range (:mod:`osgd.models.categories`).

Every part is at least :data:`MIN_THICKNESS` thick so that physics contact
margins and the depth renderer still see it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
import trimesh

from osgd.contract.taxonomy import CATEGORIES, PART_INDEX
from osgd.models.categories import draw_length

#: The thinnest any part may be, metres (REFERENCE section 8: a 4 mm fork is
#: already hard for the physics gripper; much thinner parts vanish).
MIN_THICKNESS: Final[float] = 0.0032


@dataclass(frozen=True)
class Primitive:
    """A convex solid of a tool, in the tool frame (metres).

    Attributes
    ----------
    part : str
        A name from :data:`osgd.contract.taxonomy.PARTS`.
    mesh : trimesh.Trimesh
        Convex and watertight.
    carve : bool
        True when the solid is cut out of the tool instead of added.
    """

    part: str
    mesh: trimesh.Trimesh
    carve: bool = False


@dataclass
class ProceduralModel:
    """A generated tool.

    Attributes
    ----------
    mesh : trimesh.Trimesh
        Watertight, metres, tool frame (see the module docstring).
    face_parts : (F,) int8
        Index into :data:`osgd.contract.taxonomy.PARTS` per face.
    parameters : dict
        The shape parameters drawn, JSON-able (for provenance).
    """

    mesh: trimesh.Trimesh
    face_parts: np.ndarray
    parameters: dict[str, Any] = field(default_factory=dict)


# -- convex building blocks ---------------------------------------------------------------


def _box(size_x: float, size_y: float, size_z: float, centre: tuple[float, float, float]) -> trimesh.Trimesh:
    return trimesh.creation.box(
        extents=[size_x, size_y, size_z], transform=trimesh.transformations.translation_matrix(centre)
    )


def _cylinder_x(
    x_start: float,
    x_end: float,
    radius_y: float,
    radius_z: float,
    sections: int = 16,
    y: float = 0.0,
    z: float = 0.0,
) -> trimesh.Trimesh:
    """An elliptic cylinder along x from ``x_start`` to ``x_end``."""
    mesh = trimesh.creation.cylinder(radius=1.0, height=x_end - x_start, sections=sections)
    mesh.apply_scale([radius_z, radius_y, 1.0])
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    mesh.apply_translation([(x_start + x_end) / 2, y, z])
    return mesh


def _cylinder_z(
    radius: float, height: float, centre: tuple[float, float, float], sections: int = 24
) -> trimesh.Trimesh:
    mesh = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    mesh.apply_translation(centre)
    return mesh


def _cylinder_y(
    radius: float, height: float, centre: tuple[float, float, float], sections: int = 20
) -> trimesh.Trimesh:
    mesh = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    mesh.apply_translation(centre)
    return mesh


def _hull(points: np.ndarray) -> trimesh.Trimesh:
    return trimesh.convex.convex_hull(np.asarray(points, dtype=np.float64))


def _slab(outline_xy: np.ndarray, thickness: float, z: float = 0.0) -> trimesh.Trimesh:
    """The convex hull of a 2-D outline (in x, y) extruded to ``thickness`` along z."""
    outline_xy = np.asarray(outline_xy, dtype=np.float64)
    low = np.column_stack([outline_xy, np.full(len(outline_xy), z - thickness / 2)])
    high = np.column_stack([outline_xy, np.full(len(outline_xy), z + thickness / 2)])
    return _hull(np.vstack([low, high]))


def _ellipse_section(x: float, half_width: float, half_thickness: float, count: int = 12, z: float = 0.0) -> np.ndarray:
    """Points of an ellipse in the plane x = const."""
    angles = np.linspace(0.0, 2 * np.pi, count, endpoint=False)
    return np.column_stack([np.full(count, x), half_width * np.cos(angles), z + half_thickness * np.sin(angles)])


def _tapered_bar(
    x_start: float,
    x_end: float,
    widths: tuple[float, float],
    thicknesses: tuple[float, float],
    z: tuple[float, float] = (0.0, 0.0),
    count: int = 12,
) -> trimesh.Trimesh:
    """A convex bar with elliptic sections, tapering linearly from x_start to x_end."""
    return _hull(
        np.vstack(
            [
                _ellipse_section(x_start, widths[0] / 2, thicknesses[0] / 2, count, z[0]),
                _ellipse_section(x_end, widths[1] / 2, thicknesses[1] / 2, count, z[1]),
            ]
        )
    )


def _uniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(rng.uniform(low, high))


# -- one builder per category -------------------------------------------------------------
# Each takes the drawn length (m) and the rng, and returns (primitives, parameters).
# The handle starts at x = 0 and the working end reaches x = length.

Builder = Callable[[float, np.random.Generator], tuple[list[Primitive], dict[str, Any]]]


def _knife(length: float, rng: np.random.Generator) -> tuple[list[Primitive], dict[str, Any]]:
    handle_length = length * _uniform(rng, 0.36, 0.48)
    handle_width = _uniform(rng, 0.016, 0.026)
    handle_thickness = _uniform(rng, 0.010, 0.017)
    blade_height = _uniform(rng, 0.014, 0.038)
    blade_thickness = _uniform(rng, MIN_THICKNESS, 0.0045)
    tip = str(rng.choice(["pointed", "rounded", "spear"]))
    guard = bool(rng.random() < 0.4)
    x0, h = handle_length - 0.004, blade_height / 2
    if tip == "pointed":
        outline = [(x0, -h), (x0, h), (length, 0.7 * h), (length - 0.4 * (length - x0), -h)]
    elif tip == "rounded":
        angles = np.linspace(-np.pi / 2, np.pi / 2, 9)
        arc = [(length - h + h * np.cos(a), h * np.sin(a)) for a in angles]
        outline = [(x0, -h), (x0, h), *arc]
    else:
        outline = [
            (x0, -h),
            (x0, h),
            (length - 1.2 * blade_height, h),
            (length, 0.0),
            (length - 1.2 * blade_height, -h),
        ]
    primitives = [
        Primitive(
            "handle",
            _tapered_bar(
                0.0, handle_length, (handle_width, handle_width * 0.9), (handle_thickness, handle_thickness * 0.85)
            ),
        ),
        Primitive("blade", _slab(np.array(outline), blade_thickness)),
    ]
    if guard:
        primitives.append(
            Primitive(
                "handle",
                _box(
                    0.006,
                    max(blade_height, handle_width) + 0.006,
                    handle_thickness * 1.1,
                    (handle_length - 0.003, 0, 0),
                ),
            )
        )
    return primitives, {
        "handle_length": handle_length,
        "handle_width": handle_width,
        "blade_height": blade_height,
        "blade_thickness": blade_thickness,
        "tip": tip,
        "guard": guard,
    }


def _screwdriver(length: float, rng: np.random.Generator) -> tuple[list[Primitive], dict[str, Any]]:
    handle_length = length * _uniform(rng, 0.36, 0.5)
    handle_radius = _uniform(rng, 0.011, 0.018)
    sections = int(rng.choice([6, 8, 16]))
    shaft_radius = _uniform(rng, 0.0025, 0.004)
    tip_length = _uniform(rng, 0.007, 0.014)
    tip = str(rng.choice(["flat", "cross"]))
    flange = bool(rng.random() < 0.5)
    primitives = [
        Primitive("handle", _cylinder_x(0.0, handle_length, handle_radius, handle_radius, sections)),
        Primitive(
            "shaft", _cylinder_x(handle_length - 0.01, length - tip_length + 0.001, shaft_radius, shaft_radius, 12)
        ),
    ]
    if flange:
        primitives.append(
            Primitive(
                "handle",
                _cylinder_x(handle_length - 0.004, handle_length + 0.002, handle_radius * 0.8, handle_radius * 0.8, 16),
            )
        )
    base = _ellipse_section(length - tip_length, shaft_radius, shaft_radius, 12)
    if tip == "flat":
        end = np.array(
            [
                [length, shaft_radius * 1.15, MIN_THICKNESS / 2],
                [length, shaft_radius * 1.15, -MIN_THICKNESS / 2],
                [length, -shaft_radius * 1.15, MIN_THICKNESS / 2],
                [length, -shaft_radius * 1.15, -MIN_THICKNESS / 2],
            ]
        )
    else:
        end = _ellipse_section(length, MIN_THICKNESS / 2, MIN_THICKNESS / 2, 8)
    primitives.append(Primitive("tip", _hull(np.vstack([base, end]))))
    return primitives, {
        "handle_length": handle_length,
        "handle_radius": handle_radius,
        "handle_sections": sections,
        "shaft_radius": shaft_radius,
        "tip": tip,
        "tip_length": tip_length,
        "flange": flange,
    }


def _spoon(length: float, rng: np.random.Generator) -> tuple[list[Primitive], dict[str, Any]]:
    bowl_half_length = _uniform(rng, 0.020, 0.034)
    bowl_half_width = _uniform(rng, 0.013, 0.022)
    bowl_depth = _uniform(rng, 0.007, 0.013)
    wall = _uniform(rng, MIN_THICKNESS, 0.0042)
    handle_end_width = _uniform(rng, 0.010, 0.022)
    handle_neck_width = _uniform(rng, 0.005, 0.009)
    handle_thickness = _uniform(rng, MIN_THICKNESS, 0.0045)
    bowl_centre = length - bowl_half_length
    outer = trimesh.creation.icosphere(subdivisions=3)
    outer.apply_scale([bowl_half_length, bowl_half_width, bowl_depth])
    outer.apply_translation([bowl_centre, 0, 0])
    inner = trimesh.creation.icosphere(subdivisions=3)
    inner.apply_scale([bowl_half_length - wall, bowl_half_width - wall, bowl_depth - wall])
    inner.apply_translation([bowl_centre, 0, 0])
    top = _box(3 * bowl_half_length, 3 * bowl_half_width, 2 * bowl_depth, (bowl_centre, 0, bowl_depth))
    handle_top = -0.0002
    primitives = [
        Primitive(
            "handle",
            _slab(
                np.array(
                    [
                        (0.0, -handle_end_width / 2),
                        (0.0, handle_end_width / 2),
                        (bowl_centre - bowl_half_length + 0.006, handle_neck_width / 2),
                        (bowl_centre - bowl_half_length + 0.006, -handle_neck_width / 2),
                    ]
                ),
                handle_thickness,
                z=handle_top - handle_thickness / 2,
            ),
        ),
        Primitive("bowl", outer),
        Primitive("bowl", inner, carve=True),
        Primitive("bowl", top, carve=True),
    ]
    return primitives, {
        "bowl_half_length": bowl_half_length,
        "bowl_half_width": bowl_half_width,
        "bowl_depth": bowl_depth,
        "wall": wall,
        "handle_end_width": handle_end_width,
        "handle_neck_width": handle_neck_width,
        "handle_thickness": handle_thickness,
    }


def _fork(length: float, rng: np.random.Generator) -> tuple[list[Primitive], dict[str, Any]]:
    tine_count = int(rng.integers(2, 5))
    tine_width = _uniform(rng, MIN_THICKNESS, 0.0045)
    gap = _uniform(rng, 0.0022, 0.0040)
    tine_length = _uniform(rng, 0.028, 0.048)
    base_length = _uniform(rng, 0.008, 0.014)
    neck_length = _uniform(rng, 0.025, 0.045)
    thickness = _uniform(rng, MIN_THICKNESS, 0.0045)
    handle_width = _uniform(rng, 0.011, 0.022)
    head_width = tine_count * tine_width + (tine_count - 1) * gap
    tines_start = length - tine_length
    base_start = tines_start - base_length
    neck_start = base_start - neck_length
    neck_width = _uniform(rng, 0.006, 0.009)
    primitives = [
        Primitive(
            "handle",
            _slab(
                np.array(
                    [
                        (0.0, -handle_width / 2),
                        (0.0, handle_width / 2),
                        (neck_start + 0.002, neck_width / 2),
                        (neck_start + 0.002, -neck_width / 2),
                    ]
                ),
                thickness,
            ),
        ),
        Primitive(
            "neck",
            _slab(
                np.array(
                    [
                        (neck_start, -neck_width / 2),
                        (neck_start, neck_width / 2),
                        (base_start + 0.001, head_width / 2),
                        (base_start + 0.001, -head_width / 2),
                    ]
                ),
                thickness,
            ),
        ),
        Primitive("tines", _box(base_length, head_width, thickness, (base_start + base_length / 2, 0, 0))),
    ]
    for index in range(tine_count):
        y = -head_width / 2 + tine_width / 2 + index * (tine_width + gap)
        primitives.append(
            Primitive(
                "tines",
                _slab(
                    np.array(
                        [
                            (tines_start - 0.001, y - tine_width / 2),
                            (tines_start - 0.001, y + tine_width / 2),
                            (length - 0.002, y + tine_width / 2),
                            (length, y),
                            (length - 0.002, y - tine_width / 2),
                        ]
                    ),
                    thickness,
                ),
            )
        )
    return primitives, {
        "tine_count": tine_count,
        "tine_width": tine_width,
        "gap": gap,
        "tine_length": tine_length,
        "neck_length": neck_length,
        "thickness": thickness,
        "handle_width": handle_width,
    }


def _wrench_end(
    kind: str, x: float, facing: float, radius: float, thickness: float, rng: np.random.Generator
) -> list[Primitive]:
    """An open jaw end or a closed ring end at ``x``; ``facing`` is +1 or -1 (the opening's side)."""
    if kind == "open":
        slot_width = _uniform(rng, 0.9, 1.15) * radius
        slot_width = min(slot_width, 2 * radius - 2 * 0.006)
        angle = np.deg2rad(15.0) * facing
        slot = _box(2 * radius, slot_width, thickness * 2, (0, 0, 0))
        slot.apply_translation([radius * 0.95, 0, 0])
        slot.apply_transform(trimesh.transformations.rotation_matrix(angle if facing > 0 else np.pi + angle, [0, 0, 1]))
        slot.apply_translation([x, 0, 0])
        return [Primitive("jaws", _cylinder_z(radius, thickness, (x, 0, 0))), Primitive("jaws", slot, carve=True)]
    hole = _cylinder_z(radius * _uniform(rng, 0.45, 0.6), thickness * 2, (x, 0, 0), sections=int(rng.choice([6, 12])))
    return [Primitive("head", _cylinder_z(radius, thickness, (x, 0, 0))), Primitive("head", hole, carve=True)]


def _wrench(length: float, rng: np.random.Generator) -> tuple[list[Primitive], dict[str, Any]]:
    style = str(rng.choice(["open-open", "open-ring", "open-only"]))
    radius_front = _uniform(rng, 0.013, 0.022)
    radius_back = radius_front * _uniform(rng, 0.75, 1.0)
    handle_width = _uniform(rng, 0.011, 0.018)
    handle_thickness = _uniform(rng, 0.004, 0.007)
    head_thickness = handle_thickness * _uniform(rng, 1.0, 1.4)
    x_front = length - radius_front
    x_back = radius_back if style != "open-only" else 0.0
    primitives = [
        Primitive("handle", _box(x_front - x_back, handle_width, handle_thickness, ((x_front + x_back) / 2, 0, 0)))
    ]
    primitives += _wrench_end("open", x_front, 1.0, radius_front, head_thickness, rng)
    if style == "open-open":
        primitives += _wrench_end("open", x_back, -1.0, radius_back, head_thickness, rng)
    elif style == "open-ring":
        primitives += _wrench_end("ring", x_back, -1.0, radius_back, head_thickness, rng)
    return primitives, {
        "style": style,
        "radius_front": radius_front,
        "radius_back": radius_back,
        "handle_width": handle_width,
        "handle_thickness": handle_thickness,
    }


def _hammer(length: float, rng: np.random.Generator) -> tuple[list[Primitive], dict[str, Any]]:
    style = str(rng.choice(["claw", "sledge", "ball-peen"]))
    head_span = _uniform(rng, 0.085, 0.14)
    head_size = _uniform(rng, 0.020, 0.032)
    handle_width = _uniform(rng, 0.022, 0.032)
    handle_thickness = handle_width * _uniform(rng, 0.55, 0.8)
    neck_length = _uniform(rng, 0.02, 0.04)
    head_x = length - head_size / 2
    neck_start = length - head_size - neck_length
    primitives = [
        Primitive(
            "handle",
            _tapered_bar(
                0.0,
                neck_start + 0.002,
                (handle_width, handle_width * 0.85),
                (handle_thickness, handle_thickness * 0.85),
            ),
        ),
        Primitive(
            "neck",
            _tapered_bar(
                neck_start,
                length - head_size / 2,
                (handle_width * 0.8, handle_width * 1.05),
                (handle_thickness * 0.9, handle_thickness * 1.05),
            ),
        ),
    ]
    face_span = head_span * (0.55 if style != "sledge" else 0.5)
    primitives.append(Primitive("head", _cylinder_y(head_size / 2, face_span, (head_x, face_span / 2 - 0.001, 0))))
    if style == "claw":
        claw_span = head_span - face_span
        primitives.append(
            Primitive(
                "head",
                _hull(
                    np.vstack(
                        [
                            _box(head_size, 0.002, head_size * 0.8, (head_x, 0.0, 0)).vertices,
                            _box(
                                head_size * 0.35, 0.002, MIN_THICKNESS * 1.5, (head_x - head_size * 0.3, -claw_span, 0)
                            ).vertices,
                        ]
                    )
                ),
            )
        )
    elif style == "sledge":
        primitives.append(Primitive("head", _cylinder_y(head_size / 2, face_span, (head_x, -face_span / 2 + 0.001, 0))))
    else:
        peen_span = head_span - face_span
        primitives.append(
            Primitive("head", _cylinder_y(head_size * 0.35, peen_span * 0.6, (head_x, -peen_span * 0.3, 0)))
        )
        ball = trimesh.creation.icosphere(subdivisions=2, radius=head_size * 0.45)
        ball.apply_translation([head_x, -peen_span * 0.65, 0])
        primitives.append(Primitive("head", ball))
    return primitives, {
        "style": style,
        "head_span": head_span,
        "head_size": head_size,
        "handle_width": handle_width,
        "neck_length": neck_length,
    }


def _pen(length: float, rng: np.random.Generator) -> tuple[list[Primitive], dict[str, Any]]:
    radius = _uniform(rng, 0.0040, 0.0065)
    sections = int(rng.choice([6, 16]))
    tip_length = _uniform(rng, 0.012, 0.026)
    clip = bool(rng.random() < 0.6)
    rounded_end = bool(rng.random() < 0.5)
    body_start = radius if rounded_end else 0.0
    primitives = [
        Primitive("handle", _cylinder_x(body_start, length - tip_length + 0.001, radius, radius, sections)),
        Primitive(
            "tip",
            _hull(
                np.vstack(
                    [
                        _ellipse_section(length - tip_length, radius * 0.95, radius * 0.95, 12),
                        _ellipse_section(length, MIN_THICKNESS / 2, MIN_THICKNESS / 2, 8),
                    ]
                )
            ),
        ),
    ]
    if rounded_end:
        cap = trimesh.creation.icosphere(subdivisions=2, radius=radius * 0.98)
        cap.apply_translation([radius, 0, 0])
        primitives.append(Primitive("handle", cap))
    if clip:
        clip_length = length * _uniform(rng, 0.3, 0.4)
        primitives.append(
            Primitive(
                "handle",
                _box(
                    clip_length,
                    MIN_THICKNESS,
                    MIN_THICKNESS,
                    (body_start + clip_length / 2 + 0.004, 0, radius + MIN_THICKNESS / 2 - 0.0005),
                ),
            )
        )
    return primitives, {
        "radius": radius,
        "sections": sections,
        "tip_length": tip_length,
        "clip": clip,
        "rounded_end": rounded_end,
    }


def _toothbrush(length: float, rng: np.random.Generator) -> tuple[list[Primitive], dict[str, Any]]:
    handle_width = _uniform(rng, 0.010, 0.017)
    handle_thickness = _uniform(rng, 0.006, 0.011)
    neck_width = _uniform(rng, 0.005, 0.008)
    neck_length = _uniform(rng, 0.025, 0.045)
    head_length = _uniform(rng, 0.024, 0.032)
    head_width = _uniform(rng, 0.010, 0.014)
    head_thickness = _uniform(rng, 0.004, 0.006)
    bristle_height = _uniform(rng, 0.009, 0.013)
    tufted = bool(rng.random() < 0.5)
    head_start = length - head_length
    neck_start = head_start - neck_length
    primitives = [
        Primitive(
            "handle",
            _tapered_bar(
                0.0, neck_start + 0.002, (handle_width, handle_width * 0.8), (handle_thickness, handle_thickness * 0.7)
            ),
        ),
        Primitive(
            "neck",
            _tapered_bar(neck_start, head_start + 0.002, (neck_width, neck_width), (head_thickness, head_thickness)),
        ),
        Primitive(
            "head",
            _tapered_bar(
                head_start, length, (head_width, head_width * 0.9), (head_thickness, head_thickness), count=16
            ),
        ),
    ]
    bristle_z = head_thickness / 2 + bristle_height / 2 - 0.0005
    if tufted:
        rows = int(rng.integers(4, 7))
        pitch = (head_length - 0.004) / rows
        for row in range(rows):
            x = head_start + 0.002 + pitch * (row + 0.5)
            primitives.append(
                Primitive(
                    "bristles",
                    _box(max(pitch * 0.6, MIN_THICKNESS), head_width * 0.75, bristle_height, (x, 0, bristle_z)),
                )
            )
    else:
        primitives.append(
            Primitive(
                "bristles",
                _box(
                    head_length - 0.004, head_width * 0.8, bristle_height, (head_start + head_length / 2, 0, bristle_z)
                ),
            )
        )
    return primitives, {
        "handle_width": handle_width,
        "neck_length": neck_length,
        "head_length": head_length,
        "bristle_height": bristle_height,
        "tufted": tufted,
    }


def _spatula(length: float, rng: np.random.Generator) -> tuple[list[Primitive], dict[str, Any]]:
    blade_length = _uniform(rng, 0.065, 0.10)
    blade_width = _uniform(rng, 0.05, 0.085)
    blade_thickness = _uniform(rng, MIN_THICKNESS, 0.0045)
    shape = str(rng.choice(["square", "flared", "rounded"]))
    slots = int(rng.choice([0, 0, 3, 4]))
    handle_length = (length - blade_length) * _uniform(rng, 0.6, 0.75)
    handle_radius = _uniform(rng, 0.008, 0.013)
    drop = _uniform(rng, 0.0, 0.02)
    blade_start = length - blade_length
    half = blade_width / 2
    if shape == "square":
        outline = [(blade_start, -half * 0.7), (blade_start, half * 0.7), (length, half), (length, -half)]
    elif shape == "flared":
        outline = [(blade_start, -half * 0.45), (blade_start, half * 0.45), (length, half), (length, -half)]
    else:
        angles = np.linspace(-np.pi / 2, np.pi / 2, 11)
        arc = [(length - half * 0.6 + half * 0.6 * np.cos(a), half * np.sin(a)) for a in angles]
        outline = [(blade_start, -half * 0.7), (blade_start, half * 0.7), *arc]
    neck_width = _uniform(rng, 0.010, 0.016)
    primitives = [
        Primitive("handle", _cylinder_x(0.0, handle_length, handle_radius, handle_radius * 0.75, 16)),
        Primitive(
            "neck",
            _hull(
                np.vstack(
                    [
                        _box(0.004, neck_width, MIN_THICKNESS, (handle_length - 0.004, 0, 0)).vertices,
                        _box(0.004, neck_width * 1.3, blade_thickness, (blade_start + 0.002, 0, -drop)).vertices,
                    ]
                )
            ),
        ),
        Primitive("blade", _slab(np.array(outline), blade_thickness, z=-drop)),
    ]
    slot_width = 0.004
    for index in range(slots):
        y = (index - (slots - 1) / 2) * blade_width * 0.6 / max(slots - 1, 1)
        primitives.append(
            Primitive(
                "blade",
                _box(
                    blade_length * 0.55, slot_width, blade_thickness * 3, (blade_start + blade_length * 0.5, y, -drop)
                ),
                carve=True,
            )
        )
    return primitives, {
        "blade_length": blade_length,
        "blade_width": blade_width,
        "shape": shape,
        "slots": slots,
        "handle_length": handle_length,
        "drop": drop,
    }


def _pliers(length: float, rng: np.random.Generator) -> tuple[list[Primitive], dict[str, Any]]:
    style = str(rng.choice(["needle", "combination", "slip-joint"]))
    jaw_fraction = {"needle": 0.42, "combination": 0.30, "slip-joint": 0.32}[style] * _uniform(rng, 0.9, 1.1)
    pivot_x = length * (1 - jaw_fraction)
    spread = _uniform(rng, 0.016, 0.032)
    arm_width = _uniform(rng, 0.009, 0.014)
    thickness = _uniform(rng, 0.007, 0.011)
    jaw_base = _uniform(rng, 0.014, 0.022)
    jaw_tip = {"needle": 0.004, "combination": 0.011, "slip-joint": 0.009}[style]
    pivot_radius = _uniform(rng, 0.007, 0.010)
    grip = bool(rng.random() < 0.6)
    primitives = []
    for side in (1.0, -1.0):
        arm = np.array(
            [
                (pivot_x, side * 0.001),
                (pivot_x, side * (0.001 + arm_width)),
                (0.0, side * (spread + arm_width)),
                (0.0, side * spread),
            ]
        )
        primitives.append(Primitive("handle", _slab(arm, thickness * 0.8)))
        if grip:
            sleeve = np.array(
                [
                    (0.004 + 0.0, side * (spread - 0.0015)),
                    (0.0, side * (spread + arm_width + 0.0015)),
                    (pivot_x * 0.6, side * (0.6 * spread + arm_width + 0.0015 + 0.4 * 0.001)),
                    (pivot_x * 0.6, side * (0.6 * spread - 0.0015 + 0.4 * 0.001)),
                ]
            )
            primitives.append(Primitive("handle", _slab(sleeve, thickness * 1.05)))
    primitives.append(Primitive("jaws", _cylinder_z(pivot_radius, thickness, (pivot_x, 0, 0))))
    primitives.append(
        Primitive(
            "jaws",
            _slab(
                np.array(
                    [(pivot_x, -jaw_base / 2), (pivot_x, jaw_base / 2), (length, jaw_tip / 2), (length, -jaw_tip / 2)]
                ),
                thickness,
            ),
        )
    )
    return primitives, {
        "style": style,
        "pivot_x": pivot_x,
        "spread": spread,
        "arm_width": arm_width,
        "jaw_base": jaw_base,
        "grip": grip,
    }


#: The builder of each category.
BUILDERS: Final[dict[str, Builder]] = {
    "knife": _knife,
    "screwdriver": _screwdriver,
    "spoon": _spoon,
    "fork": _fork,
    "wrench": _wrench,
    "hammer": _hammer,
    "pen": _pen,
    "toothbrush": _toothbrush,
    "spatula": _spatula,
    "pliers": _pliers,
}

assert set(BUILDERS) == set(CATEGORIES), "every category needs a builder"


# -- assembly -----------------------------------------------------------------------------


def _signed_distance_to_convex(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Lower bound of the signed distance to a convex solid: the largest plane distance (N,)."""
    offsets = np.einsum("ij,ij->i", mesh.face_normals, mesh.triangles[:, 0])
    return (points @ mesh.face_normals.T - offsets).max(axis=1)


def label_faces(mesh: trimesh.Trimesh, primitives: list[Primitive]) -> np.ndarray:
    """The part of each face: that of the primitive whose surface the face lies on.

    A boolean result's faces all lie on some primitive's surface; a face
    centroid's distance to that primitive is (numerically) zero. Ties go to
    the first primitive in the list.

    Returns
    -------
    (F,) int8
    """
    centroids = mesh.triangles_center
    distances = np.column_stack([np.abs(_signed_distance_to_convex(p.mesh, centroids)) for p in primitives])
    # Snap near-zero distances so that coplanar ties go to the earliest primitive.
    distances[distances < 1e-7] = 0.0
    nearest = distances.argmin(axis=1)
    labels = np.array([PART_INDEX[p.part] for p in primitives], dtype=np.int8)
    return labels[nearest]


def assemble(primitives: list[Primitive]) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Join the primitives into one watertight mesh and label its faces.

    Returns
    -------
    mesh : trimesh.Trimesh
    face_parts : (F,) int8
    """
    added = [p.mesh for p in primitives if not p.carve]
    carved = [p.mesh for p in primitives if p.carve]
    mesh = trimesh.boolean.union(added, engine="manifold") if len(added) > 1 else added[0].copy()
    if carved:
        mesh = trimesh.boolean.difference([mesh, *carved], engine="manifold")
    return mesh, label_faces(mesh, primitives)


def generate(category: str, rng: np.random.Generator) -> ProceduralModel:
    """One random tool of ``category``.

    Parameters
    ----------
    category : str
        One of :data:`osgd.contract.taxonomy.CATEGORIES`.
    rng : numpy.random.Generator
        The only source of randomness: the same state gives the same mesh.

    Returns
    -------
    ProceduralModel
        Watertight, centred on its bounding box, longest extent (along x)
        equal to a length drawn from the category's real-size range.
    """
    if category not in BUILDERS:
        raise ValueError(f"unknown category {category!r}; expected one of {list(CATEGORIES)}")
    length = draw_length(category, rng)
    primitives, parameters = BUILDERS[category](length, rng)
    mesh, face_parts = assemble(primitives)
    # Parts may poke out of [0, length] by a millimetre (round ends, jaws):
    # rescale so that the longest extent is exactly the drawn length.
    mesh.apply_translation(-mesh.bounds.mean(axis=0))
    mesh.apply_scale(length / float(mesh.extents.max()))
    parameters = {key: (round(value, 6) if isinstance(value, float) else value) for key, value in parameters.items()}
    parameters["length"] = round(length, 6)
    return ProceduralModel(mesh, face_parts, parameters)
