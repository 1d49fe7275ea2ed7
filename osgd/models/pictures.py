"""Pictures of models for people: one model coloured by part, and a contact sheet.

The meshes are drawn by a small painter's-algorithm projection (faces
sorted far to near, shaded by the angle to a light) into matplotlib 2-D
polygons: much faster than matplotlib's 3-D axes for meshes of 50k faces,
which matters for a sheet of 175 models. Each model is seen along its
smallest principal axis, turned a little so that thickness shows.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import trimesh
from matplotlib.collections import PolyCollection
from matplotlib.patches import Patch

from osgd.contract.schemas import mesh_from_arrow
from osgd.contract.taxonomy import PARTS, TAB20, TABLE1, Taxonomy
from osgd.models.parts import PrincipalFrame, parts_method, principal_frame
from osgd.models.rows import find_model, model_tables
from osgd.store import ShardStore

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


def _view_rotation(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Rows: screen x (the mesh's length), screen y (its width), depth (its thickness); turned 30 degrees about x.

    The axes are :func:`osgd.models.parts.principal_frame`'s.
    """
    axes = principal_frame(trimesh.Trimesh(vertices, faces, process=False)).axes
    angle = math.radians(30.0)
    tilt = np.array([[1, 0, 0], [0, math.cos(angle), -math.sin(angle)], [0, math.sin(angle), math.cos(angle)]])
    return tilt @ axes


