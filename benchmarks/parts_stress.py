"""Stress cases for the automatic parts (``benchmarks/bench_parts.py``): a tool mesh changed as scans, exports and
other people's models change it, with the map that carries its known parts or its hand-made contact pairs along.

Every case ends in a random rigid pose (the parts must not depend on the pose). A :class:`Stressed` holds the new
mesh, for each of its faces the original face it comes from (so the generator's labels follow), and the affine
map of points (4 x 4; the authors' contact pairs are moved by it; the identity where the geometry is only
resampled). The generic cases apply to any tool; the procedural ones need the generator's own labels to find
where a part begins.

Lengths in metres; meshes at real size.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

import numpy as np
import trimesh

from osgd.contract.taxonomy import PART_INDEX

#: Non-uniform scaling: each of the tool's axes by a factor drawn in 1 +- this.
SCALE_SPREAD: Final[float] = 0.15
#: Remeshing: longest edge after subdivision, m (raised where the result would exceed MAX_FACES).
REMESH_EDGE: Final[float] = 0.002
MAX_FACES: Final[int] = 400_000
#: Decimation by vertex clustering: the cell, as a share of the tool's length.
DECIMATE_CELL: Final[float] = 1 / 160
#: Vertex noise: Gaussian, per axis, m.
NOISE: Final[float] = 0.0002
#: Holes: this many patches of faces removed, each the faces whose centroid lies within HOLE_RADIUS (a share
#: of the length) of a face drawn by area.
HOLE_COUNT: Final[int] = 12
HOLE_RADIUS: Final[float] = 0.012


@dataclass
class Stressed:
    """A changed mesh.

    Attributes
    ----------
    mesh : trimesh.Trimesh
    origin : (F',) int
        Per face, the index of the original face it comes from.
    matrix : (4, 4) float
        Affine map of points from the original mesh's frame to the new one's.
    """

    mesh: trimesh.Trimesh
    origin: np.ndarray
    matrix: np.ndarray

    def then(self, other: Stressed) -> Stressed:
        """This change followed by ``other`` (which was applied to this one's mesh)."""
        return Stressed(other.mesh, self.origin[other.origin], other.matrix @ self.matrix)

    def points(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) original-frame points in the new frame."""
        return np.asarray(points, dtype=np.float64) @ self.matrix[:3, :3].T + self.matrix[:3, 3]


def _same(mesh: trimesh.Trimesh) -> Stressed:
    return Stressed(mesh, np.arange(len(mesh.faces)), np.eye(4))


def _affine(mesh: trimesh.Trimesh, matrix: np.ndarray) -> Stressed:
    vertices = np.asarray(mesh.vertices) @ matrix[:3, :3].T + matrix[:3, 3]
    faces = np.asarray(mesh.faces)
    if np.linalg.det(matrix[:3, :3]) < 0:
        faces = faces[:, ::-1]
    return Stressed(trimesh.Trimesh(vertices, faces, process=False), np.arange(len(faces)), matrix)


def pose(mesh: trimesh.Trimesh, rng: np.random.Generator) -> Stressed:
    """A random rotation and a shift of up to 10 cm."""
    matrix = trimesh.transformations.random_rotation_matrix(rng.random(3))
    matrix[:3, 3] = rng.uniform(-0.1, 0.1, 3)
    return _affine(mesh, matrix)


def scaled(mesh: trimesh.Trimesh, rng: np.random.Generator) -> Stressed:
    """Each of the mesh's own axes (x, y, z: the tools lie along them) scaled by 1 +- :data:`SCALE_SPREAD`."""
    return _affine(mesh, np.diag([*rng.uniform(1 - SCALE_SPREAD, 1 + SCALE_SPREAD, 3), 1.0]))


def _subdivided(mesh: trimesh.Trimesh, edge: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices, faces and each face's original face after subdividing to edges of at most ``edge`` (coarser
    where that would exceed :data:`MAX_FACES`)."""
    edge = max(edge, float(np.sqrt(2 * mesh.area / MAX_FACES)) * 1.5)
    vertices, faces, index = trimesh.remesh.subdivide_to_size(
        mesh.vertices, mesh.faces, max_edge=edge, max_iter=20, return_index=True
    )
    return vertices, faces, np.asarray(index)


def remeshed(mesh: trimesh.Trimesh, rng: np.random.Generator) -> Stressed:
    """Subdivided to edges of at most :data:`REMESH_EDGE` (coarser where that would exceed :data:`MAX_FACES`)."""
    vertices, faces, index = _subdivided(mesh, REMESH_EDGE)
    return Stressed(trimesh.Trimesh(vertices, faces, process=False), index, np.eye(4))


def decimated(mesh: trimesh.Trimesh, rng: np.random.Generator) -> Stressed:
    """Vertex clustering: vertices in one cube of :data:`DECIMATE_CELL` x the length merge at their mean; faces
    that lose a corner go, as do duplicates."""
    cell = DECIMATE_CELL * float(mesh.extents.max())
    keys = np.floor(np.asarray(mesh.vertices) / cell).astype(np.int64)
    _, cluster, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    cluster = cluster.ravel()
    vertices = np.zeros((len(counts), 3))
    np.add.at(vertices, cluster, mesh.vertices)
    vertices /= counts[:, None]
    faces = cluster[np.asarray(mesh.faces)]
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    _, first = np.unique(np.sort(faces, axis=1), axis=0, return_index=True)
    unique = np.zeros(len(faces), dtype=bool)
    unique[first] = True
    origin = np.flatnonzero(keep & unique)
    return Stressed(trimesh.Trimesh(vertices, faces[origin], process=False), origin, np.eye(4))


def noisy(mesh: trimesh.Trimesh, rng: np.random.Generator) -> Stressed:
    """Every vertex moved by Gaussian noise of :data:`NOISE` per axis."""
    merged = mesh.copy()
    merged.merge_vertices()
    vertices = merged.vertices + rng.normal(0.0, NOISE, merged.vertices.shape)
    return Stressed(trimesh.Trimesh(vertices, merged.faces, process=False), np.arange(len(merged.faces)), np.eye(4))


def holed(mesh: trimesh.Trimesh, rng: np.random.Generator) -> Stressed:
    """:data:`HOLE_COUNT` small patches of faces removed (the models stage fills what it can).

    Faces longer than a patch is wide are subdivided first, so that a patch is a small hole also where one face
    spans the tool (a procedural handle's side), not a strip along it.
    """
    radius = HOLE_RADIUS * float(mesh.extents.max())
    vertices, faces, index = _subdivided(mesh, 2 * radius)
    fine = trimesh.Trimesh(vertices, faces, process=False)
    centres, area = fine.triangles_center, fine.area_faces
    seeds = rng.choice(len(centres), size=HOLE_COUNT, p=area / area.sum())
    gone = np.zeros(len(centres), dtype=bool)
    for seed in seeds:
        gone |= np.linalg.norm(centres - centres[seed], axis=1) < radius
    kept = np.flatnonzero(~gone)
    return Stressed(trimesh.Trimesh(vertices, faces[kept], process=False), index[kept], np.eye(4))


def scan(mesh: trimesh.Trimesh, rng: np.random.Generator) -> Stressed:
    """Remeshed, noised and holed."""
    first = remeshed(mesh, rng)
    second = first.then(noisy(first.mesh, rng))
    return second.then(holed(second.mesh, rng))


#: Generic cases, applied to every tool (each then posed at random).
GENERIC: Final[dict[str, Callable[[trimesh.Trimesh, np.random.Generator], Stressed]]] = {
    "pose": lambda mesh, rng: _same(mesh),
    "scaled": scaled,
    "remeshed": remeshed,
    "decimated": decimated,
    "noise": noisy,
    "holes": holed,
    "scan": scan,
}


def thickened(mesh: trimesh.Trimesh, factor: float) -> Stressed:
    """The mesh's smallest axis-aligned extent scaled by ``factor`` (pliers with thick arms: seen edge-on, its side
    walls outweigh its faces)."""
    axis = int(np.argmin(mesh.extents))
    scale = np.ones(3)
    scale[axis] = factor
    return _affine(mesh, np.diag([*scale, 1.0]))


# -- procedural cases: deformations that need the generator's labels ---------------------------------------


def _warped(mesh: trimesh.Trimesh, vertices: np.ndarray) -> Stressed:
    return Stressed(trimesh.Trimesh(vertices, mesh.faces, process=False), np.arange(len(mesh.faces)), np.eye(4))


def _part_start(mesh: trimesh.Trimesh, labels: np.ndarray, part: str) -> float:
    """Least x of the faces of ``part`` (procedural tools are built along x, handle at -x)."""
    return float(mesh.vertices[mesh.faces[labels == PART_INDEX[part]]][..., 0].min())


def pliers_arms(mesh: trimesh.Trimesh, labels: np.ndarray, gap: float | None, spread: float = 1.0) -> Stressed:
    """Pliers opened or closed: each arm sheared across, linearly from where the jaws begin (still) to the handle
    end. ``gap``: the gap between the arms at the handle end, m (closed); else the gap times ``spread`` (open)."""
    vertices = np.array(mesh.vertices, dtype=np.float64)
    start, end = _part_start(mesh, labels, "jaws"), float(vertices[:, 0].min())
    handle = vertices[mesh.faces[labels == PART_INDEX["handle"]].ravel()]
    inner = float(np.abs(handle[handle[:, 0] < end + 0.005, 1]).min())
    shift = inner - gap / 2 if gap is not None else inner * (1 - spread)
    share = np.clip((start - vertices[:, 0]) / (start - end), 0.0, 1.0)
    vertices[:, 1] -= np.sign(vertices[:, 1]) * shift * share
    return _warped(mesh, vertices)


def knife_proportions(mesh: trimesh.Trimesh, labels: np.ndarray, handle: float, blade: float) -> Stressed:
    """A knife's handle stretched by ``handle`` and its blade by ``blade`` along its axis, the length kept."""
    vertices = np.array(mesh.vertices, dtype=np.float64)
    start, low, high = _part_start(mesh, labels, "blade"), vertices[:, 0].min(), vertices[:, 0].max()
    x = vertices[:, 0]
    vertices[:, 0] = np.where(x < start, start + (x - start) * handle, start + (x - start) * blade)
    vertices[:, 0] = low + (vertices[:, 0] - vertices[:, 0].min()) * (high - low) / np.ptp(vertices[:, 0])
    return _warped(mesh, vertices)


def spoon_depth(mesh: trimesh.Trimesh, labels: np.ndarray, depth: float) -> Stressed:
    """A spoon's bowl made ``depth`` times as deep (across its thickness, z), fading in over its first quarter."""
    vertices = np.array(mesh.vertices, dtype=np.float64)
    start, end = _part_start(mesh, labels, "bowl"), float(vertices[:, 0].max())
    share = np.clip((vertices[:, 0] - start) / (0.25 * (end - start)), 0.0, 1.0)
    vertices[:, 2] *= 1 + (depth - 1) * share
    return _warped(mesh, vertices)


#: Per category: the procedural cases, each (name, change of a tool built along x and its generator's labels).
PROCEDURAL: Final[dict[str, dict[str, Callable[[trimesh.Trimesh, np.ndarray], Stressed]]]] = {
    "pliers": {
        "closed": lambda mesh, labels: pliers_arms(mesh, labels, gap=0.003),
        "open": lambda mesh, labels: pliers_arms(mesh, labels, gap=None, spread=1.8),
        "edge-on": lambda mesh, labels: thickened(mesh, 2.0),
        "closed edge-on": lambda mesh, labels: pliers_arms(mesh, labels, gap=0.003).then(
            thickened(pliers_arms(mesh, labels, gap=0.003).mesh, 2.0)),
    },
    "knife": {
        "long blade": lambda mesh, labels: knife_proportions(mesh, labels, handle=0.65, blade=1.35),
        "long handle": lambda mesh, labels: knife_proportions(mesh, labels, handle=1.4, blade=0.65),
    },
    "spoon": {
        "shallow bowl": lambda mesh, labels: spoon_depth(mesh, labels, depth=0.45),
        "deep bowl": lambda mesh, labels: spoon_depth(mesh, labels, depth=1.8),
    },
}

#: The authors' pliers: thickened across their thin axis (pairs move with them), seen edge-on.
AUTHORS_EXTRA: Final[dict[str, dict[str, Callable[[trimesh.Trimesh], Stressed]]]] = {
    "pliers": {"edge-on": lambda mesh: thickened(mesh, 2.0)},
}


def case_rng(*names: object) -> np.random.Generator:
    """A generator of its own for each case, from its names only."""
    digest = hashlib.sha256("/".join(map(str, names)).encode()).digest()
    return np.random.default_rng(int.from_bytes(digest[:8], "little"))


def posed(change: Stressed, rng: np.random.Generator) -> Stressed:
    """``change`` followed by a random pose."""
    return change.then(pose(change.mesh, rng))
