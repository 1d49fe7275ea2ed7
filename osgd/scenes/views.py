"""Scenes as posed meshes, and orthographic ray-cast views of them.

Shared by the statistics (top-down overlap and occlusion) and the pictures.
A view casts parallel rays on a regular grid (embree, exact on the models'
visual meshes; REFERENCE section 8) and records, per pixel, the first object
hit and how far along the ray it was.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow.compute as pc
from scipy.spatial.transform import Rotation

from osgd.contract.schemas import mesh_from_arrow
from osgd.raycast import EmbreeScenes, rotate_rows
from osgd.store import ShardStore


def load_models(store: ShardStore, model_ids: Iterable[str], columns: Sequence[str] | None = None,
                ) -> dict[str, dict[str, Any]]:
    """``models`` rows by model id, from whatever models shards the data dir holds.

    Model ids are content hashes, so a row found in any shard is the right one.

    Raises
    ------
    KeyError
        If some model id is in no models shard.
    """
    wanted = set(model_ids)
    found: dict[str, dict[str, Any]] = {}
    for key in store.keys_on_disk("models"):
        if not wanted - set(found):
            break
        ids = store.read("models", key, ["model_id"]).column("model_id")
        if not pc.any(pc.is_in(ids, value_set=_string_array(wanted))).as_py():
            continue
        table = store.read("models", key, columns)
        for row in table.to_pylist():
            if row["model_id"] in wanted:
                found[row["model_id"]] = row
    missing = sorted(wanted - set(found))
    if missing:
        raise KeyError(f"model(s) {missing[:5]} are in no models shard under {store.root / 'models'}")
    return found


def _string_array(values: Iterable[str]) -> Any:
    import pyarrow as pa  # noqa: PLC0415

    return pa.array(sorted(values), type=pa.string())


def find_scene(store: ShardStore, scene_id: str) -> dict[str, Any]:
    """The ``scenes`` row called ``scene_id`` (first shard in key order that has it).

    Raises
    ------
    KeyError
        If no scenes shard holds it.
    """
    keys = store.keys_on_disk("scenes")
    for key in keys:
        table = store.read("scenes", key)
        mask = pc.equal(table.column("scene_id"), scene_id)
        if pc.any(mask).as_py():
            return table.filter(mask).to_pylist()[0]
    raise KeyError(f"no scene {scene_id!r} in the {len(keys)} scenes shard(s) under {store.root / 'scenes'}")


@dataclass(frozen=True)
class PosedMesh:
    """One object of a scene, its visual mesh in the world frame.

    Attributes
    ----------
    vertices : (V, 3) float64
        World frame, metres: ``rotation @ local + position`` per vertex.
    faces : (F, 3) int64
    category : str
    model_id : str
    local_vertices : (V, 3) float64
        The model's own (mesh-frame) vertices.
    rotation : (3, 3) float64
        Mesh frame to world.
    position : (3,) float64
        The mesh frame's origin in the world, metres.
    """

    vertices: np.ndarray
    faces: np.ndarray
    category: str
    model_id: str
    local_vertices: np.ndarray
    rotation: np.ndarray
    position: np.ndarray


def posed_meshes(scene: Mapping[str, Any], models: Mapping[str, Mapping[str, Any]]) -> list[PosedMesh]:
    """Each object's mesh placed at its stored mesh-frame pose."""
    meshes = []
    for obj in scene["objects"]:
        model = models[obj["model_id"]]
        vertices, faces = mesh_from_arrow(model["vertices"], model["faces"])
        rotation = Rotation.from_quat(obj["quaternion"])
        position = np.asarray(obj["position"], dtype=np.float64)
        meshes.append(PosedMesh(rotation.apply(vertices) + position, faces, str(obj["category"]),
                                str(obj["model_id"]), vertices, rotation.as_matrix(), position))
    return meshes