@dataclass(frozen=True)
class View:
    """How :func:`draw_mesh` projected a mesh, to draw more in the same picture.

    Attributes
    ----------
    rotation : (3, 3) float
        Rows: screen x, screen y, depth, in the mesh frame.
    centre : (3,) float
        The mesh point at the screen origin, m.
    """

    rotation: np.ndarray
    centre: np.ndarray

    def project(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) mesh-frame points to (N, 2) screen points."""
        return ((np.asarray(points, dtype=np.float64) - self.centre) @ self.rotation.T)[:, :2]


def part_colour(index: int) -> np.ndarray:
    """The colour of a part (its index in the taxonomy's parts): Table I's own, then the light shades of tab20 in turn
    for the parts of a pipeline's own taxonomy."""
    if index < len(PARTS):
        return PART_COLOURS[index]
    return np.array(TAB20[(2 * (index - len(PARTS)) + 1) % len(TAB20)])


def draw_mesh(axes: plt.Axes, vertices: np.ndarray, faces: np.ndarray, face_parts: np.ndarray) -> View:
    """Draw a mesh into 2-D axes, coloured by part and shaded.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int
    face_parts : (F,) int, index into PARTS or -1

    Returns
    -------
    View
        The projection used.
    """
    view = View(_view_rotation(vertices, faces), vertices.mean(axis=0))
    rotated = (vertices - view.centre) @ view.rotation.T
    triangles = rotated[faces]
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    norms = np.linalg.norm(normals, axis=1)
    normals = normals / np.where(norms > 0, norms, 1.0)[:, None]
    # Two-sided shading: authored meshes are often open or wound either way.
    light = np.abs(normals @ np.array([0.3, 0.4, -0.866]))
    palette = np.array([part_colour(index) for index in range(max(int(face_parts.max(initial=0)) + 1, len(PARTS)))])
    colours = np.where((face_parts >= 0)[:, None], palette[np.clip(face_parts, 0, None)], UNKNOWN_COLOUR)
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
    return view


def legend_handles(parts: set[int], names: tuple[str, ...] = PARTS) -> list[Patch]:
    """Legend entries for the parts seen (indices into ``names``, a taxonomy's parts; -1 unknown), in that order;
    a part that ``names`` does not have is ``part N``."""
    handles = [Patch(color=part_colour(index), label=names[index] if index < len(names) else f"part {index}")
               for index in sorted(p for p in parts if p >= 0)]
    if -1 in parts:
        handles.append(Patch(color=UNKNOWN_COLOUR, label="unknown"))
    return handles


def _working_direction(
    vertices: np.ndarray, faces: np.ndarray, face_parts: np.ndarray, category: str, taxonomy: Taxonomy
) -> tuple[PrincipalFrame, float | None]:
    """The mesh's principal frame turned so that *t* points to the working end, and the category's split.

    The direction is the label rules' own (:func:`osgd.grasps.labels.tool_axis`
    with the category's default rule in ``taxonomy``); the split is None when the mesh has
    no axis to tell (no handle or no working part).
    """
    from osgd.grasps.labels import default_rules, tool_axis  # noqa: PLC0415 (grasps come after models)

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    frame = principal_frame(mesh)
    rule = default_rules(taxonomy).get(category)
    axis = tool_axis(mesh, face_parts, rule) if rule is not None else None
    if axis is None:
        return frame, None
    return (frame if frame.axes[0] @ axis.direction >= 0 else frame.flipped()), rule.split


def draw_axis(axes: plt.Axes, view: View, frame: PrincipalFrame, split: float | None) -> None:
    """The principal axis through the mesh, its length long; an arrow to the working end and the split when known.

    Parameters
    ----------
    view : View
        What :func:`draw_mesh` returned for the mesh.
    frame : PrincipalFrame
        Its *t* axis pointing to the working end.
    split : float or None
        Where the label rules' category task gives way to hand over, as a
        share of the length from the handle end (:class:`osgd.grasps.labels.LabelRule`);
        None when the ends are not known.
    """
    half = frame.length / 2 * frame.axes[0]
    ends = view.project(np.array([frame.centre - half, frame.centre + half]))
    known = split is not None
    style = "-|>" if known else "-"
    axes.annotate("", xy=ends[1], xytext=ends[0],
                  arrowprops={"arrowstyle": style, "color": "black", "linewidth": 1.2, "linestyle": "--"})
    if not known:
        return
    axes.annotate("handle end", ends[0], textcoords="offset points", xytext=(0, -14), ha="center", fontsize=8)
    axes.annotate("working end", ends[1], textcoords="offset points", xytext=(0, 8), ha="center", fontsize=8)
    if split < 1.0:
        along = ends[1] - ends[0]
        across = np.array([-along[1], along[0]]) * 0.05
        mark = ends[0] + split * along
        axes.plot(*np.array([mark - across, mark + across]).T, color="black", linewidth=1.5)
        for side, text in ((-0.08, "task"), (0.08, "hand over")):
            axes.annotate(text, mark + side * along - across, textcoords="offset points", xytext=(0, -10),
                          ha="center", fontsize=8)


def show_model(store: ShardStore, model_id: str, out: str | Path, taxonomy: Taxonomy = TABLE1) -> str:
    """Write a PNG of one model coloured by part, with its principal axis and a legend.

    The title says how the parts were found (procedural, sidecar,
    automatic with its confidence, none); the dashed principal axis runs
    from the handle end to the working end, so a wrong head shows at a glance,
    and a bar across it marks where the label rules' category task gives way
    to hand over (docs/grasps.md, ``split``). The legend names the parts of ``taxonomy`` (the pipeline's).

    Raises
    ------
    KeyError
        If no verified shard of the data dir holds ``model_id`` (a model id, or a name such as
        ``user/drill``).
    """
    row = find_model(store, model_id).to_pylist()[0]
    vertices, faces = mesh_from_arrow(row["vertices"], row["faces"])
    face_parts = np.asarray(row["face_parts"], dtype=np.int64)
    provenance = json.loads(row["provenance"])
    method, confidence = parts_method(row["source"], provenance)
    figure, axes = plt.subplots(figsize=(8, 5), dpi=120)
    view = draw_mesh(axes, vertices, faces, face_parts)
    draw_axis(axes, view, *_working_direction(vertices, faces, face_parts, row["category"], taxonomy))
    found = {
        "procedural": "the generator's parts",
        "sidecar": "parts from the sidecar's regions",
        "none": "no part labels" + (f" (automatic parts not found, confidence {confidence:.2f})"
                                    if row["source"] == "user" else ""),
    }.get(method, f"{method} parts, confidence {confidence:.2f}")
    axes.set_title(
        f"{row['name']} ({row['category']}, {row['source']})  {row['length'] * 100:.1f} cm, "
        f"{row['mass'] * 1000:.0f} g, {len(faces)} faces, {len(row['convex_parts'])} convex parts\n{found}",
        fontsize=9,
    )
    axes.legend(handles=legend_handles(set(face_parts.tolist()), taxonomy.parts), loc="lower right", fontsize=8)
    figure.tight_layout()
    figure.savefig(out)
    plt.close(figure)
    return f"wrote {out}"


def show_models(store: ShardStore, out: str | Path, taxonomy: Taxonomy = TABLE1) -> str:
    """Write a contact sheet of every model in the data dir (sorted by category, then name); the legend names the
    parts of ``taxonomy``.

    Raises
    ------
    FileNotFoundError
        If the data dir holds no model.
    """
    columns = ["model_id", "name", "category", "source", "length", "vertices", "faces", "face_parts"]
    rows = [row for _, table in model_tables(store, columns) for row in table.to_pylist()]
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
    figure.legend(handles=legend_handles(seen_parts, taxonomy.parts), loc="upper center", ncol=11, fontsize=8)
    figure.tight_layout(rect=(0, 0, 1, 1 - 0.5 / (1.3 * rows_count + 0.6)))
    figure.savefig(out)
    plt.close(figure)
    return f"wrote {out}: {count} models"
