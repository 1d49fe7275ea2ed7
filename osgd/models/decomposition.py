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
- ``scan``: for users' meshes (scans, CAD): the mesh is repaired first
  (:func:`repair_for_decomposition`: duplicate vertices merged, every hole
  closed by a fan of triangles), simplified to at most ``[models]
  scan_max_faces`` faces (:func:`simplify_for_decomposition`, quadric edge
  collapse; :data:`SCAN_MAX_FACES` by default), then cut at
  threshold 0.02 without coacd's remeshing when the repair made it
  watertight, and remeshed at cells of :data:`SCAN_CELL` otherwise.
- ``auto`` (the stage default) picks ``scan`` for users' meshes, ``thin``
  for the categories in :data:`THIN_CATEGORIES` and ``fast`` for the others.

The other presets use ``preprocess_mode="auto"``: coacd remeshes a mesh only
when it is not a 2-manifold (most authored models are surface soups, where
this is faster *and* better than cutting the soup directly), and leaves the
watertight procedural meshes alone. Why scans need their own preset
(measured by ``benchmarks/bench_decomposition.py``, docs/models.md): coacd's
own test finds a noisy scan not manifold even when it is watertight, and its
remesh at 50 cells along the longest side (4 mm on a 20 cm fork) merges the
tines and fills a wrench's jaws. Why a scan is simplified first: coacd's time
grows with the faces and the noise; quadric edge collapse to a few thousand
faces is quick, smooths the sensor noise away and leaves the hulls as close
to the true solid or closer (``bench_decomposition.py``, docs/models.md).
The collapse may leave a few edges shared by four faces; coacd cuts such a
mesh without remeshing as it does a closed one. coacd runs on a user's mesh
in a process of its own (:func:`_run_coacd_isolated`): its native code
crashes on some closed meshes when it cuts them without remeshing, and a
crash then costs that one decomposition, which runs again with coacd's
remesh on (a note says so), never the process of the stage.

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

import concurrent.futures
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

from osgd.executor import spawned_pool
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
    "scan": CoacdParameters(threshold=0.02, mcts_iterations=60, preprocess_mode="off"),
}

#: Cell size of coacd's manifold remesh of a scan that stays open after its repair, m.
SCAN_CELL: Final[float] = 0.0015
#: Bounds of that remesh's resolution (cells along the longest side): coacd's default, and a cost cap.
SCAN_RESOLUTION: Final[tuple[int, int]] = (50, 200)
#: Version of the ``scan`` preset's repair and simplification; in the payload of users' models, so a change
#: rebuilds them.
SCAN_REPAIR_VERSION: Final[int] = 2
#: Default largest face count of a scan given to coacd (``[models] scan_max_faces``).
SCAN_MAX_FACES: Final[int] = 5000
#: fast_simplification's aggressiveness (0 slow and close to the input, 10 fast and coarse; its default 7).
SIMPLIFY_AGGRESSION: Final[int] = 3

#: Categories whose thin parts need the ``thin`` preset under ``auto``.
THIN_CATEGORIES: Final[frozenset[str]] = frozenset({"fork"})

#: Preset names a config may give.
PRESET_NAMES: Final[tuple[str, ...]] = ("auto", *PRESETS)


def resolve_preset(preset: str, category: str, user_mesh: bool = False) -> str:
    """The concrete preset for ``category`` (``auto`` resolved; ``scan`` for a user's mesh).

    Raises
    ------
    ValueError
        For an unknown preset name.
    """
    if preset == "auto":
        if user_mesh:
            return "scan"
        return "thin" if category in THIN_CATEGORIES else "fast"
    if preset not in PRESETS:
        raise ValueError(f"unknown decomposition preset {preset!r}; expected one of {list(PRESET_NAMES)}")
    return preset


@dataclass(frozen=True)
class Repaired:
    """A mesh made ready for coacd by :func:`repair_for_decomposition`.

    Attributes
    ----------
    vertices : (V, 3) float64
        Duplicates merged; otherwise the input's, in its frame and units.
    faces : (F, 3) int64
        The input's faces, then the fans that close its holes.
    holes_closed : int
    watertight : bool
        Every edge shared by exactly two faces, in opposite directions.
    """

    vertices: np.ndarray
    faces: np.ndarray
    holes_closed: int
    watertight: bool


