"""Reading models in the original OSGD layout.

Layout (REFERENCE section 2)::

    <models dir>/<category>_<NNN>/model/model_normalized.obj
    <models dir>/<category>_<NNN>/annotations/<task>.npy

The OBJ files are ShapeNet-normalised (about one unit long, not metres) and
name a ``.mtl`` file that does not exist; that is not an error. Each
annotation file is a float array of shape (2N, 3): rows 2i and 2i + 1 are the
two finger positions of pair i, in Blender's Z-up frame, while the OBJ
vertices are Y-up: a point (x, y, z) of an annotation file is (x, z, -y) in
the OBJ's coordinates (REFERENCE section 2).

Some of the authors' OBJ files name objects with a trailing backslash
(``o \\X2\\9524628A\\X0\\``, an IFC-style escape), which trimesh reads as a
line continuation, gluing the next vertex onto the name; the loader drops
the trailing backslashes of ``o`` and ``g`` lines before trimesh reads the
text. A file that still cannot be read, or a malformed annotation file,
raises :class:`osgd.errors.InputError` naming the file and the cause.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from osgd.config import file_problem
from osgd.contract.taxonomy import CATEGORIES, task_from_file_stem
from osgd.errors import InputError

log = logging.getLogger(__name__)

#: Where the mesh lies inside a model folder.
MESH_PATH = Path("model") / "model_normalized.obj"
#: Where the annotation files lie inside a model folder.
ANNOTATIONS_DIR = Path("annotations")

_FOLDER_NAME = re.compile(r"^(?P<category>[a-z]+)_(?P<number>\d+)$")
#: An ``o`` or ``g`` line whose name ends in backslashes (kept: the name, the line end).
_NAME_WITH_BACKSLASH = re.compile(rb"^([ \t]*[og][ \t][^\r\n]*?)\\+([ \t]*\r?)$", re.MULTILINE)


@dataclass
class AnnotatedPair:
    """One hand-made contact pair.

    Attributes
    ----------
    task : str
        A task of :data:`osgd.contract.taxonomy.TASKS`.
    contact_a, contact_b : (3,) float64
        The two finger positions, in the mesh's frame and units.
    file : str
        The annotation file, relative to the model folder.
    """

    task: str
    contact_a: np.ndarray
    contact_b: np.ndarray
    file: str

    def scaled(self, scale: float, offset: np.ndarray | None = None) -> AnnotatedPair:
        """The pair with both points multiplied by ``scale`` and then shifted by ``offset``."""
        shift = np.zeros(3) if offset is None else offset
        return AnnotatedPair(self.task, self.contact_a * scale + shift, self.contact_b * scale + shift, self.file)

    def as_row(self) -> dict:
        """A cell of the ``annotated_pairs`` column."""
        return {
            "task": self.task,
            "contact_a": self.contact_a.tolist(),
            "contact_b": self.contact_b.tolist(),
            "file": self.file,
        }


@dataclass
class OsgdModel:
    """One model folder, read.

    Attributes
    ----------
    name : str
        The folder name, e.g. ``hammer_001``.
    category : str
    mesh : trimesh.Trimesh
        In the OBJ's frame and units (about one unit long), unprocessed.
    pairs : list of AnnotatedPair
        In the OBJ's frame and units.
    notes : list of str
    """

    name: str
    category: str
    mesh: trimesh.Trimesh
    pairs: list[AnnotatedPair] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def category_from_folder(name: str) -> str:
    """The category named by an OSGD model folder (``hammer_001`` -> ``hammer``).

    Raises
    ------
    ValueError
    """
    match = _FOLDER_NAME.match(name)
    if not match or match.group("category") not in CATEGORIES:
        raise ValueError(f"model folder {name!r} is not <category>_<number> with a category of {list(CATEGORIES)}")
    return match.group("category")


def blender_to_obj(points: np.ndarray) -> np.ndarray:
    """Map points from Blender's Z-up frame to the OBJ's Y-up frame: (x, y, z) -> (x, z, -y).

    Parameters
    ----------
    points : (N, 3) float

    Returns
    -------
    (N, 3) float64
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return np.column_stack([points[:, 0], points[:, 2], -points[:, 1]])


def _existing_models_dir(models_dir: Path) -> Path:
    """``models_dir`` as a path; an InputError if it is no folder."""
    models_dir = Path(models_dir)
    if not models_dir.is_dir():
        raise InputError(models_dir, "no such folder; set [models] osgd_dir to a folder in the OSGD layout")
    return models_dir


def list_model_folders(models_dir: Path) -> list[Path]:
    """Model folders of an OSGD models dir (those holding ``model/model_normalized.obj``), sorted by name.

    Raises
    ------
    InputError
        If the folder does not exist.
    """
    models_dir = _existing_models_dir(models_dir)
    return sorted(path for path in models_dir.iterdir() if (path / MESH_PATH).is_file())


