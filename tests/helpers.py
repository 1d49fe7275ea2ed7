"""Small, real inputs for tests of the later stages.

Simple tools built from convex primitives, each primitive labelled with a
part, written as genuine rows of the ``models`` table. Tests of the grasps,
checks, scenes and samples stages use them so that they do not depend on the
(slower) models stage; the models stage has its own tests.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import trimesh

from osgd.schemas import MODELS
from osgd.store import ShardStore
from osgd.taxonomy import PART_INDEX

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
