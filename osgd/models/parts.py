"""Automatic parts: a part label on every face of a tool mesh, from its geometry.

For a mesh of a known category without part labels (a user's scan or CAD
model whose sidecar gives no ``[[parts]]`` regions), the parts of
``docs/models.md`` are found from the mesh's own shape, wherever it lies:

1. **Principal frame** (:func:`principal_frame`): the tool's axis *t* is
   the longest side of the mesh's smallest oriented bounding box, its
   thickness *v* the direction most of its surface faces, its width *u*
   the third. The longest side is the mesh's true length
   (:func:`true_length`), whatever the mesh's tilt.
2. **Profiles** (:class:`Profiles`): the mesh is drawn, seen along *v* (the
   *top* silhouette, t x u) and along *u* (the *side* silhouette, t x v),
   into images of :data:`COLUMNS` columns along the axis. Per column: the
   width and thickness, the number of separate runs across the width (the
   gaps between fork tines and pliers arms) and how much of it crosses
   enclosed holes (a wrench's ring); for the rules of
   :data:`READS_LEAST_WIDTH` also the least width of each column's section
   over every direction across *t*, whatever the frame's turn.
3. **A rule per category** (:data:`SEGMENTERS`; for a taxonomy's own
   elongated categories the generic :func:`elongated`) reads these profiles: which
   end is the handle (the thinner end of a knife is its blade, the wider end
   of a hammer its head...), where each part begins along the axis, and how
   clearly the profile shows it (the *confidence*, in [0, 1]). Each face
   takes the part of the column its centroid lies in; toothbrush bristles
   are the faces beyond the head's plate.
4. **The other cross-section** (:func:`find_parts`): where the principal
   frame's profiles do not show the parts, the rule reads those of the frame
   turned a quarter about *t* (width and thickness swapped: a pliers whose
   thick arms made its frame see it edge-on), with its confidence lowered by
   :func:`turned_confidence`.

A model whose profile does not show its category's parts (confidence below
:data:`MIN_CONFIDENCE`, say a plain box called a hammer) gets no labels and a
note saying why. The cues of each category and the measured agreement with
known parts are in ``docs/models.md`` (``benchmarks/bench_parts.py``).

Lengths in metres; the mesh is expected at real size.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any, Final

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import trimesh
from scipy import ndimage
from scipy.spatial import ConvexHull, QhullError
from scipy.spatial.transform import Rotation

from osgd.contract.taxonomy import CATEGORIES, ELONGATED, PART_INDEX, TABLE1, UNKNOWN_PART, CategorySpec, Taxonomy

#: Columns of the profiles along the tool's axis (0.4-0.8 mm for real tools).
COLUMNS: Final[int] = 400
#: Below this confidence the parts count as not found (no labels, a note).
MIN_CONFIDENCE: Final[float] = 0.25
#: Bump whenever the parts found for the same mesh change (it enters the keys of users' models).
VERSION: Final[int] = 7
#: A face takes the part of the column this many columns behind it times its normal's component along the
#: axis (against the normal, into the solid): the end face of a step (a screwdriver handle's front, a spoon
#: bowl's back) is the wider part's, whatever column the step's own column is given; a face along the axis
#: keeps its column. It relies on outward normals, which validation gives closed meshes; a surface that is
#: open and wound inside out gives its steps' end faces to the narrower part.
INSIDE_COLUMNS: Final[float] = 1.5
#: Where a part that widens out of a narrower one begins: going back from its widest column, the first
#: column whose size has fallen this share of the way from the widest size to the narrow one's (1: just
#: past the narrowest column). Three quarters: an ellipse is a quarter as wide as at its widest 3 % of
#: its half-length from its end, so on a narrow neck the boundary lies close to where an elliptic bowl ends.
RISE_SHARE: Final[float] = 0.75


# -- the principal frame ---------------------------------------------------------------------------


@dataclass(frozen=True)
class PrincipalFrame:
    """A mesh's own axes: its length, width and thickness directions.

    Attributes
    ----------
    centre : (3,) float
        Centre of the box the axes span around the mesh, mesh frame.
    axes : (3, 3) float
        Rows: the unit axis *t* (length), *u* (width), *v* (thickness);
        right-handed.
    extents : (3,) float
        The mesh's extent along each row of ``axes``; ``extents[0]`` is the
        longest side of its oriented bounding box.
    """

    centre: np.ndarray
    axes: np.ndarray
    extents: np.ndarray

    @property
    def length(self) -> float:
        """The longest side of the oriented bounding box: the mesh's true length."""
        return float(self.extents[0])

    def coordinates(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) mesh-frame points as (t, u, v) about the centre."""
        return (np.asarray(points, dtype=np.float64) - self.centre) @ self.axes.T

    def flipped(self) -> PrincipalFrame:
        """The same axes with *t* and *u* reversed (still right-handed)."""
        return replace(self, axes=self.axes * np.array([[-1.0], [-1.0], [1.0]]))

    def turned(self) -> PrincipalFrame:
        """The frame turned a quarter about *t*: width and thickness swapped (*u* is the old *v*, *v* the old
        -*u*; still right-handed), so that the profiles see the tool from its edge."""
        axes = np.array([self.axes[0], self.axes[2], -self.axes[1]])
        return replace(self, axes=axes, extents=self.extents[[0, 2, 1]])


def _thickness_axis(mesh: trimesh.Trimesh, axis: np.ndarray) -> np.ndarray:
    """The direction across ``axis`` that most of the surface faces: a blade's or a plate's normal."""
    normals = mesh.face_normals - np.outer(mesh.face_normals @ axis, axis)
    scatter = (normals * mesh.area_faces[:, None]).T @ normals
    _, vectors = np.linalg.eigh(scatter)
    return vectors[:, -1]


def _box_volume(points: np.ndarray, axes: np.ndarray) -> float:
    local = points @ axes.T
    return float(np.prod(local.max(axis=0) - local.min(axis=0)))


#: Turns tried by :func:`_smallest_box`, radians, coarse to fine.
_TURNS: Final[np.ndarray] = np.deg2rad([4.0, 2.0, 1.0, 0.5, 0.25, 0.1])


def _refined(points: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """``axes`` turned about themselves, step by step, while the box around ``points`` shrinks."""
    best = _box_volume(points, axes)
    for turn in _TURNS:
        improved = True
        while improved:
            improved = False
            for axis in range(3):
                for sign in (1.0, -1.0):
                    candidate = Rotation.from_rotvec(np.eye(3)[axis] * sign * turn).as_matrix() @ axes
                    volume = _box_volume(points, candidate)
                    if volume < best * (1 - 1e-9):
                        best, axes, improved = volume, candidate, True
    return axes


def _smallest_box(mesh: trimesh.Trimesh) -> np.ndarray:
    """(3, 3) rows: the axes of the smallest box found around the mesh.

    Two starts, each refined by :func:`_refined`: trimesh's ``oriented_bounds``
    (its search over hull face directions is coarse) and the principal axes of
    the surface (area-weighted); the smaller box wins. Measured on the
    procedural tools, turned and remeshed with noise: the longest side is the
    tool's length within 0.9 %, where either start alone is off by up to 2.9 %.
    """
    try:
        hull = np.asarray(mesh.convex_hull.vertices, dtype=np.float64)
    except QhullError:  # flat: the box of the points themselves
        hull = np.asarray(mesh.vertices, dtype=np.float64)
    transform, _ = trimesh.bounds.oriented_bounds(hull)
    covariance = np.cov(mesh.triangles_center.T, aweights=mesh.area_faces, bias=True)
    starts = [np.asarray(transform[:3, :3], dtype=np.float64), np.linalg.eigh(covariance)[1].T]
    return min((_refined(hull, start) for start in starts), key=lambda axes: _box_volume(hull, axes))


def principal_frame(mesh: trimesh.Trimesh) -> PrincipalFrame:
    """A mesh's own axes, whatever its pose.

    *t* is the longest side of the mesh's smallest oriented bounding box
    (:func:`_smallest_box`); *v*, across *t*, is the direction most of the
    surface faces (area-weighted normals), so that a knife's blade or a
    spatula's plate lies in the (t, u) plane even when the handle is
    thicker; *u* completes them.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Any units; (V, 3) vertices.

    Returns
    -------
    PrincipalFrame
    """
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    box = _smallest_box(mesh)
    along = box[int(np.argmax(np.ptp(vertices @ box.T, axis=0)))]
    thickness = _thickness_axis(mesh, along)
    thickness -= (thickness @ along) * along
    axes = np.array([along, np.cross(thickness, along), thickness])
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    local = vertices @ axes.T
    low, high = local.min(axis=0), local.max(axis=0)
    return PrincipalFrame(axes.T @ ((low + high) / 2), axes, high - low)


def true_length(mesh: trimesh.Trimesh) -> float:
    """The longest side of the mesh's oriented bounding box, in the mesh's units."""
    return principal_frame(mesh).length


# -- profiles ---------------------------------------------------------------------------------------


def _silhouette(points: np.ndarray, faces: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Triangles filled into a boolean image; points are (column along t, row across) in pixels."""
    image = np.zeros(shape, dtype=np.uint8)
    # cv2 wants (x, y) = (index across, index along t), in 1/16 pixel.
    triangles = np.round(points[:, ::-1][faces] * 16).astype(np.int32)
    for triangle in triangles:
        cv2.fillConvexPoly(image, triangle, 1, lineType=cv2.LINE_8, shift=4)
    return image.astype(bool)


