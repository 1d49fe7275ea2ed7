"""Convex decomposition of a model into a collision compound, with coacd, cached on disk.

pybullet simulates a dynamic mesh body as the convex hull of the whole mesh;
a compound of convex parts is what gives a tool its real, non-convex
collision shape (REFERENCE section 8).

Presets (REFERENCE section 8 measured coacd on tool meshes here: the default
threshold 0.05 takes 0.3-3.3 s; 0.1 takes 0.1-0.8 s, but fork tines merge
into one hull unless the threshold is at most 0.02):

- ``fast``: threshold 0.1, 100 tree-search iterations. Most tools.
- ``thin``: threshold 0.02, 60 iterations (fewer, to pay for the finer
  threshold). Thin parts that must stay apart: fork tines.
- ``fine``: coacd's default threshold 0.05.
- ``hull``: no coacd, the convex hull of the whole mesh (quick tests).
- ``auto`` (the stage default) picks ``thin`` for the categories in
  :data:`THIN_CATEGORIES` and ``fast`` for the others.

Every preset uses ``preprocess_mode="auto"``: coacd remeshes a mesh only when
it is not a 2-manifold (most authored models are surface soups, where this
is faster *and* better than cutting the soup directly), and leaves the
watertight procedural meshes alone.

Cache: ``<cache_dir>/<key>.npz`` where ``key`` is the sha256 of the mesh's
vertex and face bytes, the coacd version and *every* coacd parameter
(REFERENCE section 5: a cache keyed on vertices only serves stale results
when parameters change). Each file holds its own key and a sha256 of its
parts, and is used only when both check out: a truncated or altered file,
or a valid file of another mesh copied under this name, is recomputed and
overwritten, with a warning (:attr:`Decomposition.warnings`), never trusted
and never fatal.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import logging
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any, Final

import numpy as np
import trimesh

from osgd.store import atomic_write_bytes, canonical_json

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CoacdParameters:
    """Every argument of ``coacd.run_coacd`` besides the mesh (coacd's names and defaults)."""

    threshold: float = 0.05
    max_convex_hull: int = -1
    preprocess_mode: str = "auto"
    preprocess_resolution: int = 50
    resolution: int = 2000
    mcts_nodes: int = 20
    mcts_iterations: int = 150
    mcts_max_depth: int = 3
    pca: bool = False
    merge: bool = True
    decimate: bool = False
    max_ch_vertex: int = 256
    extrude: bool = False
    extrude_margin: float = 0.01
    apx_mode: str = "ch"
    seed: int = 0
    real_metric: bool = False

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


#: The quality presets (see the module docstring).
PRESETS: Final[dict[str, CoacdParameters | None]] = {
    "fast": CoacdParameters(threshold=0.1, mcts_iterations=100),
    "thin": CoacdParameters(threshold=0.02, mcts_iterations=60),
    "fine": CoacdParameters(threshold=0.05),
    "hull": None,
}

#: Categories whose thin parts need the ``thin`` preset under ``auto``.
THIN_CATEGORIES: Final[frozenset[str]] = frozenset({"fork"})

#: Preset names a config may give.
PRESET_NAMES: Final[tuple[str, ...]] = ("auto", *PRESETS)


def resolve_preset(preset: str, category: str) -> str:
    """The concrete preset for ``category`` (``auto`` resolved).

    Raises
    ------
    ValueError
        For an unknown preset name.
    """
    if preset == "auto":
        return "thin" if category in THIN_CATEGORIES else "fast"
    if preset not in PRESETS:
        raise ValueError(f"unknown decomposition preset {preset!r}; expected one of {list(PRESET_NAMES)}")
    return preset


def _coacd_version() -> str:
    try:
        return metadata.version("coacd")
    except metadata.PackageNotFoundError:
        return "unknown"


def cache_key(vertices: np.ndarray, faces: np.ndarray, parameters: CoacdParameters | None) -> str:
    """sha256 naming the decomposition of one mesh under one set of parameters.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    parameters : CoacdParameters or None
        None for the plain convex hull.
    """
    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(vertices, dtype=np.float64).tobytes())
    digest.update(b"|")
    digest.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    document = {
        "method": "convex_hull" if parameters is None else "coacd",
        "coacd_version": _coacd_version() if parameters is not None else None,
        "parameters": parameters.as_dict() if parameters is not None else None,
    }
    digest.update(canonical_json(document).encode())
    return digest.hexdigest()


@dataclass
class Decomposition:
    """A collision compound.

    Attributes
    ----------
    parts : list of (vertices (V, 3) float64, faces (F, 3) int64)
        Convex, closed, in the mesh's frame and units.
    description : dict
        method, preset and every parameter used; JSON-able.
    notes : list of str
        Fallbacks taken.
    cached : bool
        Whether the parts came from the cache.
    warnings : list of str
        A cache file that was bad and recomputed. Not part of the result:
        the same mesh gives the same parts whatever the cache held.
    """

    parts: list[tuple[np.ndarray, np.ndarray]]
    description: dict[str, Any]
    notes: list[str]
    cached: bool = False
    warnings: list[str] = dataclasses.field(default_factory=list)