def _hole_loops(faces: np.ndarray) -> list[list[int]]:
    """The holes of a mesh: loops of boundary edges (an edge whose reverse no face has), in face order.

    Where two holes touch at a vertex, the walk splits them into separate loops; a boundary
    chain that does not close (a non-manifold edge) is left alone.
    """
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).tolist()
    present = set(map(tuple, edges))
    successors: dict[int, list[int]] = {}
    for start, end in edges:
        if (end, start) not in present:
            successors.setdefault(start, []).append(end)
    loops = []
    while successors:
        path = [next(iter(successors))]
        position = {path[0]: 0}
        while path:
            following = successors.get(path[-1])
            if not following:
                break
            vertex = following.pop()
            if not following:
                del successors[path[-1]]
            if vertex in position:  # a loop closes: cut it off the path
                cut = position[vertex]
                loops.append(path[cut:])
                for dropped in path[cut + 1:]:
                    del position[dropped]
                path = path[:cut + 1]
                continue
            position[vertex] = len(path)
            path.append(vertex)
    return [loop for loop in loops if len(loop) >= 3]


def repair_for_decomposition(vertices: np.ndarray, faces: np.ndarray) -> Repaired:
    """Merge duplicate vertices and close every hole with a fan of triangles.

    A scan's holes (where the sensor saw nothing) and the seams of a mesh
    stored with split vertices keep it from being a closed surface, and
    coacd then remeshes it coarsely. Each fan runs against its hole's
    boundary edges, so the closed surface keeps one winding. (trimesh's
    ``repair.fill_holes`` closes only holes of three or four edges; on a
    scan with 2 % of its faces gone it left the mesh open.)

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    """
    mesh = trimesh.Trimesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int64), process=False)
    mesh.merge_vertices()
    merged = np.asarray(mesh.faces, np.int64)
    loops = _hole_loops(merged)
    fans = [[loop[0], loop[index + 1], loop[index]] for loop in loops for index in range(1, len(loop) - 1)]
    closed = np.concatenate([merged, np.asarray(fans, np.int64).reshape(-1, 3)])
    result = trimesh.Trimesh(np.asarray(mesh.vertices, np.float64), closed, process=False)
    return Repaired(np.asarray(result.vertices, np.float64), closed, len(loops),
                    bool(result.is_watertight and result.is_winding_consistent))