def with_mesh_arrays(models: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """The rows with ``vertices`` and ``faces`` as (N, 3) arrays, converted once for many scenes.

    A row from ``Table.to_pylist()`` holds them as flat lists, and turning
    them into arrays for every object of every scene is slow.

    Parameters
    ----------
    models : mapping of model id to ``models`` row (dict)

    Returns
    -------
    dict of model id to dict
        Copies of the rows, ``vertices`` (V, 3) float64 and ``faces`` (F, 3) int64.
    """
    converted = {}
    for model_id, row in models.items():
        vertices, faces = mesh_from_arrow(row["vertices"], row["faces"])
        converted[model_id] = {**row, "vertices": vertices, "faces": faces}
    return converted


@functools.cache
def view_scenes() -> EmbreeScenes:
    """This process's embree scenes of the models' meshes for :func:`cast_view`, by model id."""
    return EmbreeScenes()


@dataclass(frozen=True)
class View:
    """An orthographic view of a scene.

    Attributes
    ----------
    object_index : (H, W) int32
        Index of the first object hit, -1 where the ray hit nothing.
    distance : (H, W) float64
        Along the ray from the image plane to the hit, metres (inf: no hit).
    footprints : (N, H, W) bool
        Where each object alone would be hit (its silhouette, hidden parts too).
    extent : (left, right, bottom, top) float
        World coordinates of the image edges along its horizontal and vertical axes.
    """

    object_index: np.ndarray
    distance: np.ndarray
    footprints: np.ndarray
    extent: tuple[float, float, float, float]


def cast_view(meshes: Sequence[PosedMesh], axis: str = "top", pixel: float = 0.002, margin: float = 0.02) -> View:
    """Cast parallel rays at the scene along one world axis.

    Parameters
    ----------
    meshes : sequence of PosedMesh
    axis : {"top", "side"}
        ``"top"``: rays straight down (-z), image axes world x (right) and y
        (up). ``"side"``: rays along +y from in front, image axes world x
        (right) and z (up).
    pixel : float
        Pixel size, metres.
    margin : float
        Added around the objects' bounds, metres.
    """
    points = np.concatenate([mesh.vertices for mesh in meshes])
    low, high = points.min(axis=0) - margin, points.max(axis=0) + margin
    horizontal, vertical, depth = (0, 1, 2) if axis == "top" else (0, 2, 1)
    if axis == "side":
        low[2] = min(low[2], 0.0)
    columns = np.arange(low[horizontal] + pixel / 2, high[horizontal], pixel)
    rows = np.arange(high[vertical] - pixel / 2, low[vertical], -pixel)
    grid_h, grid_v = np.meshgrid(columns, rows)
    origins = np.zeros((grid_h.size, 3))
    origins[:, horizontal] = grid_h.ravel()
    origins[:, vertical] = grid_v.ravel()
    direction = np.zeros(3)
    if axis == "top":
        origins[:, depth] = high[depth] + 1.0
        direction[depth] = -1.0
    else:
        origins[:, depth] = low[depth] - 1.0
        direction[depth] = 1.0
    shape = grid_h.shape
    distances = np.full((len(meshes), *shape), np.inf)
    for index, mesh in enumerate(meshes):
        # Cast in the mesh's frame at its scene built once per process (building one per object and view is
        # slow); the distances below are on the world triangles.
        scene = view_scenes().scene(mesh.model_id, mesh.local_vertices, mesh.faces)
        local_origins = rotate_rows(origins - mesh.position, mesh.rotation.T).astype(np.float32)
        local_direction = rotate_rows(direction[None, :], mesh.rotation.T)[0]
        local_directions = np.broadcast_to(local_direction, origins.shape).astype(np.float32)
        triangles = np.asarray(scene.run(local_origins, local_directions))
        hit = triangles >= 0
        # Distance along the ray to the hit triangle's plane.
        corners = mesh.vertices[mesh.faces[triangles[hit]]]
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        along = np.einsum("ij,j->i", normals, direction)
        along = np.where(np.abs(along) < 1e-15, 1e-15, along)
        values = np.einsum("ij,ij->i", normals, corners[:, 0] - origins[hit]) / along
        flat = distances[index].reshape(-1)
        flat[hit] = values
    nearest = np.argmin(distances, axis=0)
    nearest_distance = np.min(distances, axis=0)
    object_index = np.where(np.isfinite(nearest_distance), nearest, -1).astype(np.int32)
    extent = (float(low[horizontal]), float(low[horizontal] + pixel * len(columns)),
              float(high[vertical] - pixel * len(rows)), float(high[vertical]))
    return View(object_index, nearest_distance, np.isfinite(distances), extent)