def unreadable_model_folders(models_dir: Path) -> dict[Path, tuple[str, str]]:
    """Entries of an OSGD models dir that cannot be read: a symbolic link loop, a broken link, a folder whose
    ``model`` link is broken or whose mesh is no readable regular file of a bounded size.

    Returns
    -------
    dict of entry to (file relative to the entry, or the entry's own name; the cause)

    Raises
    ------
    InputError
        If the folder does not exist.
    """
    models_dir = _existing_models_dir(models_dir)
    problems: dict[Path, tuple[str, str]] = {}
    for entry in sorted(models_dir.iterdir()):
        if not entry.exists():
            problems[entry] = (entry.name, file_problem(entry) or "cannot be read")
        elif not entry.is_dir():
            continue
        elif (entry / "model").is_symlink() and not (entry / "model").is_dir():
            problems[entry] = ("model", file_problem(entry / "model") or "not a folder")
        elif os.path.lexists(entry / MESH_PATH) and file_problem(entry / MESH_PATH):
            problems[entry] = (MESH_PATH.as_posix(), str(file_problem(entry / MESH_PATH)))
    return problems


def source_files(model_dir: Path) -> list[Path]:
    """The files a model is built from: the mesh and every annotation file, sorted."""
    model_dir = Path(model_dir)
    annotations = sorted((model_dir / ANNOTATIONS_DIR).glob("*.npy"))
    return [model_dir / MESH_PATH, *annotations]


def read_annotations(model_dir: Path) -> tuple[list[AnnotatedPair], list[str]]:
    """Every contact pair of a model folder, mapped into the OBJ's frame (source units).

    Returns
    -------
    pairs : list of AnnotatedPair
    notes : list of str
        E.g. an odd row count, whose last point is dropped.

    Raises
    ------
    InputError
        For a file that is not an (N, 3) float array or names no task.
    """
    pairs: list[AnnotatedPair] = []
    notes: list[str] = []
    for path in sorted((Path(model_dir) / ANNOTATIONS_DIR).glob("*.npy")):
        relative = f"{ANNOTATIONS_DIR.as_posix()}/{path.name}"
        try:
            task = task_from_file_stem(path.stem)
        except ValueError as error:
            raise InputError(path, str(error)) from error
        points = _load_points(path)
        if len(points) % 2:
            notes.append(f"{relative}: odd number of points ({len(points)}); dropped the last, which has no partner")
            points = points[:-1]
        finite = np.isfinite(points).all(axis=1).reshape(-1, 2).all(axis=1)
        if not finite.all():
            notes.append(f"{relative}: dropped {int((~finite).sum())} pairs with non-finite points")
        mapped = blender_to_obj(points).reshape(-1, 2, 3)[finite]
        pairs.extend(AnnotatedPair(task, pair[0], pair[1], relative) for pair in mapped)
    return pairs, notes


def _load_points(path: Path) -> np.ndarray:
    """An annotation file's (N, 3) array.

    Raises
    ------
    InputError
    """
    try:
        points = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as error:
        raise InputError(path, f"not a NumPy .npy array ({error})") from error
    if points.ndim != 2 or points.shape[1] != 3 or not np.issubdtype(points.dtype, np.number):
        raise InputError(
            path, f"expected an (N, 3) float array of finger positions, got shape {points.shape} {points.dtype}"
        )
    return points


@contextlib.contextmanager
def _trimesh_logs_only_errors() -> Iterator[None]:
    """Raise trimesh's logger to ERROR for a while, then give it back its level."""
    logger = logging.getLogger("trimesh")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def read_obj(mesh_path: Path) -> trimesh.Trimesh:
    """An OBJ file as one unprocessed Trimesh, object names with trailing backslashes read as names.

    Raises
    ------
    InputError
        If trimesh cannot read the file or finds no triangle mesh in it.
    """
    data = _NAME_WITH_BACKSLASH.sub(rb"\1\2", Path(mesh_path).read_bytes())
    # The OBJ names a material library that is not shipped; without materials
    # trimesh logs that and moves on (not shown: the process's trimesh logger
    # is left as it was). process=False keeps the raw vertices for validation.
    try:
        with _trimesh_logs_only_errors():
            mesh = trimesh.load(io.BytesIO(data), file_type="obj", force="mesh", process=False, skip_materials=True)
    except Exception as error:  # a third-party parser: any exception means "cannot read this file"
        raise InputError(mesh_path, f"trimesh cannot read it ({type(error).__name__}: {error})") from error
    if not isinstance(mesh, trimesh.Trimesh):
        raise InputError(mesh_path, "trimesh read no triangle mesh from it")
    return mesh


def load_osgd_model(model_dir: str | Path) -> OsgdModel:
    """Read one OSGD model folder: the mesh and its contact pairs, in the OBJ's units.

    The mesh and the pairs share the OBJ's frame and its (ShapeNet-normalised)
    units: multiply both by the same scale to get metres. The mesh is loaded
    as one unprocessed ``Trimesh`` (all OBJ objects concatenated; the missing
    material file is ignored).

    Parameters
    ----------
    model_dir : path
        ``<models dir>/<category>_<NNN>``.

    Returns
    -------
    OsgdModel

    Raises
    ------
    InputError
        If the folder name names no category, the folder has no
        ``model/model_normalized.obj``, trimesh cannot read it, or an
        annotation file is malformed.
    """
    model_dir = Path(model_dir)
    try:
        category = category_from_folder(model_dir.name)
    except ValueError as error:
        raise InputError(model_dir, str(error)) from error
    mesh_path = model_dir / MESH_PATH
    if not mesh_path.is_file():
        raise InputError(mesh_path, "no mesh (an OSGD model folder holds model/model_normalized.obj)")
    mesh = read_obj(mesh_path)
    pairs, notes = read_annotations(model_dir)
    return OsgdModel(model_dir.name, category, mesh, pairs, notes)