def simplify_for_decomposition(
    vertices: np.ndarray, faces: np.ndarray, max_faces: int
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """At most ``max_faces`` faces of a repaired mesh, by quadric edge collapse (fast_simplification).

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    max_faces : int
        0: the mesh as it is.

    Returns
    -------
    vertices, faces, description
        The description (``{}`` when nothing was collapsed) holds the face
        counts and the library's version, for the ``decomposition`` column.
    """
    if max_faces <= 0 or len(faces) <= max_faces:
        return vertices, faces, {}
    import fast_simplification  # noqa: PLC0415 - only where a scan is simplified

    collapsed = fast_simplification.simplify(np.asarray(vertices, np.float64), np.asarray(faces, np.int64),
                                             target_count=max_faces, agg=SIMPLIFY_AGGRESSION)
    simple = trimesh.Trimesh(*collapsed)  # trimesh's processing: duplicate vertices merged
    description = {"faces_before": len(faces), "faces": len(simple.faces), "method": "quadric edge collapse",
                   "library": f"fast_simplification {_version('fast_simplification')}"}
    return np.asarray(simple.vertices, np.float64), np.asarray(simple.faces, np.int64), description


def scan_parameters(repaired: Repaired) -> CoacdParameters:
    """The ``scan`` preset's coacd parameters for a repaired mesh.

    Watertight: no remesh (coacd's own test would remesh a noisy scan). Still
    open: coacd's remesh, at cells of :data:`SCAN_CELL` within :data:`SCAN_RESOLUTION`.
    """
    base = PRESETS["scan"]
    assert base is not None
    if repaired.watertight:
        return base
    longest = float(np.ptp(repaired.vertices, axis=0).max())
    low, high = SCAN_RESOLUTION
    resolution = int(np.clip(np.ceil(longest / SCAN_CELL), low, high))
    return dataclasses.replace(base, preprocess_mode="on", preprocess_resolution=resolution)


def _version(package: str) -> str:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "unknown"


def _coacd_version() -> str:
    return _version("coacd")


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


class CoacdCrashed(RuntimeError):
    """coacd's native code ended its process on a mesh."""


def _run_coacd_isolated(
    vertices: np.ndarray, faces: np.ndarray, parameters: CoacdParameters
) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`_run_coacd` in a child process (spawned, ends with this one); its crash raises :class:`CoacdCrashed`."""
    with spawned_pool(1) as pool:
        try:
            return pool.submit(_run_coacd, vertices, faces, parameters).result()
        except concurrent.futures.process.BrokenProcessPool as error:
            raise CoacdCrashed(f"coacd's process died (preprocess_mode={parameters.preprocess_mode!r})") from error


def _scan_parts(
    vertices: np.ndarray, faces: np.ndarray, parameters: CoacdParameters, description: dict[str, Any],
    notes: list[str],
) -> list[tuple[np.ndarray, np.ndarray]]:
    """coacd on a user's mesh, isolated; after a crash once more with its manifold remesh on (in ``description``)."""
    try:
        return _run_coacd_isolated(vertices, faces, parameters)
    except CoacdCrashed as error:
        remeshing = dataclasses.replace(parameters, preprocess_mode="on")
        notes.append(f"{error} on the repaired mesh; decomposed it again with coacd's manifold remesh on")
        description.update(parameters=remeshing.as_dict(), crashed=parameters.as_dict())
        return _run_coacd_isolated(vertices, faces, remeshing)


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
    scan_max_faces: int = SCAN_MAX_FACES,
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
    scan_max_faces : int
        The ``scan`` preset: the most faces of the mesh given to coacd
        (:func:`simplify_for_decomposition`); 0 keeps them all.

    Returns
    -------
    Decomposition
        Falls back to the convex hull, with a note, when coacd raises or
        returns nothing.
    """
    if preset not in PRESETS:
        raise ValueError(f"unknown decomposition preset {preset!r}; expected one of {list(PRESETS)}")
    parameters = PRESETS[preset]
    repair: dict[str, Any] = {}
    if preset == "scan":
        repaired = repair_for_decomposition(vertices, faces)
        parameters = scan_parameters(repaired)
        vertices, faces, simplified = simplify_for_decomposition(repaired.vertices, repaired.faces, scan_max_faces)
        repair = {"repair": {"holes_closed": repaired.holes_closed, "watertight": repaired.watertight,
                             "version": SCAN_REPAIR_VERSION, **({"simplified": simplified} if simplified else {})}}
    description: dict[str, Any] = {
        "method": "convex_hull" if parameters is None else "coacd",
        "preset": preset,
        "parameters": parameters.as_dict() if parameters is not None else {},
        **repair,
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
            parts = (_scan_parts(vertices, faces, parameters, description, notes) if preset == "scan"
                     else _run_coacd(vertices, faces, parameters))
        except Exception as error:
            parts, reason = [], f"coacd raised {error!r}"
        else:
            reason = "coacd returned no part"
        if not parts:
            notes.append(f"{reason}; using the convex hull as the collision shape")
            description = {"method": "convex_hull", "preset": preset, "fallback_from": description}
            parts = _hull_parts(vertices, faces)
    if path is not None and not notes:  # a crash or a fallback runs again: the description says what ran
        _save(path, key, parts)
    elif path is not None:  # a fallback is not cached: nor may a bad file stay
        path.unlink(missing_ok=True)
    return Decomposition(parts, description, notes, warnings=warnings)


def description_json(description: dict[str, Any]) -> str:
    """The ``decomposition`` column's text."""
    return json.dumps(description, sort_keys=True)