def _bounds(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of a silhouette: the first and last occupied pixel (0, -1 where empty)."""
    occupied = image.any(axis=1)
    first = image.argmax(axis=1)
    last = image.shape[1] - 1 - image[:, ::-1].argmax(axis=1)
    return np.where(occupied, first, 0), np.where(occupied, last, -1)


def _enclosed(image: np.ndarray, pixel: float) -> np.ndarray:
    """Per row: how much of it crosses holes of the silhouette (each at least 2 mm across), m."""
    holes = ndimage.binary_fill_holes(image) & ~image
    labels, count = ndimage.label(holes)
    if count == 0:
        return np.zeros(len(image))
    sizes = ndimage.sum(holes, labels, index=np.arange(1, count + 1))
    keep = np.concatenate([[False], sizes * pixel**2 >= 0.002**2])
    return keep[labels].sum(axis=1) * pixel


def _section_points(t: np.ndarray, across: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The points of the surface in each column: (P,) column and (P, 2) (u, v).

    Column *c* spans ``t`` in [c - 0.5, c + 0.5] (the silhouettes' pixels, with their borders). Its points are
    the vertices in it (one on a border in both columns) and where each edge crosses its borders (in both
    columns), so that a face spanning many columns (a procedural tool's side) shows in each of them. An edge
    along a border crosses nothing: its ends are on the border.
    """
    start, end = t[edges[:, 0]], t[edges[:, 1]]
    first = np.ceil(np.minimum(start, end) - 0.5).astype(np.int64)
    crossings = np.maximum(np.floor(np.maximum(start, end) - 0.5).astype(np.int64) - first + 1, 0)
    crossings[start == end] = 0
    edge = np.repeat(np.arange(len(edges)), crossings)
    border = np.arange(int(crossings.sum())) - np.repeat(np.cumsum(crossings) - crossings, crossings) + first[edge]
    share = (border + 0.5 - start[edge]) / (end[edge] - start[edge])
    a, b = across[edges[edge, 0]], across[edges[edge, 1]]
    crossing = a + share[:, None] * (b - a)
    below, above = np.ceil(t - 0.5).astype(np.int64), np.floor(t + 0.5).astype(np.int64)
    on_border = np.flatnonzero(below != above)
    columns = np.concatenate([above, below[on_border], border, border + 1])
    return columns, np.concatenate([across, across[on_border], crossing, crossing])


def _outline_least_width(points: np.ndarray) -> float:
    """The least width of 2-D points' convex outline over every direction (0 where they span no area).

    The least width lies across one of the outline's edges (rotating calipers): the smallest, over the edges,
    of the farthest vertex's distance from the edge's line. Walking the counter-clockwise outline, the
    farthest vertex from an edge is the one where the edges' direction passes the edge's own turned half a
    turn.
    """
    if len(points) < 3:
        return 0.0
    try:
        outline = points[ConvexHull(points).vertices]  # counter-clockwise in 2-D
    except QhullError:  # all on a line or at one point
        return 0.0
    edges = np.roll(outline, -1, axis=0) - outline
    angles = np.unwrap(np.arctan2(edges[:, 1], edges[:, 0]))
    count = len(outline)
    opposite = np.searchsorted(np.concatenate([angles, angles + 2 * np.pi]), angles + np.pi) % count
    directions = edges / np.linalg.norm(edges, axis=1, keepdims=True)
    reach = outline[opposite] - outline
    return float(np.abs(directions[:, 0] * reach[:, 1] - directions[:, 1] * reach[:, 0]).min())


def _least_widths(t: np.ndarray, across: np.ndarray, edges: np.ndarray, columns: int, pixel: float) -> np.ndarray:
    """(columns,) the least width of each column's section (:func:`_section_points`), m, in whole pixels as the
    silhouettes' extents are (a constant section reads constant, a step is a pixel)."""
    column, points = _section_points(t, across, edges)
    inside = (column >= 0) & (column < columns)
    order = np.argsort(column[inside], kind="stable")
    column, points = column[inside][order], points[inside][order]
    bounds = np.searchsorted(column, np.arange(columns + 1))
    widths = np.array([_outline_least_width(points[bounds[c]:bounds[c + 1]]) for c in range(columns)])
    return np.round(widths / pixel) * pixel


@dataclass(frozen=True)
class Profiles:
    """A mesh seen along its thickness (top) and its width (side), column by column along its axis.

    Attributes
    ----------
    frame : PrincipalFrame
    pixel : float
        Pixel size, m (the length over :data:`COLUMNS`).
    t : (F,) float
        Column of each face centroid (fractional, 0 at the low end of the axis).
    facing : (F,) float
        The component along the axis of each face's unit normal, in [-1, 1] (+1: facing the high end).
    across : (F, 2) float
        (u, v) of each face centroid, m.
    low, high : (C, 2) float
        Per column, the least and greatest u (top silhouette) and v (side silhouette), m.
    width, thickness : (C,) float
        ``high - low`` along u and along v, m, smoothed along the axis.
    runs : (C,) int
        Separate runs across the width in the top silhouette.
    holes : (C,) float
        How much of the column crosses enclosed holes of the top silhouette, m.
    least_width : (C,) float or None
        The least width of each column's section over every direction across the axis (the width of its
        convex outline between the closest pair of parallel lines), m, in whole pixels, smoothed along the
        axis; whatever the frame's turn about *t*. Only where :func:`profiles` is asked for it (it costs
        more than the silhouettes on a dense scan).
    """

    frame: PrincipalFrame
    pixel: float
    t: np.ndarray
    facing: np.ndarray
    across: np.ndarray
    low: np.ndarray
    high: np.ndarray
    width: np.ndarray
    thickness: np.ndarray
    runs: np.ndarray
    holes: np.ndarray
    least_width: np.ndarray | None = None

    @property
    def columns(self) -> int:
        return len(self.width)

    def reversed(self) -> Profiles:
        """The profiles seen from the other end (the frame's *t* and *u* flipped)."""
        flip = np.array([-1.0, 1.0])
        low, high = self.low[::-1] * flip, self.high[::-1] * flip
        return replace(
            self,
            frame=self.frame.flipped(),
            t=self.columns - 1 - self.t,
            facing=-self.facing,
            across=self.across * flip,
            low=np.column_stack([high[:, 0], low[:, 1]]),
            high=np.column_stack([low[:, 0], high[:, 1]]),
            width=self.width[::-1],
            thickness=self.thickness[::-1],
            runs=self.runs[::-1],
            holes=self.holes[::-1],
            least_width=None if self.least_width is None else self.least_width[::-1],
        )

    def at(self, low: float, high: float) -> slice:
        """Columns from fraction ``low`` to ``high`` of the length."""
        start = round(low * self.columns)
        return slice(start, max(round(high * self.columns), start + 1))


def profiles(mesh: trimesh.Trimesh, frame: PrincipalFrame | None = None, *, least_width: bool = False) -> Profiles:
    """The profiles of a mesh along its principal axis.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        (V, 3) vertices, m; (F, 3) faces.
    frame : PrincipalFrame, optional
        Default: :func:`principal_frame` of the mesh.
    least_width : bool
        Also the least width of each column's section (:attr:`Profiles.least_width`).
    """
    frame = frame or principal_frame(mesh)
    pixel = frame.length / COLUMNS
    local = frame.coordinates(mesh.vertices)
    origin = local.min(axis=0) - 2 * pixel
    grid = (local - origin) / pixel
    size = np.ceil((local.max(axis=0) - origin) / pixel).astype(int) + 3
    faces = np.asarray(mesh.faces)
    top = _silhouette(grid[:, [0, 1]], faces, (size[0], size[1]))
    side = _silhouette(grid[:, [0, 2]], faces, (size[0], size[2]))
    # Keep the columns the mesh occupies (the padding along t only serves the hole test).
    occupied = np.flatnonzero(top.any(axis=1))
    kept = slice(int(occupied[0]), int(occupied[-1]) + 1)
    holes = _enclosed(top, pixel)[kept]
    top, side = top[kept], side[kept]
    bounds = [_bounds(top), _bounds(side)]
    low = np.column_stack([first for first, _ in bounds]) * pixel + origin[1:]
    high = np.column_stack([last + 1 for _, last in bounds]) * pixel + origin[1:]
    extents = np.column_stack([last + 1 - first for first, last in bounds]) * pixel
    runs = np.count_nonzero(np.diff(top.astype(np.int8), axis=1) == 1, axis=1)
    centroids = local[faces].mean(axis=1)

    def smooth(values: np.ndarray) -> np.ndarray:
        return ndimage.median_filter(values, size=5, mode="nearest")

    return Profiles(
        frame=frame,
        pixel=pixel,
        t=(centroids[:, 0] - origin[0]) / pixel - kept.start,
        facing=np.asarray(mesh.face_normals) @ frame.axes[0],
        across=centroids[:, 1:],
        low=low,
        high=high,
        width=smooth(extents[:, 0]),
        thickness=smooth(extents[:, 1]),
        runs=ndimage.median_filter(runs, size=3, mode="nearest"),
        holes=holes,
        least_width=smooth(_least_widths(grid[:, 0] - kept.start, local[:, 1:], np.asarray(mesh.edges_unique),
                                         kept.stop - kept.start, pixel)) if least_width else None,
    )


# -- what a rule returns -----------------------------------------------------------------------------


@dataclass
class Segmentation:
    """One category rule's answer, on profiles turned so that the handle is at column 0.

    Attributes
    ----------
    columns : (C,) int8
        Part index of each column.
    confidence : float
        In [0, 1]: how clearly the profiles show the category's parts.
    reason : str
        What was missing, when the confidence is low.
    profiles : Profiles
        The profiles the columns refer to (turned).
    bristles : (int, float, float) or None
        Toothbrushes: (axis, sign, level): the head's faces whose ``sign *
        across[:, axis]`` exceeds ``level`` (m) are bristles.
    """

    columns: np.ndarray
    confidence: float
    reason: str
    profiles: Profiles
    bristles: tuple[int, float, float] | None = None


def _ramp(value: float, low: float, high: float) -> float:
    """0 at ``low``, 1 at ``high``, linear between."""
    return float(np.clip((value - low) / (high - low), 0.0, 1.0))


def _median(values: np.ndarray, where: slice) -> float:
    part = values[where]
    return float(np.median(part)) if len(part) else 0.0


def _largest(values: np.ndarray, where: slice | np.ndarray) -> float:
    part = values[where]
    return float(part.max()) if len(part) else 0.0


def _run_back(mask: np.ndarray, anchor: int | None = None, allowed_gap: int = 0) -> int:
    """First column of the run of True that ends at ``anchor`` (default: the last column).

    Scanning from ``anchor`` towards column 0, gaps of up to ``allowed_gap``
    False columns are bridged; ``anchor + 1`` when the run is empty.
    """
    anchor = len(mask) - 1 if anchor is None else anchor
    start, gap = anchor + 1, 0
    for column in range(anchor, -1, -1):
        if mask[column]:
            start, gap = column, 0
        else:
            gap += 1
            if gap > allowed_gap:
                break
    return start


def _rise_start(values: np.ndarray, narrow: int, widest: int) -> int:
    """The column where the rise from ``narrow`` to ``widest`` begins (:data:`RISE_SHARE`), ``narrow <= widest``."""
    level = values[widest] - RISE_SHARE * (values[widest] - values[narrow])
    return max(narrow, _run_back(values > level, widest, allowed_gap=2))


def _narrowest(values: np.ndarray, where: slice, tolerance: float) -> int:
    """The column of ``where`` within ``tolerance`` of the least value that is nearest the working end."""
    part = values[where]
    return where.start + int(np.flatnonzero(part <= part.min() + tolerance)[-1])


def _knee(values: np.ndarray, where: slice) -> int:
    """Where the rise from the least value of ``where`` to its last column levels off: the column farthest
    above the straight line between the two (a straight ramp onto a plateau: where the plateau begins); the
    least value's column where nothing rises after it or the rise curves upward (no column above the line)."""
    part = values[where]
    low = int(np.argmin(part))
    rise = part[low:]
    chord = np.linspace(rise[0], rise[-1], len(rise))
    return where.start + low + int(np.argmax(rise - chord))


def _columns(count: int, *segments: tuple[str, int]) -> np.ndarray:
    """Part per column: each (part, first column) segment runs to the next one."""
    parts = np.full(count, PART_INDEX[segments[0][0]], dtype=np.int8)
    for part, start in segments[1:]:
        parts[max(0, min(start, count)) :] = PART_INDEX[part]
    return parts


def _orient(
    profiles: Profiles, working_score: Callable[[Profiles, slice], float], outer: float
) -> tuple[Profiles, float]:
    """Turn the profiles so that the end with the larger score is the working end (high columns).

    Returns the turned profiles and the ratio of the larger end score to the smaller.
    """
    low_end = working_score(profiles, profiles.at(0.0, outer))
    high_end = working_score(profiles, profiles.at(1.0 - outer, 1.0))
    turned = profiles if high_end >= low_end else profiles.reversed()
    larger, smaller = max(low_end, high_end), min(low_end, high_end)
    return turned, (larger / smaller if smaller > 0 else np.inf)


# -- one rule per category ---------------------------------------------------------------------------
# Each takes the profiles (either way round) and returns a Segmentation on profiles turned so that
# the handle is at column 0 and the working end at the last column.


def _section(profiles: Profiles) -> np.ndarray:
    """Cross-section size (width x thickness) per column, m^2."""
    return profiles.width * profiles.thickness


def _thinnest(values: np.ndarray, where: slice) -> float:
    """The lower quartile: a thin part filling a quarter of ``where`` shows."""
    part = values[where]
    return float(np.percentile(part, 25)) if len(part) else 0.0


#: The share of the length at each end whose median thickness tells a knife's blade end from its handle end:
#: either part shows when it fills half of it, 7.5 % of the length (a short blade, a short handle behind a long
#: blade).
KNIFE_END: Final[float] = 0.15


def _knife(profiles: Profiles) -> Segmentation:
    """handle | blade: the blade is the thinner end (even a short one); it ends where the thickness rises."""
    profiles, contrast = _orient(profiles, lambda p, w: 1.0 / max(_median(p.thickness, w), 1e-9), KNIFE_END)
    handle = _median(profiles.thickness, profiles.at(0.0, KNIFE_END))
    blade = _thinnest(profiles.thickness, profiles.at(0.7, 1.0))
    start = _run_back(profiles.thickness < np.sqrt(handle * blade), allowed_gap=2)
    columns = _columns(profiles.columns, ("handle", 0), ("blade", start))
    confidence = _ramp(contrast, 1.25, 1.8)
    return Segmentation(columns, confidence, f"no thinner end for a blade (thickness ratio {contrast:.2f})", profiles)


def _screwdriver(profiles: Profiles) -> Segmentation:
    """handle | shaft | tip: the handle is the thick end; the tip is where the shaft's section changes at its end."""
    profiles, contrast = _orient(profiles, lambda p, w: 1.0 / max(_median(_section(p), w), 1e-12), 0.3)
    handle = _median(_section(profiles), profiles.at(0.0, 0.3))
    shaft = _median(_section(profiles), profiles.at(0.75, 0.95))
    shaft_start = _run_back(_section(profiles) < np.sqrt(handle * shaft), allowed_gap=2)
    width = max(_median(profiles.width, profiles.at(0.7, 0.92)), profiles.pixel)
    thickness = max(_median(profiles.thickness, profiles.at(0.7, 0.92)), profiles.pixel)
    changed = (np.abs(profiles.width / width - 1) > 0.15) | (np.abs(profiles.thickness / thickness - 1) > 0.15)
    tip_start = min(_run_back(changed), profiles.columns - int(0.03 * profiles.columns))
    columns = _columns(profiles.columns, ("handle", 0), ("shaft", shaft_start), ("tip", max(tip_start, shaft_start)))
    confidence = _ramp(contrast, 2.0, 4.0)
    return Segmentation(columns, confidence, f"no thin shaft at either end (section ratio {contrast:.2f})", profiles)


def _spoon(profiles: Profiles) -> Segmentation:
    """handle | bowl: the bowl is the end of larger section, or where that is unclear (a handle as wide as
    the bowl), the end nearer the narrowest point (a short bowl, a long handle); it starts where the width
    rises from that point to the bowl's widest (a long neck that widens slowly stays handle)."""
    turned, contrast = _orient(profiles, lambda p, w: _largest(_section(p), w), 0.3)
    if contrast < 1.5:
        nearer_high_end = _narrowest(profiles.width, profiles.at(0.1, 0.9), 0.0) > profiles.columns / 2
        turned = profiles if nearer_high_end else profiles.reversed()
    neck = _narrowest(turned.width, turned.at(0.3, 0.95), 1.5 * turned.pixel)
    widest = neck + int(np.argmax(turned.width[neck:]))
    ratio = float(turned.width[widest]) / max(float(turned.width[neck]), 1e-9)
    columns = _columns(turned.columns, ("handle", 0), ("bowl", _rise_start(turned.width, neck, widest)))
    return Segmentation(columns, _ramp(ratio, 1.4, 2.2), f"no bowl wider than its neck (ratio {ratio:.2f})", turned)


def _gaps(profiles: Profiles, where: slice) -> float:
    """Share of the columns with two runs or more across the width (tines, open arms)."""
    return float(np.mean(profiles.runs[where] >= 2)) + 1e-3


def _fork(profiles: Profiles) -> Segmentation:
    """handle | neck | tines: the tines are the end with gaps across; the neck the narrowest stretch before them."""
    profiles, _ = _orient(profiles, _gaps, 0.3)
    first_gap = _run_back(profiles.runs >= 2, allowed_gap=max(2, profiles.columns // 50))
    head = _median(profiles.width, slice(first_gap, profiles.columns))
    anchor = min(first_gap, profiles.columns - 1)
    tines = min(_run_back(profiles.width >= 0.94 * head, anchor=anchor, allowed_gap=2), first_gap)
    neck_reach = int(0.35 * profiles.columns)  # how far before the tines the neck is looked for
    tines = max(tines, _knee(profiles.width, slice(max(0, first_gap - neck_reach), anchor + 1)))
    window = slice(max(0, tines - neck_reach), max(tines - 1, 1))
    neck = _narrowest(profiles.width, window, 1.5 * profiles.pixel)
    columns = _columns(profiles.columns, ("handle", 0), ("neck", neck), ("tines", tines))
    share = _gaps(profiles, profiles.at(0.85, 1.0))
    return Segmentation(columns, _ramp(share, 0.2, 0.6), f"no gaps between tines at either end ({share:.0%})", profiles)


def _wide_end(width: np.ndarray, wide: np.ndarray) -> int:
    """First column of the high end's wide part: back from its widest column (in the outer third) while wide.

    ``len(width)`` when that end is not wide.
    """
    first = 2 * len(width) // 3
    widest = first + int(np.argmax(width[first:]))
    return _run_back(wide, anchor=widest, allowed_gap=2) if wide[widest] else len(width)


def _wrench(profiles: Profiles) -> Segmentation:
    """handle | jaws (an open end) or head (a ring end): an end much wider than the handle, or a little wider
    with a slot (open jaws) or a hole (a ring) a third of its width across; a hang hole in a grip is neither."""
    profiles, _ = _orient(profiles, lambda p, w: _largest(p.width, w), 0.25)
    handle = max(_median(profiles.width, profiles.at(0.35, 0.65)), profiles.pixel)
    wide = profiles.width > 1.15 * handle
    count = profiles.columns
    ends = (
        slice(_wide_end(profiles.width, wide), count),
        slice(0, count - _wide_end(profiles.width[::-1], wide[::-1])),
    )
    columns = np.full(count, PART_INDEX["handle"], dtype=np.int8)
    widest = 1.0
    for span in ends:
        if span.stop - span.start < 0.03 * count:
            continue
        width = _largest(profiles.width, span)
        # A ring's hole lies where its end is widest; a hang hole in a grip lies elsewhere.
        broadest = profiles.width[span] >= 0.9 * width
        ring = _largest(profiles.holes[span], broadest) >= width / 3
        # Open jaws: two prongs across the outer third of the end (not around a hole).
        third = (span.stop - span.start) // 3
        outer = slice(span.stop - third, span.stop) if span.stop == count else slice(0, third)
        slot = float(np.mean((profiles.runs[outer] >= 2) & (profiles.holes[outer] == 0))) >= 0.3
        if width < 1.35 * handle and not (ring or slot):
            continue
        columns[span] = PART_INDEX["head" if ring else "jaws"]
        widest = max(widest, width / handle)
    confidence = _ramp(widest, 1.2, 1.6)
    return Segmentation(columns, confidence, f"no end wider than the handle (ratio {widest:.2f})", profiles)


def _hammer(profiles: Profiles) -> Segmentation:
    """handle | neck | head: the head is the wide end; the neck the narrowest stretch just before it."""
    profiles, _ = _orient(profiles, lambda p, w: _largest(p.width, w), 0.2)
    handle = _median(profiles.width, profiles.at(0.1, 0.6))
    ratio = _largest(profiles.width, profiles.at(0.0, 1.0)) / max(handle, 1e-9)
    outer = profiles.at(0.8, 1.0)
    widest = outer.start + int(np.argmax(profiles.width[outer]))
    head = _run_back(profiles.width > 1.5 * handle, anchor=widest, allowed_gap=2)
    window = slice(max(0, head - int(0.15 * profiles.columns)), max(head - 2, 1))
    neck = _narrowest(profiles.width, window, 1.5 * profiles.pixel)
    columns = _columns(profiles.columns, ("handle", 0), ("neck", neck), ("head", head))
    confidence = _ramp(ratio, 1.8, 2.6)
    return Segmentation(columns, confidence, f"no head wider than the handle (ratio {ratio:.2f})", profiles)


#: A pen's end tapers when its section grows steadily from the end to where it reaches 90 % of the body's: in
#: at least :data:`PEN_STEADY_GROWTH` of those columns, or, where a slender cone's profile rises a pixel step
#: every few columns so that few columns grow, in steps none larger than :data:`PEN_LARGEST_STEP` of the whole
#: rise with no flat stretch longer than :data:`PEN_LONGEST_FLAT` of the columns. A narrow plug at the back or
#: a blunt end does neither: it stays flat, then steps up, at once or over a short shoulder. Where both ends
#: taper, the longer stretch is the tip (docs/models.md).
PEN_STEADY_GROWTH: Final[float] = 0.2
#: The largest step of a steady taper, as a share of its rise (see :data:`PEN_STEADY_GROWTH`).
PEN_LARGEST_STEP: Final[float] = 1 / 3
#: The longest stretch without growth of a steady taper, as a share of its columns (see :data:`PEN_STEADY_GROWTH`).
PEN_LONGEST_FLAT: Final[float] = 0.5


#: The share of a pen's length at each end whose median size tells a cap from the back end.
PEN_END: Final[float] = 0.08


def _tip_columns(count: int) -> int:
    """The columns a pen's tip may span: a quarter of them."""
    return max(count // 4, 1)


def _pen_size(profiles: Profiles) -> np.ndarray:
    """A pen's section size where its taper is read: the lesser of width and thickness, in the silhouettes' steps."""
    return np.minimum(profiles.width, profiles.thickness)


def _cap_size(profiles: Profiles) -> np.ndarray:
    """A capped pen's section size: its least width, whichever way round a flat body or a clip lies about the
    axis (the lesser of width and thickness grows as the frame turns off a flat body's thin side)."""
    if profiles.least_width is None:
        raise ValueError("the pen's rule reads the sections' least width: profiles(..., least_width=True)")
    return profiles.least_width


def _longest_flat(steps: np.ndarray) -> int:
    """The longest run of steps without growth."""
    growing = np.flatnonzero(np.concatenate([[True], steps > 0, [True]]))
    return int(np.diff(growing).max()) - 1


def _taper_length(size: np.ndarray, body: float) -> int:
    """Columns from column 0 to where ``size`` reaches 90 % of ``body``, if it grows steadily there; else 0.

    Only the first quarter of the columns is searched (a tip is at most a quarter of a pen). The growth is read
    from column 1 on: the end column holds only the part of the end that reaches into it (a sliver of an apex,
    lifted or cut by a scan's noise), not a step of the taper.
    """
    quarter = _tip_columns(len(size))
    reached = np.flatnonzero(size[:quarter] >= 0.9 * body)
    stop = int(reached[0]) if len(reached) else quarter
    steps = np.diff(size[1 : stop + 1])
    if not len(steps):
        return 0
    growing = np.count_nonzero(steps > 0) >= PEN_STEADY_GROWTH * stop
    rise = float(size[stop] - size[1])
    small_steps = (rise > 0 and steps.max() <= PEN_LARGEST_STEP * rise
                   and _longest_flat(steps) <= PEN_LONGEST_FLAT * stop)
    return stop if growing or small_steps else 0


def _pen(profiles: Profiles) -> Segmentation:
    """handle | tip: the tip is the end that tapers to a cone over the longer stretch.

    With neither end tapering (a capped pen: the writing tip lies under the cap), the tip is the end under
    the wider cap, and the cap is the tip part; the ends are compared by their least width (:func:`_cap_size`).
    """
    size = _pen_size(profiles)
    body = _median(size, profiles.at(0.2, 0.8))
    low_end, high_end = _taper_length(size, body), _taper_length(size[::-1], body)
    if max(low_end, high_end) >= 0.03 * profiles.columns:
        profiles = profiles if high_end >= low_end else profiles.reversed()
        size = _pen_size(profiles)
        # The tip begins where the cone's rise from the apex levels off into the body (its knee) or where the
        # section falls below 90 % of the body's, whichever lies farther from the apex.
        cone_base = profiles.columns - 1 - _knee(size[::-1], slice(0, _tip_columns(profiles.columns)))
        tip = min(_run_back(size < 0.9 * body), cone_base)
        confidence = _ramp((max(low_end, high_end) + 1) / (min(low_end, high_end) + 1), 1.2, 1.8)
        reason = f"both ends taper alike ({low_end} and {high_end} columns)"
        return Segmentation(_columns(profiles.columns, ("handle", 0), ("tip", tip)), confidence, reason, profiles)
    profiles, contrast = _orient(profiles, lambda p, w: _median(_cap_size(p), w), PEN_END)
    size = _cap_size(profiles)
    # The cap runs back from its widest column at the end: its rounded rim may be narrower than the back end.
    end = profiles.at(1.0 - PEN_END, 1.0)
    widest = end.start + int(np.argmax(size[end]))
    cap = _run_back(size >= 1.1 * _median(size, profiles.at(0.0, PEN_END)), anchor=widest,
                    allowed_gap=round(0.02 * profiles.columns))
    confidence = _ramp(contrast, 1.15, 1.4) if cap < profiles.columns else 0.0
    reason = f"neither end tapers to a tip nor has a cap wider than the other end (ratio {contrast:.2f})"
    return Segmentation(_columns(profiles.columns, ("handle", 0), ("tip", cap)), confidence, reason, profiles)


def _bristles(profiles: Profiles, head: int, neck: slice) -> tuple[tuple[int, float, float], float]:
    """Where the bristles stand: (axis, sign, level) of :class:`Segmentation`, and how far they stand out, m.

    Of the four directions across the axis (+-u, +-v), the one in which the head stands out farthest beyond the
    neck's surface (its median over the neck's columns: the neck's ends rise into the handle and the head, and
    a scan's noise lifts its highest point), of those in which the head reaches past the level: 1 mm beyond the
    neck's highest point.
    """
    best = ((1, 1.0, np.inf), 0.0)
    for axis in (0, 1):
        for sign, bound in ((1.0, profiles.high), (-1.0, profiles.low)):
            neck_reach = sign * bound[neck, axis]
            head_reach, level = float((sign * bound[head:, axis]).max()), float(neck_reach.max()) + 0.001
            stands_out = head_reach - float(np.median(neck_reach))
            if head_reach > level and stands_out > best[1]:
                best = ((axis, sign, level), stands_out)
    return best


def _toothbrush(profiles: Profiles) -> Segmentation:
    """handle | neck | head + bristles: the neck is the narrowest stretch, near the head's end."""
    section = _section(profiles)
    narrowest = _narrowest(section, profiles.at(0.05, 0.95), 0.0)
    if narrowest < profiles.columns / 2:
        profiles, section, narrowest = profiles.reversed(), section[::-1], profiles.columns - 1 - narrowest
    around = slice(max(0, narrowest - profiles.columns // 40), narrowest + profiles.columns // 40 + 1)
    width, thickness = _median(profiles.width, around), _median(profiles.thickness, around)
    head = narrowest + int(np.argmax(section[narrowest:] > 1.3 * width * thickness))
    thicker = (profiles.width[:narrowest] > 1.15 * width) | (profiles.thickness[:narrowest] > 1.15 * thickness)
    neck = _run_back(~thicker, allowed_gap=1)
    columns = _columns(profiles.columns, ("handle", 0), ("neck", neck), ("head", head))
    bristles, reach = _bristles(profiles, head, slice(min(neck, head - 1), head))
    ratio = reach / max(width, thickness, 1e-9)
    return Segmentation(columns, _ramp(ratio, 0.6, 1.2), f"no bristles standing out of a head ({ratio:.2f})",
                        profiles, bristles)


def _spatula(profiles: Profiles) -> Segmentation:
    """handle | neck | blade: the blade is the wide end; the neck is where the handle's thickness ends."""
    profiles, _ = _orient(profiles, lambda p, w: _largest(p.width, w), 0.3)
    outer = profiles.at(0.6, 1.0)
    widest = outer.start + int(np.argmax(profiles.width[outer]))
    narrow = float(profiles.width[profiles.at(0.3, 0.8)].min())
    blade_width = float(profiles.width[widest])
    blade = _run_back(profiles.width > np.sqrt(blade_width * narrow), anchor=widest, allowed_gap=2)
    handle = _median(profiles.thickness, profiles.at(0.05, 0.3))
    plate = _median(profiles.thickness, slice(blade, profiles.columns))
    thick = profiles.thickness[:blade] > np.sqrt(handle * plate)
    neck = int(np.flatnonzero(thick).max()) + 1 if thick.any() and handle > 1.5 * plate else blade
    columns = _columns(profiles.columns, ("handle", 0), ("neck", neck), ("blade", blade))
    ratio = blade_width / max(narrow, 1e-9)
    return Segmentation(columns, _ramp(ratio, 1.8, 2.8), f"no blade wider than the handle (ratio {ratio:.2f})",
                        profiles)


def _pliers(profiles: Profiles) -> Segmentation:
    """handle | jaws: the handle is the end whose two arms leave a gap across; the jaws start where they join."""
    profiles, _ = _orient(profiles, lambda p, w: 1.0 / _gaps(p, w), 0.3)
    arms = profiles.runs >= 2
    share = float(np.mean(arms[profiles.at(0.0, 0.3)]))
    joined = np.flatnonzero(~arms)
    joined = joined[joined > 0.15 * profiles.columns]
    pivot = int(joined[0]) if len(joined) else profiles.columns
    columns = _columns(profiles.columns, ("handle", 0), ("jaws", pivot))
    return Segmentation(columns, _ramp(share, 0.3, 0.7), f"no two arms at either end ({share:.0%})", profiles)


# -- the generic rule of a taxonomy's elongated category ---------------------------------------------

#: The share of the length at each end read by :func:`elongated` to tell the ends apart ("wider",
#: "narrower"), and the share at each end where the boundary between the two parts may not lie.
END_SHARE: Final[float] = 0.2
#: The cross-section contrast across the boundary, as ``|log(working / handle)|``, from which the parts
#: count as found (confidence 0) to clearly found (confidence 1): 1.1x to 1.5x.
CONTRAST_RANGE: Final[tuple[float, float]] = (float(np.log(1.1)), float(np.log(1.5)))


def _two_segments(values: np.ndarray, lowest: int, highest: int) -> int:
    """The column in ``[lowest, highest]`` where a fit of two constant segments to ``values`` is best."""
    total, squares = np.concatenate([[0.0], np.cumsum(values)]), np.concatenate([[0.0], np.cumsum(values**2)])
    count = len(values)
    splits = np.arange(max(lowest, 1), min(highest, count - 1) + 1)
    left = squares[splits] - total[splits] ** 2 / splits
    right = (squares[count] - squares[splits]) - (total[count] - total[splits]) ** 2 / (count - splits)
    return int(splits[int(np.argmin(left + right))])


def _end_scores(section: np.ndarray, working_end: str, profiles: Profiles) -> tuple[float, float]:
    """How much each end (low, high columns) looks like the working end; the larger one is."""
    if working_end in ("wider", "narrower"):
        low, high = (_median(section, profiles.at(0.0, END_SHARE)), _median(section, profiles.at(1 - END_SHARE, 1)))
    else:  # heavier, lighter: the volume of each half
        low, high = float(section[profiles.at(0.0, 0.5)].sum()), float(section[profiles.at(0.5, 1.0)].sum())
    return (low, high) if working_end in ("wider", "heavier") else (-low, -high)


def elongated(profiles: Profiles, category: CategorySpec, part_index: Mapping[str, int]) -> Segmentation:
    """handle | working part of a taxonomy's elongated category (``parts_rule = "elongated"``).

    The working end is the one ``category.working_end`` names: the end whose outer fifth has the larger
    (``wider``) or smaller (``narrower``) median cross-section, or the half of the larger (``heavier``) or
    smaller (``lighter``) volume. The boundary is where the cross-section changes: the best fit of two
    constant segments to the log cross-section along the axis, at least a fifth of the length from either
    end. The confidence is the contrast of the two segments (:data:`CONTRAST_RANGE`); it is zero where the
    segments disagree with the ends (the working segment of a ``wider`` tool narrower than its handle).
    Faces take ``category.handle[0]`` behind the boundary and ``category.working[0]`` from it on.
    """
    section = np.log(np.maximum(_section(profiles), profiles.pixel**2))
    low, high = _end_scores(section, category.working_end, profiles)
    profiles = profiles if high >= low else profiles.reversed()
    section = section if high >= low else section[::-1]
    count = profiles.columns
    boundary = _two_segments(section, round(END_SHARE * count), round((1 - END_SHARE) * count))
    contrast = float(section[boundary:].mean() - section[:boundary].mean())
    agrees = contrast > 0 if category.working_end in ("wider", "heavier") else contrast < 0
    columns = np.full(count, part_index[category.handle[0]], dtype=np.int8)
    columns[boundary:] = part_index[category.working[0]]
    confidence = _ramp(abs(contrast), *CONTRAST_RANGE) if agrees else 0.0
    reason = (f"the cross-section changes by {np.exp(abs(contrast)):.2f}x along the tool" if agrees else
              f"the {category.working_end} end's segment is not {category.working_end} than the other")
    return Segmentation(columns, confidence, reason, profiles)


#: The rule of each category.
SEGMENTERS: Final[dict[str, Callable[[Profiles], Segmentation]]] = {
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

assert set(SEGMENTERS) == set(CATEGORIES), "every category needs a rule"

#: The categories whose rule reads the sections' least width (:attr:`Profiles.least_width`); their profiles
#: alone compute it.
READS_LEAST_WIDTH: Final[frozenset[str]] = frozenset({"pen"})


# -- faces -----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class AutomaticParts:
    """Parts found from a mesh's geometry.

    Attributes
    ----------
    face_parts : (F,) int8
        Index into :data:`osgd.contract.taxonomy.PARTS` per face; all -1 when not found.
    confidence : float
        In [0, 1].
    found : bool
        ``confidence >= MIN_CONFIDENCE``.
    note : str
        Why the parts were not found ('' when found).
    frame : PrincipalFrame
        Turned so that its *t* axis points from the handle end to the working end.
    """

    face_parts: np.ndarray
    confidence: float
    found: bool
    note: str
    frame: PrincipalFrame

    @property
    def axis(self) -> np.ndarray:
        """(3,) unit vector from the handle end to the working end, mesh frame."""
        return self.frame.axes[0]


def _face_parts(segmentation: Segmentation) -> np.ndarray:
    """The part of each face: that of the column just inside the solid behind it (:data:`INSIDE_COLUMNS`)."""
    profiles = segmentation.profiles
    inside = profiles.t - INSIDE_COLUMNS * profiles.facing
    column = np.clip(np.round(inside).astype(int), 0, profiles.columns - 1)
    parts = segmentation.columns[column]
    if segmentation.bristles is not None:
        axis, sign, level = segmentation.bristles
        beyond = sign * profiles.across[:, axis] > level
        parts = np.where((parts == PART_INDEX["head"]) & beyond, PART_INDEX["bristles"], parts).astype(np.int8)
    return parts


def turned_confidence(turned: float, principal: float) -> float:
    """The confidence of the turned frame's reading, used where the principal frame's does not find the parts.

    ``turned * (1 - principal / MIN_CONFIDENCE) ** 0.5``: both in [0, 1], ``principal`` below
    :data:`MIN_CONFIDENCE`. A principal reading that sees nothing (0, a pliers seen edge-on) takes nothing
    away; one that almost finds other parts lowers the turned reading towards zero.
    """
    return float(turned * np.sqrt(max(0.0, 1.0 - principal / MIN_CONFIDENCE)))


def _segmenter(category: str, taxonomy: Taxonomy) -> Callable[[Profiles], Segmentation] | None:
    """The rule of a category: its own (Table I's), the taxonomy's elongated rule, or None."""
    spec = taxonomy.category(category)
    if category in SEGMENTERS:
        return SEGMENTERS[category]
    if spec.parts_rule == ELONGATED:
        return functools.partial(elongated, category=spec, part_index=taxonomy.part_index)
    return None


def find_parts(mesh: trimesh.Trimesh, category: str, taxonomy: Taxonomy = TABLE1) -> AutomaticParts:
    """The part of every face of a tool mesh, found from its geometry (module text).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        (V, 3) vertices at real size, m, any pose; (F, 3) faces.
    category : str
        A category of ``taxonomy``: one of Table I's (its own rule), or one whose ``parts_rule`` is
        ``"elongated"`` (:func:`elongated`); any other gets no parts and a note.
    taxonomy : Taxonomy

    Returns
    -------
    AutomaticParts
        ``face_parts`` (F,) int8, indices into the taxonomy's parts.

    Raises
    ------
    ValueError
        For a category the taxonomy does not have.
    """
    segmenter = _segmenter(category, taxonomy)
    frame = principal_frame(mesh)
    if segmenter is None:
        note = (f"automatic parts: the taxonomy gives a {category} no parts rule; its faces are left unknown and "
                "its sampled grasps get no task: give [[parts]] regions or a [part_labels] file in the sidecar, or "
                'parts_rule = "elongated" to the category (docs/taxonomy.md)')
        return AutomaticParts(np.full(len(mesh.faces), UNKNOWN_PART, dtype=np.int8), 0.0, False, note, frame)
    least_width = category in READS_LEAST_WIDTH
    segmentation = segmenter(profiles(mesh, frame, least_width=least_width))
    confidence = round(float(segmentation.confidence), 3)
    if confidence < MIN_CONFIDENCE:
        turned = segmenter(profiles(mesh, frame.turned(), least_width=least_width))
        if round(turned_confidence(float(turned.confidence), confidence), 3) >= MIN_CONFIDENCE:
            segmentation = turned
            confidence = round(turned_confidence(float(turned.confidence), confidence), 3)
    frame = segmentation.profiles.frame
    if confidence < MIN_CONFIDENCE:
        unknown = np.full(len(mesh.faces), UNKNOWN_PART, dtype=np.int8)
        note = (f"automatic parts: the shape does not show a {category}'s parts ({segmentation.reason}, "
                f"confidence {confidence:.2f}); its faces are left unknown and its sampled grasps get no task: "
                "give [[parts]] regions in the sidecar (docs/models.md)")
        return AutomaticParts(unknown, confidence, False, note, frame)
    return AutomaticParts(_face_parts(segmentation), confidence, True, "", frame)


# -- reading what a models row says --------------------------------------------------------------------


def parts_method(source: str, provenance: Mapping[str, Any]) -> tuple[str, float]:
    """How a model's parts were found, and the confidence.

    Users' meshes record it in ``provenance["parts"]`` (``sidecar``,
    ``automatic``, ``sidecar+automatic`` or ``none`` when not found);
    procedural tools carry the generator's parts (``procedural``, 1.0); OSGD
    models carry no part labels but hand-made contact pairs (``hand-made
    pairs``, 0.0).

    Parameters
    ----------
    source : str
        The ``source`` column.
    provenance : mapping
        The ``provenance`` column, parsed.
    """
    record = provenance.get("parts")
    if record:
        return str(record["method"]), float(record["confidence"])
    return ("procedural", 1.0) if source == "procedural" else ("hand-made pairs", 0.0)


def without_task_labels(table: pa.Table) -> list[str]:
    """Names of the models of a ``models`` table whose grasps all get no task.

    Those with no part label on any face and no hand-made contact pair: the
    grasps stage samples their grasps and labels them from parts they do not have.
    """
    names = table.column("name").to_pylist()
    pair_counts = pc.list_value_length(table.column("annotated_pairs")).to_pylist()
    face_parts = table.column("face_parts")
    return [
        name
        for row, name in enumerate(names)
        if not pair_counts[row] and not (np.asarray(face_parts[row].values, dtype=np.int64) >= 0).any()
    ]
