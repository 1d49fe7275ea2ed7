"""Users' own meshes: any mesh trimesh reads plus a small TOML sidecar.

For ``<user dir>/drill.stl`` the sidecar is ``<user dir>/drill.toml``::

    category = "screwdriver"
    length = 0.25            # real length, m: the longest side of the mesh's oriented box  (or: scale = 0.001)
    default_part = "handle"  # faces no region claims; omit: automatic parts (osgd.models.parts)

    [part_labels]            # optional: a part per face (or per vertex) from a file
    file = "drill.parts.npy" # integers, one per face of the mesh as trimesh reads it; -1: unknown
    names = ["handle", "shaft", "tip"]   # the part each integer 0, 1, 2... stands for
    per = "face"             # or "vertex": a face takes the part of at least two of its corners

    [[parts]]                # later regions win over earlier ones, and over the labels
    part = "shaft"
    box = { min = [0.0, -10.0, -10.0], max = [150.0, 10.0, 10.0] }

    [[parts]]
    part = "tip"
    half_space = { point = [140.0, 0.0, 0.0], normal = [1.0, 0.0, 0.0] }

    [[parts]]
    part = "handle"
    groups = ["grip"]        # OBJ groups / objects

    [[grasps]]               # optional contact pairs in the OSGD .npy form
    file = "drill_screw.npy"
    task = "screw"           # default: from the file stem (hand_over.npy -> hand over)
    frame = "model"          # "model" (the mesh's own axes) or "blender" (OSGD's Z-up files)

Regions and grasp points are in the mesh's own frame and units; a face
belongs to a region when its centroid does. A face's part is, in this order
of precedence: the last region that holds it, its label in the part label
file, ``default_part``, else unknown (automatic parts fill the unknown
faces where no ``default_part`` is given). Faces and vertices of a label
file are in the order ``trimesh.load(path, process=False)`` reads them
(a scene's objects one after another). See ``docs/models.md``.
"""

from __future__ import annotations

import json
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

import numpy as np
import trimesh
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from osgd.config import MAX_CONFIG_BYTES, read_input_file
from osgd.contract.taxonomy import TABLE1, UNKNOWN_PART, Taxonomy, task_from_file_stem
from osgd.errors import InputError
from osgd.models.osgd_import import AnnotatedPair, blender_to_obj
from osgd.models.validation import ModelRejected

#: File name endings read as users' meshes.
MESH_SUFFIXES: tuple[str, ...] = (".obj", ".stl", ".ply", ".glb", ".gltf", ".off")


