"""Pictures of samples: depth in a colour map, object boxes, grasp rectangles.

Like the paper's figures 2 and 7: each object's box labelled with its
category, each grasp rectangle coloured by its task (``taxonomy.TASK_COLOURS``, legend on the side);
the rectangle's finger-plate edges (across the closing direction) are drawn
thick, the edges along the closing direction thin.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow.compute as pc

from osgd.contract.samples import Sample, decode_row, metadata_vocabulary
from osgd.contract.taxonomy import TASK_COLOURS, TASKS, task_palette
from osgd.samples.projection import rectangle_corners
from osgd.store import ShardStore


def find_sample(store: ShardStore, sample_id: str) -> tuple[Sample, dict[str, list[str]]]:
    """The sample called ``sample_id`` in any verified ``samples`` shard, and the vocabulary of its shard.

    Raises
    ------
    KeyError
        If no shard holds it.
    """
    keys = store.keys_on_disk("samples")
    for key in keys:
        if not store.is_done("samples", key):
            continue
        ids = store.read("samples", key, columns=["sample_id"])["sample_id"]
        matches = pc.equal(ids, sample_id)
        if pc.any(matches).as_py():
            table = store.read("samples", key)
            vocabulary = metadata_vocabulary(table.schema.metadata, f"samples shard {key}")
            return decode_row(table.filter(matches).to_pylist()[0], vocabulary), vocabulary
    raise KeyError(f"no sample {sample_id!r} in {store.root / 'samples'} ({len(keys)} shards searched)")


def view_window(sample: Sample, grow: float = 1.3, margin: int = 16, minimum: int = 160) -> tuple[int, int, int, int]:
    """The part of the image worth showing: the union of the boxes, grown.

    Like the original OSGD crops (REFERENCE section 2): the union of the
    object boxes grown by ``grow`` about its centre plus ``margin`` pixels,
    at least ``minimum`` pixels across, clipped to the image.

    Returns
    -------
    left, top, right, bottom : int
        Inclusive pixel bounds; the whole image when there is no box.
    """
    height, width = sample.depth.shape
    if not len(sample.boxes):
        return 0, 0, width - 1, height - 1
    low = sample.boxes[:, :2].min(axis=0)
    high = sample.boxes[:, 2:].max(axis=0)
    centre = (low + high) / 2
    half = np.maximum((high - low) * grow / 2 + margin, minimum / 2)
    left, top = np.maximum(np.floor(centre - half), 0).astype(int)
    right, bottom = np.minimum(np.ceil(centre + half), [width - 1, height - 1]).astype(int)
    return int(left), int(top), int(right), int(bottom)


def draw_sample(sample: Sample, axes, noisy: bool = True, crop: bool = True, tasks: Sequence[str] = TASKS) -> None:
    """Draw a sample onto matplotlib axes (depth, boxes, rectangles, legend).

    ``crop`` shows only :func:`view_window`; the colour map then spans the
    depths seen there. ``tasks`` are the names ``sample.grasp_tasks`` index: the
    vocabulary of the sample's shard (Table I's by default).
    """
    from matplotlib.lines import Line2D  # noqa: PLC0415
    from matplotlib.patches import Rectangle  # noqa: PLC0415

    depth = sample.depth if noisy else sample.depth_clean
    shown = np.where(depth > 0, depth, np.nan)
    left, top, right, bottom = view_window(sample) if crop else (0, 0, depth.shape[1] - 1, depth.shape[0] - 1)
    window = shown[top : bottom + 1, left : right + 1]
    finite = window[np.isfinite(window)]
    low, high = (np.percentile(finite, [0.5, 99.5]) if finite.size else (0.0, 1.0))
    image = axes.imshow(shown, cmap="viridis_r", vmin=low, vmax=high, interpolation="nearest")
    axes.figure.colorbar(image, ax=axes, fraction=0.035, pad=0.01, label="depth (m)")
    for category, box in zip(sample.categories, sample.boxes, strict=True):
        x1, y1, x2, y2 = (float(value) for value in box)
        axes.add_patch(Rectangle((x1 - 0.5, y1 - 0.5), x2 - x1 + 1, y2 - y1 + 1, fill=False, edgecolor="white",
                                 linewidth=1.2))
        axes.text(x1, y1 - 3, category, color="black", fontsize=7,
                  bbox={"facecolor": "white", "alpha": 0.8, "pad": 1, "edgecolor": "none"})
    colours = TASK_COLOURS if tuple(tasks) == TASKS else task_palette(tasks)
    names = [tasks[index] for index in sample.grasp_tasks]
    for corners, task in zip(rectangle_corners(sample.grasp_rectangles), names, strict=True):
        colour = colours[task]
        closed = np.vstack([corners, corners[:1]])
        axes.plot(closed[:, 0], closed[:, 1], color=colour, linewidth=0.8)
        for start, end in ((0, 1), (2, 3)):  # the finger plates
            axes.plot(corners[[start, end], 0], corners[[start, end], 1], color=colour, linewidth=2.2)
    present = [task for task in tasks if task in set(names)]
    handles = [Line2D([], [], color=colours[task], linewidth=2.2, label=task) for task in present]
    if handles:
        axes.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.18, 1.0), fontsize=8, title="task",
                    title_fontsize=8, frameon=False)
    axes.set_title(f"{sample.sample_id} ({sample.split}): {len(sample.boxes)} objects, "
                   f"{len(sample.grasp_rectangles)} grasps", fontsize=9)
    axes.set_xlim(left - 0.5, right + 0.5)
    axes.set_ylim(bottom + 0.5, top - 0.5)
    axes.set_xticks([])
    axes.set_yticks([])


def show_sample(store: ShardStore, sample_id: str, out: str | Path, crop: bool = True) -> str:
    """Write a picture of one sample (noisy depth, boxes, grasp rectangles) as PNG.

    Parameters
    ----------
    store : ShardStore
    sample_id : str
        E.g. ``scene_000042_view0``.
    out : path
        PNG file to write.
    crop : bool
        Show only the objects' surroundings (:func:`view_window`).

    Returns
    -------
    str
        What was written.

    Raises
    ------
    KeyError
        If there is no such sample.
    """
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    sample, vocabulary = find_sample(store, sample_id)
    figure, axes = plt.subplots(figsize=(9.0, 6.5), dpi=120)
    try:
        draw_sample(sample, axes, crop=crop, tasks=vocabulary["tasks"])
        figure.tight_layout()
        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        figure.savefig(out)
    finally:
        plt.close(figure)
    return f"wrote {out}: {len(sample.boxes)} objects, {len(sample.grasp_rectangles)} grasps"
