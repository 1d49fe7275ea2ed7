"""The one definition of every Parquet table osgd writes.

Tables, in the order data flows through the pipeline::

    models -> grasps -> checks -> scenes -> samples

Conventions shared by all tables (see ``docs/architecture.md``):

- lengths in metres, angles in radians, masses in kilograms;
- a 3-vector is ``fixed_size_list<float64, 3>``; a quaternion is
  ``fixed_size_list<float64, 4>`` in ``(x, y, z, w)`` order (pybullet's and
  scipy's order);
- a mesh is a pair of columns ``*_vertices`` (list of 3-vectors) and
  ``*_faces`` (list of ``fixed_size_list<int32, 3>``, counter-clockwise seen
  from outside);
- every file carries ``osgd.schema_version``, ``osgd.table`` and
  ``osgd.key`` in its Parquet key-value metadata.

The helpers at the end turn these columns into numpy arrays and back.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Final

import numpy as np
import pyarrow as pa

from osgd.contract.taxonomy import VOCABULARY, vocabulary_json

#: Bumped whenever a table's columns change meaning or type.
SCHEMA_VERSION: Final[int] = 1

VEC3 = pa.list_(pa.float64(), 3)
QUAT = pa.list_(pa.float64(), 4)
FACE = pa.list_(pa.int32(), 3)
VERTICES = pa.list_(VEC3)
FACES = pa.list_(FACE)

#: One row per object model.
MODELS = pa.schema(
    [
        pa.field("model_id", pa.string(), nullable=False,
                 metadata={"doc": "sha256 of the scaled mesh and category, hex, first 16 chars"}),
        pa.field("name", pa.string(), nullable=False,
                 metadata={"doc": "human-readable name, e.g. hammer_001 or procedural/hammer_03"}),
        pa.field("category", pa.string(), nullable=False, metadata={"doc": "one of taxonomy.CATEGORIES"}),
        pa.field("source", pa.string(), nullable=False, metadata={"doc": "osgd | procedural | user"}),
        pa.field("scale", pa.float64(), nullable=False,
                 metadata={"doc": "factor from source mesh units to metres"}),
        pa.field("length", pa.float64(), nullable=False, metadata={"doc": "longest extent, m"}),
        pa.field("vertices", VERTICES, nullable=False, metadata={"doc": "object frame, m"}),
        pa.field("faces", FACES, nullable=False),
        pa.field("face_parts", pa.list_(pa.int8()), nullable=False,
                 metadata={"doc": "index into taxonomy.PARTS per face, -1 unknown"}),
        pa.field("convex_parts", pa.list_(pa.struct([("vertices", VERTICES), ("faces", FACES)])),
                 nullable=False, metadata={"doc": "collision compound, object frame, m"}),
        pa.field("decomposition", pa.string(), nullable=False,
                 metadata={"doc": "JSON: method, preset and every parameter used"}),
        pa.field("density", pa.float64(), nullable=False, metadata={"doc": "kg/m^3"}),
        pa.field("mass", pa.float64(), nullable=False, metadata={"doc": "kg"}),
        pa.field("center_of_mass", VEC3, nullable=False, metadata={"doc": "object frame, m"}),
        pa.field("inertia", pa.list_(pa.float64(), 9), nullable=False,
                 metadata={"doc": "3x3 row-major about the centre of mass, object axes, kg m^2"}),
        pa.field("friction", pa.list_(pa.float64(), 3), nullable=False,
                 metadata={"doc": "lateral, rolling, spinning coefficients"}),
        pa.field("annotated_pairs", pa.list_(pa.struct(
            [("task", pa.string()), ("contact_a", VEC3), ("contact_b", VEC3), ("file", pa.string())])),
            nullable=False, metadata={"doc": "hand-made contact pairs, object frame, m (OSGD, sidecar)"}),
        pa.field("provenance", pa.string(), nullable=False,
                 metadata={"doc": "JSON: relative source path or generator parameters, repairs, warnings"}),
    ]
)

#: One row per 6-DoF grasp of a model.
GRASPS = pa.schema(
    [
        pa.field("model_id", pa.string(), nullable=False),
        pa.field("grasp_id", pa.int32(), nullable=False, metadata={"doc": "unique within the model"}),
        pa.field("task", pa.string(), nullable=False, metadata={"doc": "one of taxonomy.TASKS"}),
        pa.field("position", VEC3, nullable=False, metadata={"doc": "grasp centre, object frame, m"}),
        pa.field("quaternion", QUAT, nullable=False,
                 metadata={"doc": "gripper frame in the object frame, (x, y, z, w); see osgd.gripper"}),
        pa.field("width", pa.float64(), nullable=False, metadata={"doc": "pre-grasp opening, m"}),
        pa.field("contact_a", VEC3, nullable=False, metadata={"doc": "object frame, m"}),
        pa.field("contact_b", VEC3, nullable=False, metadata={"doc": "object frame, m"}),
        pa.field("origin", pa.string(), nullable=False,
                 metadata={"doc": "annotation file (e.g. annotations/cut.npy) or 'antipodal'"}),
        pa.field("pair_index", pa.int32(), nullable=False,
                 metadata={"doc": "contact pair the grasp came from; approach variants share it"}),
        pa.field("quality", pa.float64(), nullable=False,
                 metadata={"doc": "sampler score in [0, 1]; NaN for hand-made pairs"}),
    ]
)

#: One row per simulated grasp trial.
CHECKS = pa.schema(
    [
        pa.field("model_id", pa.string(), nullable=False),
        pa.field("grasp_id", pa.int32(), nullable=False),
        pa.field("stable", pa.bool_(), nullable=False,
                 metadata={"doc": "held under the stage's criterion (checks.criterion): lift_stable or shake_stable"}),
        pa.field("lift_stable", pa.bool_(), nullable=False,
                 metadata={"doc": "closed, lifted 10 cm and held: the paper's check"}),
        pa.field("shake_stable", pa.bool_(), nullable=True,
                 metadata={"doc": "held through three linear and three rotational shakes as well (ACRONYM); "
                                  "null for a grasp held on the lift whose shakes did not run (checks.store_shake)"}),
        pa.field("fail_reason", pa.string(), nullable=False,
                 metadata={"doc": "'' | approach_collision | empty_close | slipped_on_lift | dropped_on_shake"}),
        pa.field("slip_distance", pa.float64(), nullable=False,
                 metadata={"doc": "object displacement relative to the gripper, m"}),
        pa.field("slip_rotation", pa.float64(), nullable=False,
                 metadata={"doc": "object rotation relative to the gripper, rad"}),
        pa.field("final_opening", pa.float64(), nullable=False, metadata={"doc": "m"}),
        pa.field("sim_steps", pa.int32(), nullable=False),
    ]
)

SCENE_OBJECT = pa.struct(
    [
        ("model_id", pa.string()),
        ("category", pa.string()),
        ("position", VEC3),
        ("quaternion", QUAT),
    ]
)

#: One row per stacking scene.
SCENES = pa.schema(
    [
        pa.field("scene_id", pa.string(), nullable=False, metadata={"doc": "e.g. scene_000042"}),
        pa.field("scene_index", pa.int64(), nullable=False),
        pa.field("seed", pa.int64(), nullable=False, metadata={"doc": "seed of the accepted attempt"}),
        pa.field("attempts", pa.int32(), nullable=False, metadata={"doc": "1 + number of redraws"}),
        pa.field("rejections", pa.string(), nullable=False,
                 metadata={"doc": "JSON: redraw count by reason"}),
        pa.field("objects", pa.list_(SCENE_OBJECT), nullable=False,
                 metadata={"doc": "pose of each mesh frame in the world frame"}),
        pa.field("settled", pa.bool_(), nullable=False),
        pa.field("sim_time", pa.float64(), nullable=False, metadata={"doc": "simulated seconds"}),
        pa.field("sim_steps", pa.int32(), nullable=False),
    ]
)

SAMPLE_OBJECT = pa.struct(
    [
        ("object_index", pa.int32()),
        ("model_id", pa.string()),
        ("category", pa.string()),
        ("box", pa.list_(pa.float32(), 4)),
        ("visible_fraction", pa.float32()),
    ]
)

SAMPLE_GRASP = pa.struct(
    [
        ("object_index", pa.int32()),
        ("grasp_id", pa.int32()),
        ("task", pa.string()),
        ("rectangle", pa.list_(pa.float32(), 5)),
        ("position", VEC3),
        ("quaternion", QUAT),
        ("width", pa.float64()),
    ]
)

#: One row per rendered depth image.
SAMPLES = pa.schema(
    [
        pa.field("sample_id", pa.string(), nullable=False, metadata={"doc": "e.g. scene_000042_view0"}),
        pa.field("scene_id", pa.string(), nullable=False),
        pa.field("split", pa.string(), nullable=False, metadata={"doc": "train | test"}),
        pa.field("height", pa.int32(), nullable=False),
        pa.field("width", pa.int32(), nullable=False),
        pa.field("depth", pa.binary(), nullable=False,
                 metadata={"doc": "noisy depth, 16-bit PNG, millimetres, 0 = no reading"}),
        pa.field("depth_clean", pa.binary(), nullable=False,
                 metadata={"doc": "noise-free depth, 16-bit PNG, millimetres"}),
        pa.field("mask", pa.binary(), nullable=False,
                 metadata={"doc": "instance mask, 8-bit PNG, 0 background, object_index + 1"}),
        pa.field("intrinsics", pa.list_(pa.float64(), 4), nullable=False, metadata={"doc": "fx, fy, cx, cy, px"}),
        pa.field("camera_position", VEC3, nullable=False, metadata={"doc": "camera origin in the world, m"}),
        pa.field("camera_quaternion", QUAT, nullable=False,
                 metadata={"doc": "camera frame (OpenCV) in the world frame, (x, y, z, w)"}),
        pa.field("renderer", pa.string(), nullable=False, metadata={"doc": "egl | embree | tiny"}),
        pa.field("objects", pa.list_(SAMPLE_OBJECT), nullable=False,
                 metadata={"doc": "box = (x1, y1, x2, y2) px of the visible pixels"}),
        pa.field("grasps", pa.list_(SAMPLE_GRASP), nullable=False,
                 metadata={"doc": "rectangle = (x, y, h, w, theta): centre px, opening px, finger width px, "
                                  "angle of the closing direction to the image x axis, rad, in [-pi/2, pi/2); "
                                  "position/quaternion: the 3-D grasp in the camera frame"}),
    ],
    metadata={b"osgd.vocabulary": vocabulary_json(VOCABULARY)},
)

def samples_schema(vocabulary: Mapping[str, Sequence[str]]) -> pa.Schema:
    """:data:`SAMPLES` recording another vocabulary (``osgd.vocabulary``): that of a pipeline's taxonomy."""
    return SAMPLES.with_metadata({**(SAMPLES.metadata or {}), b"osgd.vocabulary": vocabulary_json(vocabulary)})


