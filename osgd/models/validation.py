"""Checks and safe repairs of a model's mesh before it enters the ``models`` table.

What happens to each problem (documented in ``docs/models.md``):

==================  =====================================================  ==========
problem             what is done                                           outcome
==================  =====================================================  ==========
no faces            nothing can be repaired                                rejected
non-finite vertex   faces using it are dropped                             note
duplicate vertices  merged                                                 silent
degenerate faces    zero-area and duplicate faces are dropped              note
damaged             more than ``max_loss`` of the faces dropped above      rejected
                    (non-finite or zero-area; when ``max_loss`` is given)
flat / zero size    the mesh has (almost) no extent along some axis        rejected
several bodies      bodies whose boxes touch form one object; the largest  note
                    object (by area) is kept, the others dropped
inverted winding    fixed (watertight meshes turned outside-out)           note
open surface        small holes filled; if still open, kept as is and the  note
                    mass comes from the convex parts
far off scale       real length outside the category's plausible range     rejected
==================  =====================================================  ==========

A rejected model raises :class:`ModelRejected`; the models stage turns it into
a note and an empty shard, so one bad file never stops a run. A damaged or
degenerate mesh raises its subclass :class:`DamagedMesh`, which the models
stage turns into a failed item for a user's mesh (the file needs fixing).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from osgd.contract.taxonomy import TABLE1, UNKNOWN_PART, Taxonomy
from osgd.models.categories import plausible_length_range

log = logging.getLogger(__name__)

#: Bodies whose bounding boxes, grown by this fraction of the mesh's length,
#: overlap are parts of one object (a handle pushed into a head).
BODY_TOUCH_TOLERANCE = 0.01
#: A mesh whose smallest extent is below this fraction of its largest is flat.
FLAT_RATIO = 1e-4


class ModelRejected(ValueError):
    """A mesh that cannot be made usable; the message says why."""


class DamagedMesh(ModelRejected):
    """A mesh damaged beyond repair or degenerate (no usable face left, flat, too many faces lost to repair).

    Parameters
    ----------
    name : str
        The file or item named in the message.
    cause : str
        What is wrong, without the name.
    """

    def __init__(self, name: str, cause: str) -> None:
        super().__init__(f"{name}: {cause}")
        self.cause = cause

    def __reduce__(self) -> tuple[type[DamagedMesh], tuple[str, str]]:
        return type(self), (str(self).removesuffix(f": {self.cause}"), self.cause)


@dataclass
class CheckedMesh:
    """A mesh that passed validation, with what was done to it.

    Attributes
    ----------
    mesh : trimesh.Trimesh
    face_parts : (F,) int8
        Part index per face, aligned with ``mesh.faces``.
    notes : list of str
        One line per repair, for people.
    is_closed : bool
        True when the mesh is watertight with consistent winding (a volume).
    """

    mesh: trimesh.Trimesh
    face_parts: np.ndarray
    notes: list[str] = field(default_factory=list)
    is_closed: bool = False


def _keep_faces(mesh: trimesh.Trimesh, face_parts: np.ndarray, mask: np.ndarray) -> tuple[trimesh.Trimesh, np.ndarray]:
    kept = trimesh.Trimesh(mesh.vertices, mesh.faces[mask], process=False)
    kept.remove_unreferenced_vertices()
    return kept, face_parts[mask]


def _object_groups(mesh: trimesh.Trimesh) -> list[np.ndarray]:
    """Face indices of each object: connected bodies whose grown boxes overlap, joined."""
    components = trimesh.graph.connected_components(mesh.face_adjacency, nodes=np.arange(len(mesh.faces)))
    if len(components) <= 1:
        return [np.arange(len(mesh.faces))]
    tolerance = BODY_TOUCH_TOLERANCE * float(mesh.extents.max())
    bounds = np.array(
        [
            np.concatenate(
                [
                    mesh.vertices[mesh.faces[faces]].reshape(-1, 3).min(axis=0) - tolerance,
                    mesh.vertices[mesh.faces[faces]].reshape(-1, 3).max(axis=0) + tolerance,
                ]
            )
            for faces in components
        ]
    )
    parent = np.arange(len(components))

    def root(index: int) -> int:
        while parent[index] != index:
            parent[index] = parent[parent[index]]
            index = parent[index]
        return index

    tree = trimesh.util.bounds_tree(bounds)
    for index, box in enumerate(bounds):
        for other in tree.intersection(box):
            first, second = root(index), root(int(other))
            if first != second:
                parent[max(first, second)] = min(first, second)
    groups: dict[int, list[np.ndarray]] = {}
    for index, faces in enumerate(components):
        groups.setdefault(root(index), []).append(np.asarray(faces))
    return [np.sort(np.concatenate(parts)) for _, parts in sorted(groups.items())]


def check_mesh(
    mesh: trimesh.Trimesh,
    face_parts: np.ndarray | None = None,
    *,
    name: str = "mesh",
    max_loss: float | None = None,
) -> CheckedMesh:
    """Validate a mesh and apply the safe repairs of the module table.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Any units; not modified.
    face_parts : (F,) int8, optional
        Part index per face; unknown (-1) when omitted.
    name : str
        Named in messages (a file path or item id).
    max_loss : float, optional
        In [0, 1]: the largest share of the faces that repair may drop (faces on non-finite vertices and
        zero-area faces; duplicates, which lose nothing, are not counted). Default None: no limit.

    Returns
    -------
    CheckedMesh

    Raises
    ------
    DamagedMesh
        When no usable face is left, the mesh is flat, or repair dropped more than ``max_loss`` of its faces.
    ModelRejected
        For the other problems of the module table.
    """
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
    notes: list[str] = []
    if len(faces) == 0 or len(vertices) == 0:
        raise ModelRejected(f"{name}: empty mesh (no faces)")
    parts = np.full(len(faces), UNKNOWN_PART, dtype=np.int8) if face_parts is None else np.asarray(face_parts, np.int8)
    if len(parts) != len(faces):
        raise ModelRejected(f"{name}: {len(parts)} part labels for {len(faces)} faces")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ModelRejected(f"{name}: faces index vertices that do not exist")

    count = len(faces)
    vertices, faces, parts = _drop_non_finite(vertices, faces, parts, notes, name)
    non_finite = count - len(faces)
    work, parts, degenerate = _drop_degenerate(trimesh.Trimesh(vertices, faces, process=False), parts, notes, name)
    lost = non_finite + degenerate
    if max_loss is not None and lost > max_loss * count:
        raise DamagedMesh(
            name, f"damaged mesh: repair would drop {lost} of its {count} faces ({lost / count:.1%}: {non_finite} "
            f"on non-finite vertices, {degenerate} of zero area), more than max_repair_loss = {max_loss:.1%}; "
            "repair the mesh, or raise [models] max_repair_loss",
        )
    _check_not_flat(work, name)
    work, parts = _keep_largest_object(work, parts, notes)
    parts = _close_and_orient(work, parts, notes)
    is_closed = bool(work.is_watertight and work.is_winding_consistent and work.volume > 0)
    return CheckedMesh(work, parts.astype(np.int8), notes, is_closed)


def _drop_non_finite(
    vertices: np.ndarray, faces: np.ndarray, parts: np.ndarray, notes: list[str], name: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Drop the faces that use a non-finite vertex; such vertices become 0 (unused).

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    parts : (F,) int8
    notes : list of str
        A note is appended when faces are dropped.
    name : str

    Returns
    -------
    vertices (V, 3), faces (F', 3), parts (F',)

    Raises
    ------
    DamagedMesh
        When every face uses a non-finite vertex.
    """
    finite_vertex = np.isfinite(vertices).all(axis=1)
    if finite_vertex.all():
        return vertices, faces, parts
    keep = finite_vertex[faces].all(axis=1)
    notes.append(f"dropped {int((~keep).sum())} faces using {int((~finite_vertex).sum())} non-finite vertices")
    faces, parts = faces[keep], parts[keep]
    if len(faces) == 0:
        raise DamagedMesh(name, f"damaged mesh: every one of its {len(keep)} faces uses a non-finite vertex")
    return np.where(finite_vertex[:, None], vertices, 0.0), faces, parts