class SidecarError(InputError):
    """A sidecar that cannot be used; the message names the file and the problem."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Box(_Strict):
    """An axis-aligned box, mesh frame and units."""

    min: tuple[float, float, float]
    max: tuple[float, float, float]


class HalfSpace(_Strict):
    """Points p with (p - point) . normal >= 0, mesh frame and units."""

    point: tuple[float, float, float]
    normal: tuple[float, float, float]


class PartRegion(_Strict):
    """One part given as exactly one of a box, a half-space or OBJ groups."""

    part: str
    box: Box | None = None
    half_space: HalfSpace | None = None
    groups: list[str] | None = None

    @model_validator(mode="after")
    def _one_region(self) -> PartRegion:
        given = [name for name in ("box", "half_space", "groups") if getattr(self, name) is not None]
        if len(given) != 1:
            raise ValueError(f"part {self.part!r} needs exactly one of box, half_space, groups (got {given})")
        return self


class GraspFile(_Strict):
    """A contact-pair file in the OSGD .npy form, relative to the sidecar."""

    file: str
    task: str | None = None
    frame: Literal["model", "blender"] = "model"


class PartLabels(_Strict):
    """A file of part labels, one integer per face (or vertex), relative to the sidecar."""

    file: str
    names: list[str] = Field(min_length=1, description="the part that label 0, 1, 2... stands for")
    per: Literal["face", "vertex"] = "face"


class Sidecar(_Strict):
    """The contents of a sidecar file."""

    category: str
    length: float | None = Field(
        default=None, gt=0, description="real length, m: the longest side of the mesh's oriented bounding box"
    )
    scale: float | None = Field(default=None, gt=0, description="mesh units to metres")
    default_part: str | None = None
    part_labels: PartLabels | None = None
    parts: list[PartRegion] = Field(default_factory=list)
    grasps: list[GraspFile] = Field(default_factory=list)

    @model_validator(mode="after")
    def _size_given_once(self) -> Sidecar:
        if (self.length is None) == (self.scale is None):
            raise ValueError("give exactly one of length (real longest extent, m) and scale (mesh units to metres)")
        return self


def sidecar_path(mesh_path: Path) -> Path:
    """``<dir>/<stem>.toml`` for ``<dir>/<stem>.<ext>``."""
    return Path(mesh_path).with_suffix(".toml")


def list_user_meshes(user_dir: Path) -> list[Path]:
    """Mesh files directly in ``user_dir``, sorted by name: every entry with a mesh suffix that is not a folder,
    also those that cannot be read (a broken link, a FIFO), which the models stage names as failed items.

    Raises
    ------
    InputError
        If the folder does not exist.
    """
    user_dir = Path(user_dir)
    if not user_dir.is_dir():
        raise InputError(user_dir, "no such folder; set [models] user_dir to a folder of meshes with sidecars")
    return sorted(path for path in user_dir.iterdir() if path.suffix.lower() in MESH_SUFFIXES and not path.is_dir())


def taxonomy_problems(sidecar: Sidecar, taxonomy: Taxonomy = TABLE1) -> list[str]:
    """What a sidecar names that the taxonomy does not have: its category, a part, a task; ``key = value: why``."""
    problems = []
    if sidecar.category not in taxonomy.category_names:
        problems.append(f"category = {sidecar.category!r}: unknown category {sidecar.category!r}; expected one of "
                        f"{list(taxonomy.category_names)}")
    parts = [("default_part", sidecar.default_part)] if sidecar.default_part is not None else []
    parts += [(f"parts.{index}.part", region.part) for index, region in enumerate(sidecar.parts)]
    if sidecar.part_labels is not None:
        parts += [(f"part_labels.names.{index}", name) for index, name in enumerate(sidecar.part_labels.names)]
    problems += [f"{where} = {part!r}: unknown part {part!r}; expected one of {list(taxonomy.parts)}"
                 for where, part in parts if part not in taxonomy.part_index]
    problems += [f"grasps.{index}.task = {entry.task!r}: unknown task {entry.task!r}; expected one of "
                 f"{list(taxonomy.tasks)}"
                 for index, entry in enumerate(sidecar.grasps)
                 if entry.task is not None and entry.task not in taxonomy.tasks]
    return problems


def parse_sidecar(text: str, origin: str = "<sidecar>", taxonomy: Taxonomy = TABLE1) -> Sidecar:
    """Read a sidecar's TOML text; its category, parts and tasks are the taxonomy's.

    Raises
    ------
    SidecarError
    """
    try:
        document = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise SidecarError(origin, f"not valid TOML: {error}") from error
    try:
        sidecar = Sidecar(**document)
    except ValidationError as error:
        raise SidecarError(origin, "; ".join(_problem(entry) for entry in error.errors())) from error
    problems = taxonomy_problems(sidecar, taxonomy)
    if problems:
        raise SidecarError(origin, "; ".join(problems))
    return sidecar


def _problem(entry: Mapping[str, Any]) -> str:
    """One pydantic error as ``key = value: rule`` (the rule alone for a rule across keys)."""
    message = str(entry["msg"]).removeprefix("Value error, ")
    if entry["type"] == "extra_forbidden":
        message = "unknown key; see docs/models.md for the sidecar's keys"
    if not entry["loc"]:
        return message
    return f"{'.'.join(str(part) for part in entry['loc'])} = {entry.get('input')!r}: {message}"


def read_sidecar(path: Path, taxonomy: Taxonomy = TABLE1) -> Sidecar:
    """Read a sidecar file; its category, parts and tasks are the taxonomy's.

    Raises
    ------
    InputError
        Also a :class:`SidecarError`.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(
            path, "no sidecar; every user mesh needs one naming at least its category and length (see docs/models.md)"
        )
    data = read_input_file(path, MAX_CONFIG_BYTES)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise SidecarError(path, f"not UTF-8 text ({error.reason} at byte {error.start}); a sidecar is TOML") from error
    return parse_sidecar(text, str(path), taxonomy)


