"""Small, real inputs for tests of the later stages.

Simple tools built from convex primitives, each primitive labelled with a
part, written as genuine rows of the ``models`` table. Tests of the grasps,
checks, scenes and samples stages use them so that they do not depend on the
(slower) models stage; the models stage has its own tests.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import trimesh

from osgd.contract.schemas import MODELS
from osgd.contract.taxonomy import PART_INDEX
from osgd.store import ShardStore

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
OSGD_MODELS = SHARED / "osgd-models"


def _box(extents, centre) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(centre))


def _cylinder_x(radius, length, centre) -> trimesh.Trimesh:
    mesh = trimesh.creation.cylinder(radius=radius, height=length, sections=16)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    mesh.apply_translation(centre)
    return mesh


def hammer_parts() -> list[tuple[str, trimesh.Trimesh]]:
    """A 0.30 m hammer along x: handle (x < 0.1) and a heavy head at +x."""
    return [
        ("handle", _cylinder_x(0.0125, 0.24, [-0.03, 0.0, 0.0])),
        ("head", _box([0.03, 0.10, 0.03], [0.105, 0.0, 0.0])),
    ]


def screwdriver_parts() -> list[tuple[str, trimesh.Trimesh]]:
    """A 0.22 m screwdriver along x: handle at -x, thin shaft at +x."""
    return [
        ("handle", _cylinder_x(0.015, 0.10, [-0.06, 0.0, 0.0])),
        ("shaft", _cylinder_x(0.0035, 0.12, [0.05, 0.0, 0.0])),
    ]


def block_parts() -> list[tuple[str, trimesh.Trimesh]]:
    """A compact 4 x 4 x 12 cm block labelled as a handle (easy to grasp)."""
    return [("handle", _box([0.12, 0.04, 0.04], [0.0, 0.0, 0.0]))]


def model_row(
    name: str,
    category: str,
    parts: list[tuple[str, trimesh.Trimesh]],
    density: float = 700.0,
    friction: tuple[float, float, float] = (0.8, 0.01, 0.01),
    annotated_pairs: list[dict] | None = None,
) -> dict:
    """One row of the ``models`` table for a tool made of convex parts."""
    meshes = [mesh for _, mesh in parts]
    combined = trimesh.util.concatenate(meshes)
    face_parts = np.concatenate(
        [np.full(len(mesh.faces), PART_INDEX[part], dtype=np.int8) for part, mesh in parts]
    )
    volume = sum(mesh.volume for mesh in meshes)
    mass = density * volume
    centre = sum(mesh.volume * mesh.center_mass for mesh in meshes) / volume
    inertia = np.zeros((3, 3))
    for mesh in meshes:
        part_mass = density * mesh.volume
        offset = mesh.center_mass - centre
        inertia += mesh.moment_inertia * density + part_mass * (
            np.dot(offset, offset) * np.eye(3) - np.outer(offset, offset)
        )
    digest = hashlib.sha256(combined.vertices.tobytes() + combined.faces.tobytes() + category.encode())
    return {
        "model_id": digest.hexdigest()[:16],
        "name": name,
        "category": category,
        "source": "test",
        "scale": 1.0,
        "length": float(max(combined.extents)),
        "vertices": combined.vertices.tolist(),
        "faces": combined.faces.astype(np.int32).tolist(),
        "face_parts": face_parts.tolist(),
        "convex_parts": [
            {"vertices": mesh.vertices.tolist(), "faces": mesh.faces.astype(np.int32).tolist()} for mesh in meshes
        ],
        "decomposition": json.dumps({"method": "primitives"}),
        "density": density,
        "mass": float(mass),
        "center_of_mass": centre.tolist(),
        "inertia": inertia.reshape(-1).tolist(),
        "friction": list(friction),
        "annotated_pairs": annotated_pairs or [],
        "provenance": json.dumps({"test": name}),
    }


def tool_of_mass(name: str, mesh: trimesh.Trimesh, mass: float, friction: float) -> dict:
    """A one-part ``models`` row (a handle) of ``mesh`` weighing ``mass`` kg with lateral ``friction``."""
    return model_row(name, "knife", [("handle", mesh)], density=mass / mesh.volume, friction=(friction, 0.01, 0.01))


def bar_mesh(section: str, length: float = 0.2, thickness: float = 0.015) -> trimesh.Trimesh:
    """A bar along x, centred on the origin: a ``"square"`` or ``"round"`` section ``thickness`` across."""
    if section == "round":
        return _cylinder_x(thickness / 2, length, [0.0, 0.0, 0.0])
    return _box([length, thickness, thickness], [0.0, 0.0, 0.0])


def models_table(rows: list[dict]) -> pa.Table:
    """Rows as a table in the ``models`` schema."""
    return pa.Table.from_pylist(rows, schema=MODELS)


def write_models(store: ShardStore, rows: list[dict], key: str = "0" * 64) -> str:
    """Write rows as one ``models`` shard; returns its key."""
    store.write("models", key, "fixture", models_table(rows))
    return key


def fixture_models() -> list[dict]:
    """A hammer, a screwdriver and a block."""
    return [
        model_row("test/hammer", "hammer", hammer_parts()),
        model_row("test/screwdriver", "screwdriver", screwdriver_parts()),
        model_row("test/block", "knife", block_parts()),
    ]


def synthetic_sample_row(
    rng: np.random.Generator, index: int, height: int = 128, width: int = 128, split: str = "train",
    model_prefix: str = "synthetic",
) -> dict:
    """A learnable stand-in for a rendered sample, as a real ``samples`` row.

    Two to four bars lie on a table at 0.8 m; each bar's height above the
    table encodes its category, and grasps lie across it: the category's task
    on the half towards the bar's start ("handle"), "hand over" on the other
    half. Used by togcrf tests before (and independently of) the renderer.
    Each bar's model id is ``model_prefix`` and its category number.
    """
    from osgd.contract.encoding import encode_depth, encode_mask  # noqa: PLC0415
    from osgd.contract.taxonomy import CATEGORIES, CATEGORY_TASK  # noqa: PLC0415

    depth = np.full((height, width), 0.8, dtype=np.float64)
    mask = np.zeros((height, width), dtype=np.uint8)
    objects, grasps = [], []
    count = int(rng.integers(2, 5))
    for object_index in range(count):
        category_number = int(rng.integers(0, 3))
        category = CATEGORIES[category_number]
        length = rng.uniform(0.45, 0.7) * min(height, width)
        thickness = rng.uniform(0.08, 0.12) * min(height, width)
        angle = rng.uniform(-np.pi / 2, np.pi / 2)
        centre = rng.uniform(0.3, 0.7, size=2) * [width, height]
        direction = np.array([np.cos(angle), np.sin(angle)])
        normal = np.array([-direction[1], direction[0]])
        ys, xs = np.mgrid[0:height, 0:width]
        offset = np.stack([xs - centre[0], ys - centre[1]], axis=-1)
        along = offset @ direction
        across = offset @ normal
        inside = (np.abs(along) <= length / 2) & (np.abs(across) <= thickness / 2)
        depth[inside] = 0.8 - 0.02 * (category_number + 1)
        mask[inside] = object_index + 1
        for step in np.linspace(-0.4, 0.4, 7):
            point = centre + step * length * direction
            closing_angle = (angle + np.pi / 2 + np.pi / 2) % np.pi - np.pi / 2
            task = CATEGORY_TASK[category] if step < 0 else "hand over"
            grasps.append({
                "object_index": object_index,
                "grasp_id": len(grasps),
                "task": task,
                "rectangle": [float(point[0]), float(point[1]), float(thickness * 1.6), float(thickness * 0.6),
                              float(closing_angle)],
                "position": [0.0, 0.0, 0.8],
                "quaternion": [0.0, 0.0, 0.0, 1.0],
                "width": 0.04,
            })
        objects.append({"object_index": object_index, "model_id": f"{model_prefix}{category_number}",
                        "category": category, "box": [0.0, 0.0, 0.0, 0.0], "visible_fraction": 1.0})
    for obj in objects:
        ys, xs = np.nonzero(mask == obj["object_index"] + 1)
        obj["box"] = [float(xs.min()), float(ys.min()), float(xs.max()), float(ys.max())] if len(xs) else [0.0] * 4
        obj["visible_fraction"] = 1.0 if len(xs) else 0.0
    objects = [obj for obj in objects if obj["visible_fraction"] > 0]
    kept = {obj["object_index"] for obj in objects}
    grasps = [grasp for grasp in grasps if grasp["object_index"] in kept]
    noisy = depth + rng.normal(0.0, 0.001, size=depth.shape)
    return {
        "sample_id": f"synthetic_{index:06d}", "scene_id": f"synthetic_{index:06d}", "split": split,
        "height": height, "width": width,
        "depth": encode_depth(noisy), "depth_clean": encode_depth(depth), "mask": encode_mask(mask),
        "intrinsics": [365.5, 365.5, width / 2 - 0.5, height / 2 - 0.5],
        "camera_position": [0.0, 0.0, 0.8], "camera_quaternion": [1.0, 0.0, 0.0, 0.0],
        "renderer": "synthetic", "objects": objects, "grasps": grasps,
    }


def write_synthetic_samples(store: ShardStore, count: int, seed: int = 0, test_every: int = 5,
                            height: int = 128, width: int = 128, pipeline: str = "synthetic") -> list[str]:
    """Write ``count`` synthetic samples in shards of 8; returns the keys.

    Every ``test_every``-th sample is in the test split. Also writes a
    manifest named ``pipeline`` listing the shards, as the pipeline does; the
    bars' model ids start with the pipeline's name.
    """
    from osgd.contract.schemas import SAMPLES, SCHEMA_VERSION  # noqa: PLC0415

    rng = np.random.default_rng(seed)
    rows = [synthetic_sample_row(rng, index, height, width, "test" if index % test_every == 0 else "train",
                                 model_prefix=pipeline) for index in range(count)]
    records = []
    for start in range(0, count, 8):
        key = hashlib.sha256(f"{pipeline}-{seed}-{start}-{count}".encode()).hexdigest()
        records.append(store.write("samples", key, f"synthetic_{start}",
                                   pa.Table.from_pylist(rows[start:start + 8], schema=SAMPLES)))
    store.write_manifest(pipeline, {"pipeline": pipeline, "schema_version": SCHEMA_VERSION, "stages": {
        "samples": {"shards": [record.as_dict() for record in records]}}})
    return [record.key for record in records]


def silhouette_pixels(obj: Any, intrinsics: Any, pose: Any) -> int:
    """Pixels the object covers alone, counted the direct way (a reference for the stage's faster count).

    A new embree scene of the posed mesh, world rays: the reference that
    ``osgd.samples.boxes.SilhouetteCounter`` and the embree renderer's
    silhouettes are tested against.
    """
    from embreex import mesh_construction, rtcore_scene  # noqa: PLC0415

    world = obj.world_vertices()
    camera = pose.world_to_camera(world)
    if np.any(camera[:, 2] <= 1e-6):
        return 0
    pixels = intrinsics.project(camera)
    low = np.floor(pixels.min(axis=0)).astype(np.int64)
    high = np.ceil(pixels.max(axis=0)).astype(np.int64)
    rows, columns = np.mgrid[low[1] : high[1] + 1, low[0] : high[0] + 1]
    rays = np.stack(
        [(columns.reshape(-1) - intrinsics.cx) / intrinsics.fx,
         (rows.reshape(-1) - intrinsics.cy) / intrinsics.fy,
         np.ones(columns.size)],
        axis=1,
    )
    directions = rays @ pose.rotation.T
    origins = np.broadcast_to(pose.position, directions.shape)
    scene = rtcore_scene.EmbreeScene()
    mesh_construction.TriangleMesh(scene, world.astype(np.float32), np.asarray(obj.faces, dtype=np.int32))
    hits = scene.run(origins.astype(np.float32), directions.astype(np.float32))
    return int(np.count_nonzero(np.asarray(hits) >= 0))


#: The golden pipeline's config.
GOLDEN_PIPELINE = Path(__file__).resolve().parents[1] / "pipelines" / "golden.toml"


def run_golden(data_dir: Path, environment: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """Build the golden pipeline into ``data_dir`` as ``osgd --workers 2 run`` does (the kernels it pins, hash
    seed 0, ``environment`` added); fails the test, with the run's output, if the run fails."""
    result = subprocess.run(
        [sys.executable, "-m", "osgd", "--data-dir", str(data_dir), "--workers", "2", "run", str(GOLDEN_PIPELINE)],
        capture_output=True, text=True, env={**os.environ, "PYTHONHASHSEED": "0", **(environment or {})},
        check=False,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    return result