def _drop_degenerate(
    work: trimesh.Trimesh, parts: np.ndarray, notes: list[str], name: str
) -> tuple[trimesh.Trimesh, np.ndarray, int]:
    """Merge duplicate vertices, drop degenerate and duplicate faces; reject what is left without a face.

    Parameters
    ----------
    work : trimesh.Trimesh
        Modified in place (vertices merged).
    parts : (F,) int8
    notes : list of str
        A note is appended when faces are dropped.
    name : str

    Returns
    -------
    mesh, parts (F',), and how many of the dropped faces had zero area (duplicates not counted)

    Raises
    ------
    DamagedMesh
        When every face is degenerate.
    """
    work.merge_vertices()
    keep = work.nondegenerate_faces(height=1e-12 * float(work.extents.max() or 1.0))
    degenerate = int((~keep).sum())
    unique = np.zeros(len(work.faces), dtype=bool)
    unique[work.unique_faces()] = True
    keep &= unique
    if not keep.all():
        notes.append(f"dropped {int((~keep).sum())} degenerate or duplicate faces")
        work, parts = _keep_faces(work, parts, keep)
    if len(work.faces) == 0:
        raise DamagedMesh(name, "degenerate mesh: every face is degenerate (zero area)")
    return work, parts, degenerate


def _check_not_flat(work: trimesh.Trimesh, name: str) -> None:
    """Reject a mesh with (almost) no extent along some axis: no volume (a single triangle, a plane).

    Raises
    ------
    DamagedMesh
    """
    extents = work.extents
    if float(extents.min()) <= FLAT_RATIO * float(extents.max()):
        raise DamagedMesh(
            name, f"degenerate mesh: flat, no volume ({len(work.faces)} faces, extents "
            f"{np.round(extents, 6).tolist()})"
        )