def _toml_value(value: object) -> str:
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{key} = {_toml_value(item)}" for key, item in value.items()) + " }"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(item) for item in value) + "]"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, int):
        return str(value)
    return json.dumps(str(value))


def sidecar_to_toml(sidecar: Sidecar) -> str:
    """The TOML text of a sidecar; :func:`parse_sidecar` reads it back equal."""
    data = sidecar.model_dump(mode="json", exclude_none=True)
    lines = [
        f"{key} = {_toml_value(data[key])}" for key in ("category", "length", "scale", "default_part") if key in data
    ]
    if "part_labels" in data:
        lines.append("\n[part_labels]")
        lines.extend(f"{key} = {_toml_value(value)}" for key, value in data["part_labels"].items())
    for table in ("parts", "grasps"):
        for entry in data.get(table, []):
            lines.append(f"\n[[{table}]]")
            lines.extend(f"{key} = {_toml_value(value)}" for key, value in entry.items())
    return "\n".join(lines) + "\n"


def _load_with_groups(mesh_path: Path) -> tuple[trimesh.Trimesh, dict[str, np.ndarray]]:
    """The mesh as one Trimesh, and the face indices of each named group/object."""
    try:
        loaded = trimesh.load(mesh_path, process=False, skip_materials=True)
    except Exception as error:  # a third-party parser: any exception means "cannot read this file"
        raise InputError(mesh_path, f"trimesh cannot read it ({type(error).__name__}: {error})") from error
    if isinstance(loaded, trimesh.Trimesh):
        return loaded, {}
    if not isinstance(loaded, trimesh.Scene) or not loaded.geometry:
        raise ModelRejected(f"{mesh_path}: trimesh read no triangle mesh from it")
    meshes, groups, start = [], {}, 0
    for name, geometry in loaded.geometry.items():
        if not isinstance(geometry, trimesh.Trimesh):
            continue
        meshes.append(geometry)
        groups[name] = np.arange(start, start + len(geometry.faces))
        start += len(geometry.faces)
    if not meshes:
        raise ModelRejected(f"{mesh_path}: trimesh read no triangle mesh from it")
    return trimesh.util.concatenate(meshes), groups


def read_part_labels(mesh: trimesh.Trimesh, labels: PartLabels, base_dir: Path,
                     taxonomy: Taxonomy = TABLE1) -> np.ndarray:
    """The part of each face from a part label file (indices into the taxonomy's parts, -1 unknown).

    Per vertex, a face takes the part that at least two of its three corners have, else its first corner's.

    Returns
    -------
    (F,) int8

    Raises
    ------
    InputError
        Naming the file: missing, not an ``.npy`` of integers, one per face (vertex) of the mesh, each -1 or
        an index into ``names``.
    """
    path = base_dir / labels.file
    if not path.is_file():
        raise InputError(path, "part label file named in the sidecar does not exist")
    try:
        values = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as error:
        raise InputError(path, str(error)) from error
    count = len(mesh.faces) if labels.per == "face" else len(mesh.vertices)
    if values.ndim != 1 or len(values) != count or not np.issubdtype(values.dtype, np.integer):
        raise InputError(path, f"expected {count} integers, one per {labels.per} of the mesh as trimesh reads it, "
                               f"got an array of shape {values.shape} and type {values.dtype}")
    wrong = np.flatnonzero((values < -1) | (values >= len(labels.names)))
    if len(wrong):
        raise InputError(path, f"label {int(values[wrong[0]])} of {labels.per} {int(wrong[0])}: expected -1 "
                               f"(unknown) or 0-{len(labels.names) - 1}, an index into names {labels.names}")
    lookup = np.array([*(taxonomy.part_index[name] for name in labels.names), UNKNOWN_PART], dtype=np.int8)
    parts = lookup[values]  # -1 takes the last entry: unknown
    if labels.per == "vertex":
        corners = parts[mesh.faces]
        parts = np.where(corners[:, 1] == corners[:, 2], corners[:, 1], corners[:, 0])
    return parts.astype(np.int8)


