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
when parameters change).
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
    """

    parts: list[tuple[np.ndarray, np.ndarray]]
    description: dict[str, Any]
    notes: list[str]
    cached: bool = False


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


def _save(path: Path, parts: list[tuple[np.ndarray, np.ndarray]]) -> None:
    arrays: dict[str, np.ndarray] = {}
    for index, (part_vertices, part_faces) in enumerate(parts):
        arrays[f"vertices_{index}"] = part_vertices
        arrays[f"faces_{index}"] = part_faces
    buffer = io.BytesIO()
    np.savez(buffer, count=np.array(len(parts)), **arrays)
    atomic_write_bytes(path, buffer.getvalue())


def _load(path: Path) -> list[tuple[np.ndarray, np.ndarray]] | None:
    try:
        with np.load(path) as data:
            count = int(data["count"])
            return [
                (data[f"vertices_{i}"].astype(np.float64), data[f"faces_{i}"].astype(np.int64)) for i in range(count)
            ]
    except (OSError, KeyError, ValueError) as error:
        log.warning("%s: unreadable cached decomposition (%s); recomputing", path, error)
        return None


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
    if path is not None and path.exists():
        parts = _load(path)
        if parts:
            return Decomposition(parts, description, [], cached=True)
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
        _save(path, parts)
    return Decomposition(parts, description, notes)


def description_json(description: dict[str, Any]) -> str:
    """The ``decomposition`` column's text."""
    return json.dumps(description, sort_keys=True)