def _keep_largest_object(
    work: trimesh.Trimesh, parts: np.ndarray, notes: list[str]
) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Keep only the object (:func:`_object_groups`) with the largest surface area.

    Parameters
    ----------
    work : trimesh.Trimesh
    parts : (F,) int8
    notes : list of str
        A note is appended when objects are dropped.

    Returns
    -------
    mesh, parts (F',)
    """
    groups = _object_groups(work)
    if len(groups) <= 1:
        return work, parts
    areas = np.array([work.area_faces[group].sum() for group in groups])
    largest = int(areas.argmax())
    mask = np.zeros(len(work.faces), dtype=bool)
    mask[groups[largest]] = True
    dropped_share = 1.0 - areas[largest] / areas.sum()
    notes.append(
        f"{len(groups)} separate bodies: kept the largest, dropped {len(groups) - 1} "
        f"({dropped_share:.1%} of the surface area)"
    )
    return _keep_faces(work, parts, mask)


def _close_and_orient(work: trimesh.Trimesh, parts: np.ndarray, notes: list[str]) -> np.ndarray:
    """Close small holes and make the winding consistent and outward, in place.

    Parameters
    ----------
    work : trimesh.Trimesh
        Modified in place: patch faces appended, faces flipped.
    parts : (F,) int8
    notes : list of str
        A note is appended for each repair.

    Returns
    -------
    (F',) int8
        Part per face; a patch face takes the part of the nearest original face.
    """
    if work.is_watertight:
        volume_before = work.volume
        trimesh.repair.fix_normals(work)
        if volume_before < 0:
            notes.append("the mesh was inside out; fixed the winding")
        return parts
    face_count = len(work.faces)
    trimesh.repair.fill_holes(work)
    if len(work.faces) > face_count:
        # Label the patch faces with the part of the nearest original face.
        original_centres = trimesh.Trimesh(work.vertices, work.faces[:face_count], process=False).triangles_center
        added_centres = work.triangles_center[face_count:]
        _, nearest = cKDTree(original_centres).query(added_centres)
        parts = np.concatenate([parts, parts[nearest]])
    if work.is_watertight:
        trimesh.repair.fix_normals(work)
        notes.append("closed small holes in the surface")
    else:
        trimesh.repair.fix_winding(work)
        notes.append("open surface (not watertight): mass and inertia come from the convex parts")
    return parts


def check_length(length: float, category: str, *, name: str = "mesh", taxonomy: Taxonomy = TABLE1) -> None:
    """Reject a real length far outside the category's range (a unit mix-up).

    Parameters
    ----------
    length : float
        Longest extent after scaling, metres.

    Raises
    ------
    ModelRejected
    """
    low, high = plausible_length_range(category, taxonomy)
    if not low <= length <= high:
        raise ModelRejected(
            f"{name}: far off scale: {length:.4g} m long, but a {category} is {low:.3g}-{high:.3g} m; "
            "give its real length (or the right scale) in the sidecar"
        )