def face_parts_from_regions(
    mesh: trimesh.Trimesh, sidecar: Sidecar, groups: dict[str, np.ndarray], origin: str = "<sidecar>",
    base_dir: Path | None = None, taxonomy: Taxonomy = TABLE1,
) -> np.ndarray:
    """The part of each face from the sidecar: its regions (later regions win) over its part label file
    (read from ``base_dir``, the sidecar's folder) over ``default_part``; indices into the taxonomy's parts.

    Returns
    -------
    (F,) int8

    Raises
    ------
    SidecarError
        For a group the mesh does not have.
    InputError
        For a part label file that cannot be used (:func:`read_part_labels`).
    """
    part_index = taxonomy.part_index
    default = part_index[sidecar.default_part] if sidecar.default_part else UNKNOWN_PART
    parts = np.full(len(mesh.faces), default, dtype=np.int8)
    if sidecar.part_labels is not None:
        labelled = read_part_labels(mesh, sidecar.part_labels, Path(origin).parent if base_dir is None else base_dir,
                                    taxonomy)
        parts = np.where(labelled != UNKNOWN_PART, labelled, parts).astype(np.int8)
    centres = mesh.triangles_center
    for region in sidecar.parts:
        if region.box is not None:
            inside = np.all((centres >= region.box.min) & (centres <= region.box.max), axis=1)
        elif region.half_space is not None:
            inside = (centres - np.asarray(region.half_space.point)) @ np.asarray(region.half_space.normal) >= 0
        else:
            inside = np.zeros(len(parts), dtype=bool)
            for group in region.groups or []:
                if group not in groups:
                    raise SidecarError(
                        origin, f"part {region.part!r} names group {group!r}, but the mesh has "
                        f"{sorted(groups) or 'no groups'}"
                    )
                inside[groups[group]] = True
        parts[inside] = part_index[region.part]
    return parts


def read_grasp_files(sidecar: Sidecar, base_dir: Path,
                     taxonomy: Taxonomy = TABLE1) -> tuple[list[AnnotatedPair], list[str]]:
    """The sidecar's contact pairs, in the mesh's frame and units; a task from a file stem is the taxonomy's.

    Raises
    ------
    InputError
    """
    pairs: list[AnnotatedPair] = []
    notes: list[str] = []
    for entry in sidecar.grasps:
        path = base_dir / entry.file
        if not path.is_file():
            raise InputError(path, "grasp file named in the sidecar does not exist")
        try:
            points = np.load(path, allow_pickle=False)
            task = entry.task or task_from_file_stem(path.stem, taxonomy.tasks)
        except (OSError, ValueError, EOFError) as error:
            raise InputError(path, str(error)) from error
        if points.ndim != 2 or points.shape[1] != 3:
            raise InputError(path, f"expected an (N, 3) array of finger positions, got shape {points.shape}")
        if len(points) % 2:
            notes.append(f"{entry.file}: odd number of points ({len(points)}); dropped the last")
            points = points[:-1]
        points = blender_to_obj(points) if entry.frame == "blender" else np.asarray(points, np.float64)
        pairs.extend(AnnotatedPair(task, pair[0], pair[1], entry.file) for pair in points.reshape(-1, 2, 3))
    return pairs, notes


def named_files(sidecar_file: Path) -> list[Path]:
    """The files a sidecar names: its grasp files and its part label file (empty when it does not parse: the
    build reports that)."""
    try:
        sidecar = read_sidecar(sidecar_file)
    except InputError:
        return []
    labels = [] if sidecar.part_labels is None else [sidecar_file.parent / sidecar.part_labels.file]
    return [*(sidecar_file.parent / entry.file for entry in sidecar.grasps), *labels]


def load_user_mesh(mesh_path: Path) -> tuple[trimesh.Trimesh, dict[str, np.ndarray]]:
    """A user's mesh and its named groups.

    Raises
    ------
    InputError
        If trimesh cannot read the file (a failure: the file needs fixing).
    ModelRejected
        If trimesh reads it but finds no triangle mesh (an empty model: skipped).
    """
    return _load_with_groups(Path(mesh_path))