#: Every table by name; the stage framework looks schemas up here.
TABLES: Final[dict[str, pa.Schema]] = {
    "models": MODELS,
    "grasps": GRASPS,
    "checks": CHECKS,
    "scenes": SCENES,
    "samples": SAMPLES,
}


def vectors_to_arrow(values: np.ndarray, width: int = 3) -> pa.FixedSizeListArray:
    """Turn an (N, width) float array into a fixed-size-list array.

    Parameters
    ----------
    values : (N, width) array_like of float
    width : int
        Length of each vector (3 for positions, 4 for quaternions).
    """
    flat = np.ascontiguousarray(values, dtype=np.float64).reshape(-1)
    return pa.FixedSizeListArray.from_arrays(pa.array(flat, type=pa.float64()), width)


def vectors_from_arrow(column: pa.Array | pa.ChunkedArray, width: int = 3) -> np.ndarray:
    """Turn a fixed-size-list column into an (N, width) float64 array."""
    if isinstance(column, pa.ChunkedArray):
        column = column.combine_chunks()
    return np.asarray(column.flatten().to_numpy(zero_copy_only=False), dtype=np.float64).reshape(-1, width)


def mesh_to_arrow(vertices: np.ndarray, faces: np.ndarray) -> tuple[list, list]:
    """Python-list form of one mesh for a ``VERTICES``/``FACES`` cell pair.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    """
    return (
        np.asarray(vertices, dtype=np.float64).reshape(-1, 3).tolist(),
        np.asarray(faces, dtype=np.int32).reshape(-1, 3).tolist(),
    )


