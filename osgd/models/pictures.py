"""Pictures of models for people: one model coloured by part, and a contact sheet.

The meshes are drawn by a small painter's-algorithm projection (faces
sorted far to near, shaded by the angle to a light) into matplotlib 2-D
polygons: much faster than matplotlib's 3-D axes for meshes of 50k faces,
which matters for a sheet of 175 models. Each model is seen along its
smallest principal axis, turned a little so that thickness shows.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pyarrow as pa
from matplotlib.collections import PolyCollection
from matplotlib.patches import Patch

from osgd.schemas import mesh_from_arrow
from osgd.store import ShardError, ShardStore
from osgd.taxonomy import PARTS

#: Colour of each part (index into PARTS), then of unknown parts.
PART_COLOURS = np.array(
    [
        [0.12, 0.47, 0.71],  # handle: blue
        [1.00, 0.50, 0.05],  # blade: orange
        [0.17, 0.63, 0.17],  # shaft: green
        [0.84, 0.15, 0.16],  # tip: red
        [0.58, 0.40, 0.74],  # bowl: purple
        [0.55, 0.34, 0.29],  # tines: brown
        [0.89, 0.47, 0.76],  # head: pink
        [0.74, 0.74, 0.13],  # neck: olive
        [0.09, 0.75, 0.81],  # jaws: cyan
        [0.10, 0.10, 0.10],  # bristles: black
    ]
)
UNKNOWN_COLOUR = np.array([0.6, 0.6, 0.6])


def _model_tables(store: ShardStore, columns: list[str] | None = None) -> Iterator[pa.Table]:
    """Every verified, non-empty shard of the models table."""
    for key in store.keys_on_disk("models"):
        try:
            table = store.read("models", key, columns=columns)
        except ShardError:
            continue
        if table.num_rows:
            yield table


def _find_model(store: ShardStore, model_id: str) -> dict:
    for table in _model_tables(store, ["model_id"]):
        ids = table["model_id"].to_pylist()
        if model_id in ids:
            break
    else:
        raise KeyError(f"no model {model_id!r} in {store.root / 'models'}")
    for key in store.keys_on_disk("models"):
        table = store.read("models", key)
        rows = table.filter(pa.compute.equal(table["model_id"], model_id))
        if rows.num_rows:
            return rows.slice(0, 1).to_pylist()[0]
    raise KeyError(f"no model {model_id!r} in {store.root / 'models'}")


def _view_rotation(vertices: np.ndarray) -> np.ndarray:
    """Rows: screen x (longest principal axis), screen y, depth; turned 30 degrees about x."""
    centred = vertices - vertices.mean(axis=0)
    _, _, axes = np.linalg.svd(centred[:: max(1, len(centred) // 5000)], full_matrices=False)
    if np.linalg.det(axes) < 0:
        axes[2] = -axes[2]
    angle = math.radians(30.0)
    tilt = np.array([[1, 0, 0], [0, math.cos(angle), -math.sin(angle)], [0, math.sin(angle), math.cos(angle)]])
    return tilt @ axes


def draw_mesh(axes: plt.Axes, vertices: np.ndarray, faces: np.ndarray, face_parts: np.ndarray) -> None:
    """Draw a mesh into 2-D axes, coloured by part and shaded.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int
    face_parts : (F,) int, index into PARTS or -1
    """
    rotated = (vertices - vertices.mean(axis=0)) @ _view_rotation(vertices).T
    triangles = rotated[faces]
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    norms = np.linalg.norm(normals, axis=1)
    normals = normals / np.where(norms > 0, norms, 1.0)[:, None]
    # Two-sided shading: authored meshes are often open or wound either way.
    light = np.abs(normals @ np.array([0.3, 0.4, -0.866]))
    colours = np.where((face_parts >= 0)[:, None], PART_COLOURS[np.clip(face_parts, 0, len(PARTS) - 1)], UNKNOWN_COLOUR)
    colours = colours * (0.35 + 0.65 * light)[:, None]
    # Painter's algorithm: farthest faces (largest depth) first.
    order = np.argsort(-triangles[:, :, 2].mean(axis=1), kind="stable")
    collection = PolyCollection(
        triangles[order, :, :2], facecolors=colours[order], edgecolors="none", antialiased=False
    )
    axes.add_collection(collection)
    low, high = rotated[:, :2].min(axis=0), rotated[:, :2].max(axis=0)
    pad = 0.05 * float((high - low).max())
    axes.set_xlim(low[0] - pad, high[0] + pad)
    axes.set_ylim(low[1] - pad, high[1] + pad)
    axes.set_aspect("equal")
    axes.set_xticks([])
    axes.set_yticks([])


def _legend_handles(parts: set[int]) -> list[Patch]:
    handles = [Patch(color=PART_COLOURS[index], label=PARTS[index]) for index in sorted(p for p in parts if p >= 0)]
    if -1 in parts:
        handles.append(Patch(color=UNKNOWN_COLOUR, label="unknown"))
    return handles


def show_model(store: ShardStore, model_id: str, out: str | Path) -> str:
    """Write a PNG of one model coloured by part, with a legend.

    Raises
    ------
    KeyError
        If no verified shard of the data dir holds ``model_id``.
    """
    row = _find_model(store, model_id)
    vertices, faces = mesh_from_arrow(row["vertices"], row["faces"])
    face_parts = np.asarray(row["face_parts"], dtype=np.int64)
    figure, axes = plt.subplots(figsize=(8, 5), dpi=120)
    draw_mesh(axes, vertices, faces, face_parts)
    axes.set_title(
        f"{row['name']} ({row['category']}, {row['source']})  {row['length'] * 100:.1f} cm, "
        f"{row['mass'] * 1000:.0f} g, {len(faces)} faces, {len(row['convex_parts'])} convex parts",
        fontsize=9,
    )
    axes.legend(handles=_legend_handles(set(face_parts.tolist())), loc="lower right", fontsize=8)
    figure.tight_layout()
    figure.savefig(out)
    plt.close(figure)
    return f"wrote {out}"


def show_models(store: ShardStore, out: str | Path) -> str:
    """Write a contact sheet of every model in the data dir (sorted by category, then name).

    Raises
    ------
    FileNotFoundError
        If the data dir holds no model.
    """
    columns = ["model_id", "name", "category", "source", "length", "vertices", "faces", "face_parts"]
    rows = [row for table in _model_tables(store, columns) for row in table.to_pylist()]
    if not rows:
        raise FileNotFoundError(f"no models in {store.root / 'models'}; run `osgd annotate` first")
    rows.sort(key=lambda row: (row["category"], row["source"], row["name"]))
    count = len(rows)
    columns_count = min(10, count)
    rows_count = math.ceil(count / columns_count)
    figure, grid = plt.subplots(
        rows_count, columns_count, figsize=(2.0 * columns_count, 1.3 * rows_count + 0.6), dpi=80, squeeze=False
    )
    seen_parts: set[int] = set()
    for axes, row in zip(grid.flat, rows, strict=False):
        vertices, faces = mesh_from_arrow(row["vertices"], row["faces"])
        face_parts = np.asarray(row["face_parts"], dtype=np.int64)
        seen_parts |= set(np.unique(face_parts).tolist())
        draw_mesh(axes, vertices, faces, face_parts)
        axes.set_title(f"{row['name']}\n{row['length'] * 100:.1f} cm", fontsize=6)
    for axes in grid.flat[count:]:
        axes.axis("off")
    figure.legend(handles=_legend_handles(seen_parts), loc="upper center", ncol=11, fontsize=8)
    figure.tight_layout(rect=(0, 0, 1, 1 - 0.5 / (1.3 * rows_count + 0.6)))
    figure.savefig(out)
    plt.close(figure)
    return f"wrote {out}: {count} models"
