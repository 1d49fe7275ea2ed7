"""``osgd show grasps MODEL --out FILE.png``: a model with its grasps.

The mesh is drawn flat, faces tinted by part, in two views along its
principal axes: looking down the thinnest axis and looking down the middle
one. Each grasp is a gripper outline (the two fingers at the opening, the
palm bar and a short stem pointing back along the approach), coloured by
task label (``taxonomy.task_palette`` of the pipeline's tasks) or by the check stage's verdict. The
first column shows every grasp, the others one task label each, so a person
can see at a glance that, say, every "hammer" grasp sits on the handle and
every "hand over" grasp on the head.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from osgd.contract.schemas import mesh_from_arrow, vectors_from_arrow
from osgd.contract.taxonomy import PARTS, TABLE1, Taxonomy, task_palette
from osgd.gripper import PANDA, Gripper
from osgd.models.rows import find_model
from osgd.store import ShardStore

#: Face tints of the parts of a pipeline's own taxonomy (after Table I's), in turn.
EXTRA_PART_COLORS: tuple[str, ...] = ("#e5d8bd", "#b3e2cd", "#fddaec", "#cbd5e8", "#f1e2cc", "#e6f5c9")


def _part_colour(part: int) -> str:
    """A part's face tint; a part of a pipeline's own taxonomy (after Table I's) takes one of the extra tints."""
    return PART_COLORS[part] if part in PART_COLORS else EXTRA_PART_COLORS[(part - len(PARTS)) % len(EXTRA_PART_COLORS)]


def _part_name(part: int, names: tuple[str, ...]) -> str:
    """The name of a part in ``names`` (a taxonomy's parts); ``part N`` for one it has not."""
    return "unknown part" if part < 0 else names[part] if part < len(names) else f"part {part}"


#: A matplotlib colour: a name or hex string, or (r, g, b) floats in [0, 1].
Colour = str | tuple[float, float, float]

#: Face tint per part (light, so the grasps stand out); unknown parts grey.
PART_COLORS: dict[int, str] = {
    -1: "#d9d9d9",
    **dict(
        zip(
            range(len(PARTS)),
            ("#c6dbef", "#fdd0a2", "#fcbba1", "#fee391", "#d9f0a3", "#c7e9c0", "#fcc5c0",
             "#dadaeb", "#f2f0f7", "#ccebc5"),
            strict=True,
        )
    ),
}

STABILITY_COLORS = {"stable": "#1a9850", "unstable": "#d73027", "not checked": "#9e9e9e"}


def _model_grasps(store: ShardStore, model_id: str) -> pa.Table:
    tables = []
    for key in store.keys_on_disk("grasps"):
        grasps = store.read("grasps", key)
        tables.append(grasps.filter(pc.equal(grasps.column("model_id"), model_id)))
    if not tables:
        raise FileNotFoundError(f"no grasps table in {store.root}: run `osgd annotate` first")
    return pa.concat_tables(tables)


def _stability(store: ShardStore, model_id: str, grasp_ids: np.ndarray) -> list[str]:
    """"stable", "unstable" or "not checked" per grasp, from ``<root>/checks``."""
    keys = store.keys_on_disk("checks")
    if not keys:
        raise FileNotFoundError(
            f"no checks table in {store.root / 'checks'}: run `osgd check` first, or colour by task (--color-by task)"
        )
    verdict: dict[int, bool] = {}
    for key in keys:
        checks = store.read("checks", key, columns=["model_id", "grasp_id", "stable"])
        checks = checks.filter(pc.equal(checks.column("model_id"), model_id))
        verdict.update(zip(checks.column("grasp_id").to_pylist(), checks.column("stable").to_pylist(), strict=True))
    return [
        "not checked" if int(grasp) not in verdict else ("stable" if verdict[int(grasp)] else "unstable")
        for grasp in grasp_ids
    ]


def gripper_outline(gripper: Gripper, width: float) -> np.ndarray:
    """Line segments of a gripper outline in the gripper frame.

    Returns
    -------
    (4, 2, 3) float64
        Finger A, palm bar, finger B and stem, each from one end to the other.
    """
    half, tip, base = width / 2, gripper.finger_depth / 2, -gripper.finger_depth / 2
    return np.array(
        [
            [[-half, 0, tip], [-half, 0, base]],
            [[-half, 0, base], [half, 0, base]],
            [[half, 0, base], [half, 0, tip]],
            [[0, 0, base], [0, 0, base - gripper.palm_thickness]],
        ]
    )


def _quaternions_to_matrices(quaternions: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation  # noqa: PLC0415

    return Rotation.from_quat(quaternions).as_matrix()


def _grasp_segments(grasps: pa.Table, gripper: Gripper) -> tuple[np.ndarray, np.ndarray]:
    """Gripper outlines and contact points of every grasp, object frame.

    Returns
    -------
    segments : (G, 4, 2, 3) float64
        The :func:`gripper_outline` of each grasp at its pose and width.
    contacts : (G, 2, 3) float64
        Contact points a and b.
    """
    if not grasps.num_rows:
        return np.zeros((0, 4, 2, 3)), np.zeros((0, 2, 3))
    positions = vectors_from_arrow(grasps.column("position"))
    rotations = _quaternions_to_matrices(vectors_from_arrow(grasps.column("quaternion"), 4))
    widths = grasps.column("width").to_numpy()
    outlines = np.stack([gripper_outline(gripper, width) for width in widths])  # (G, 4, 2, 3)
    segments = positions[:, None, None, :] + np.einsum("gij,gsej->gsei", rotations, outlines)
    contacts = np.stack(
        [vectors_from_arrow(grasps.column("contact_a")), vectors_from_arrow(grasps.column("contact_b"))], axis=1
    )
    return segments, contacts


def _principal_views(vertices: np.ndarray) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """The two views of a mesh: looking down its thinnest and its middle principal axis.

    Parameters
    ----------
    vertices : (V, 3) float64

    Returns
    -------
    list of (name, projection (2, 3), depth axis (3,))
        The projection's rows span the image plane; the depth axis points along the view.
    """
    # Principal axes, longest first: views look down the thinnest and the middle axis.
    centred = vertices - vertices.mean(axis=0)
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    return [("looking down the thinnest axis", axes[[0, 1]], axes[2]),
            ("looking down the middle axis", axes[[0, 2]], axes[1])]


def _draw_view(
    panels: np.ndarray,
    row: int,
    view: tuple[str, np.ndarray, np.ndarray],
    mesh: tuple[np.ndarray, np.ndarray, np.ndarray],
    columns: list[tuple[str, np.ndarray]],
    grasp_lines: tuple[np.ndarray, np.ndarray, list[str], Mapping[str, Colour]],
) -> None:
    """Draw one row of panels: the mesh in one view with the grasps of each column.

    Parameters
    ----------
    panels : (rows, columns) array of matplotlib axes
    row : int
        The row to draw into; the first one carries the column titles.
    view : (name, projection (2, 3), depth axis (3,))
        From :func:`_principal_views`.
    mesh : (vertices (V, 3), faces (F, 3), face parts (F,))
    columns : list of (title, selected (G,) bool)
        The grasps each column shows.
    grasp_lines : (segments (G, 4, 2, 3), contacts (G, 2, 3), labels (G,), colours by label)
    """
    from matplotlib.collections import LineCollection, PolyCollection  # noqa: PLC0415

    view_name, projection, depth_axis = view
    vertices, faces, face_parts = mesh
    segments, contacts, labels, colors = grasp_lines
    # Painter's order: far faces first.
    order = np.argsort(vertices[faces].mean(axis=1) @ depth_axis)
    polygons = (vertices[faces[order]] - vertices.mean(axis=0)) @ projection.T
    face_colors = [_part_colour(int(part)) for part in face_parts[order]]
    for column, (title, selected) in enumerate(columns):
        axis = panels[row, column]
        axis.add_collection(PolyCollection(polygons, facecolors=face_colors, edgecolors="none"))
        chosen = np.flatnonzero(selected)
        lines = (segments[chosen] - vertices.mean(axis=0)) @ projection.T  # (G, 4, 2, 2)
        line_colors = np.repeat([colors[labels[index]] for index in chosen], 4, axis=0) if len(chosen) else []
        axis.add_collection(
            LineCollection(lines.reshape(-1, 2, 2), colors=line_colors, linewidths=0.9, alpha=0.75)
        )
        points = (contacts[chosen] - vertices.mean(axis=0)) @ projection.T
        axis.scatter(points[..., 0].ravel(), points[..., 1].ravel(), s=3, c="#333333", zorder=3)
        axis.set_aspect("equal")
        axis.autoscale_view()
        axis.margins(0.08)
        axis.set_xticks([])
        axis.set_yticks([])
        axis.set_title(f"{title} ({len(chosen)})" if row == 0 else view_name, fontsize=9)


def _add_legend(
    figure, labels: list[str], colors: Mapping[str, Colour], face_parts: np.ndarray, part_names: tuple[str, ...]
) -> None:
    """The figure's legend: the colour of each label drawn, then the tint of each part.

    Parameters
    ----------
    figure : matplotlib Figure
    labels : list of str
        The label of each grasp, (G,).
    colors : dict
        Colour by label.
    face_parts : (F,) int64
        Part index per face, -1 unknown.
    """
    from matplotlib.lines import Line2D  # noqa: PLC0415
    from matplotlib.patches import Patch  # noqa: PLC0415

    shown = [label for label in colors if label in labels]
    handles = [Line2D([], [], color=colors[label], label=label) for label in shown]
    part_handles = [
        Patch(color=_part_colour(int(part)), label=_part_name(int(part), part_names)) for part in np.unique(face_parts)
    ]
    figure.legend(handles=handles + part_handles, loc="lower center", ncol=min(len(handles) + len(part_handles), 8),
                  fontsize=8, frameon=False)


def show_grasps(
    store: ShardStore,
    model_id: str,
    out: str | Path,
    color_by: str = "task",
    gripper: Gripper = PANDA,
    taxonomy: Taxonomy = TABLE1,
) -> str:
    """Draw a model with its grasps as gripper outlines and write a PNG.

    Parameters
    ----------
    store : ShardStore
    model_id : str
        The model's id or name.
    out : path
        PNG file to write.
    color_by : {"task", "stability"}
        Colour by task label, or by the ``checks`` table's ``stable`` column.
    gripper : Gripper
    taxonomy : Taxonomy
        The pipeline's: the names of its parts, and its tasks' colours.

    Returns
    -------
    str
        A one-line description of what was drawn.

    Raises
    ------
    KeyError
        No such model.
    FileNotFoundError
        No grasps table, or no checks table when colouring by stability.
    ValueError
        Unknown ``color_by``.
    """
    if color_by not in ("task", "stability"):
        raise ValueError(f"color_by must be 'task' or 'stability', not {color_by!r}")
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    model = find_model(store, model_id)
    identity = model.column("model_id")[0].as_py()
    name = model.column("name")[0].as_py()
    category = model.column("category")[0].as_py()
    vertices, faces = mesh_from_arrow(model.column("vertices")[0], model.column("faces")[0])
    face_parts = np.asarray(model.column("face_parts")[0].as_py(), dtype=np.int64)
    grasps = _model_grasps(store, identity)

    tasks = grasps.column("task").to_pylist()
    vocabulary = [*taxonomy.tasks, *sorted(set(tasks) - set(taxonomy.tasks))]  # with any the taxonomy has not
    if color_by == "task":
        labels, colors = tasks, task_palette(vocabulary)
    else:
        labels, colors = _stability(store, identity, grasps.column("grasp_id").to_numpy()), STABILITY_COLORS
    segments, contacts = _grasp_segments(grasps, gripper)
    views = _principal_views(vertices)

    task_groups = [task for task in vocabulary if task in tasks]
    columns = [("all grasps", np.ones(len(tasks), dtype=bool))]
    columns += [(f'"{task}"', np.array([value == task for value in tasks])) for task in task_groups]
    figure, panels = plt.subplots(
        len(views), len(columns), figsize=(4.2 * len(columns), 3.6 * len(views)), squeeze=False
    )
    for row, view in enumerate(views):
        _draw_view(panels, row, view, (vertices, faces, face_parts), columns, (segments, contacts, labels, colors))
    _add_legend(figure, labels, colors, face_parts, taxonomy.parts)
    figure.suptitle(f"{name} ({category}, {identity}): {grasps.num_rows} grasps coloured by {color_by}", fontsize=10)
    figure.tight_layout(rect=(0, 0.06, 1, 0.95))
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=110)
    plt.close(figure)
    return f"wrote {out}: {name}, {grasps.num_rows} grasps coloured by {color_by}"