def mesh_from_arrow(vertices_cell: pa.Scalar | list, faces_cell: pa.Scalar | list) -> tuple[np.ndarray, np.ndarray]:
    """Numpy form of one mesh cell pair.

    Returns
    -------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    """
    def flat(cell, dtype):
        if isinstance(cell, pa.Scalar):
            values = cell.values
            if values is None:
                return np.zeros((0, 3), dtype=dtype)
            return np.asarray(values.flatten().to_numpy(zero_copy_only=False), dtype=dtype).reshape(-1, 3)
        return np.asarray(cell, dtype=dtype).reshape(-1, 3)

    return flat(vertices_cell, np.float64), flat(faces_cell, np.int64)


def empty_table(table: str) -> pa.Table:
    """A table with no rows and the schema of ``table``."""
    return TABLES[table].empty_table()


def schemas_markdown() -> str:
    """The table schemas as Markdown: ``docs/schemas.md`` is this text.

    Regenerate with ``python -m osgd.contract.schemas > docs/schemas.md``; a test
    fails when the two disagree.
    """
    lines = [
        "# Table schemas",
        "",
        f"Generated from `osgd/contract/schemas.py` (schema version {SCHEMA_VERSION}) by "
        "`python -m osgd.contract.schemas > docs/schemas.md`; do not edit by hand.",
        "",
        "Lengths in metres, angles in radians, masses in kilograms; quaternions are "
        "`(x, y, z, w)`. Frames: see `docs/architecture.md`.",
    ]
    for name, schema in TABLES.items():
        lines += ["", f"## `{name}`", "", "| column | type | meaning |", "| --- | --- | --- |"]
        for field in schema:
            doc = (field.metadata or {}).get(b"doc", b"").decode().replace("|", "\\|")
            kind = str(field.type).replace("|", "\\|")
            lines.append(f"| `{field.name}` | `{kind}` | {doc} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(schemas_markdown(), end="")