def _hull_parts(vertices: np.ndarray, faces: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    hull = trimesh.Trimesh(vertices, faces, process=False).convex_hull
    return [(np.asarray(hull.vertices, np.float64), np.asarray(hull.faces, np.int64))]


def _run_coacd(
    vertices: np.ndarray, faces: np.ndarray, parameters: CoacdParameters
) -> list[tuple[np.ndarray, np.ndarray]]:
    import coacd  # noqa: PLC0415 - heavy import, only where decompositions are computed

    coacd.set_log_level("error")
    result = coacd.run_coacd(
        coacd.Mesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int64)), **parameters.as_dict()
    )
    parts = []
    for part_vertices, part_faces in result:
        # coacd's hulls are convex already; rebuilding them makes the winding and closure certain.
        hull = trimesh.Trimesh(np.asarray(part_vertices), np.asarray(part_faces), process=False).convex_hull
        if len(hull.faces) >= 4 and hull.volume > 0:
            parts.append((np.asarray(hull.vertices, np.float64), np.asarray(hull.faces, np.int64)))
    return parts


def _parts_digest(parts: list[tuple[np.ndarray, np.ndarray]]) -> str:
    """sha256 over the shapes and bytes of every part, in order."""
    digest = hashlib.sha256()
    for part_vertices, part_faces in parts:
        for array in (np.ascontiguousarray(part_vertices, np.float64), np.ascontiguousarray(part_faces, np.int64)):
            digest.update(repr(array.shape).encode())
            digest.update(array.tobytes())
    return digest.hexdigest()


def _save(path: Path, key: str, parts: list[tuple[np.ndarray, np.ndarray]]) -> None:
    arrays: dict[str, np.ndarray] = {}
    for index, (part_vertices, part_faces) in enumerate(parts):
        arrays[f"vertices_{index}"] = part_vertices
        arrays[f"faces_{index}"] = part_faces
    buffer = io.BytesIO()
    np.savez(buffer, key=np.array(key), digest=np.array(_parts_digest(parts)), count=np.array(len(parts)), **arrays)
    atomic_write_bytes(path, buffer.getvalue())


def _load(path: Path, key: str) -> tuple[list[tuple[np.ndarray, np.ndarray]] | None, str]:
    """The cached parts, or None and what is wrong with the file."""
    try:
        with np.load(path, allow_pickle=False) as data:
            if "key" not in data.files:
                return None, "is of an older format, without its key"
            stored_key, stored_digest = str(data["key"]), str(data["digest"])
            parts = [
                (data[f"vertices_{i}"].astype(np.float64), data[f"faces_{i}"].astype(np.int64))
                for i in range(int(data["count"]))
            ]
    except Exception as error:  # zipfile.BadZipFile, zlib.error, KeyError, ValueError, OSError...: all "unreadable"
        return None, f"is unreadable ({type(error).__name__}: {error})"
    if stored_key != key:
        return None, f"holds the decomposition of another mesh or parameters (key {stored_key[:12]})"
    if stored_digest != _parts_digest(parts):
        return None, "does not match its checksum"
    if not parts:
        return None, "holds no part"
    return parts, ""


def decompose(
    vertices: np.ndarray,
    faces: np.ndarray,
    preset: str,
    cache_dir: Path | None = None,
) -> Decomposition:
    """The convex parts of a mesh, from the cache when present.

    Parameters
    ----------
    vertices : (V, 3) float
        Metres, object frame (the parts come back in the same frame).
    faces : (F, 3) int
    preset : str
        A concrete preset name (see :func:`resolve_preset`).
    cache_dir : Path, optional
        Folder of cached results; no caching when None.

    Returns
    -------
    Decomposition
        Falls back to the convex hull, with a note, when coacd raises or
        returns nothing.
    """
    if preset not in PRESETS:
        raise ValueError(f"unknown decomposition preset {preset!r}; expected one of {list(PRESETS)}")
    parameters = PRESETS[preset]
    description: dict[str, Any] = {
        "method": "convex_hull" if parameters is None else "coacd",
        "preset": preset,
        "parameters": parameters.as_dict() if parameters is not None else {},
    }
    if parameters is not None:
        description["coacd_version"] = _coacd_version()
    key = cache_key(vertices, faces, parameters)
    path = cache_dir / f"{key}.npz" if cache_dir is not None else None
    warnings: list[str] = []
    if path is not None and path.exists():
        parts, problem = _load(path, key)
        if parts:
            return Decomposition(parts, description, [], cached=True)
        warnings.append(f"the cached decomposition {path} {problem}; recomputed it")
        log.info("%s", warnings[-1])
    notes: list[str] = []
    if parameters is None:
        parts = _hull_parts(vertices, faces)
    else:
        try:
            parts = _run_coacd(vertices, faces, parameters)
        except Exception as error:
            parts, reason = [], f"coacd raised {error!r}"
        else:
            reason = "coacd returned no part"
        if not parts:
            notes.append(f"{reason}; using the convex hull as the collision shape")
            description = {"method": "convex_hull", "preset": preset, "fallback_from": description}
            parts = _hull_parts(vertices, faces)
    if path is not None and not notes:
        _save(path, key, parts)
    elif path is not None:  # a fallback is not cached: nor may a bad file stay
        path.unlink(missing_ok=True)
    return Decomposition(parts, description, notes, warnings=warnings)


def description_json(description: dict[str, Any]) -> str:
    """The ``decomposition`` column's text."""
    return json.dumps(description, sort_keys=True)
