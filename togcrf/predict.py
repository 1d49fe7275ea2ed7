"""Run a trained model on one depth image: detections, grasps, task choice, picture.

``togcrf predict CHECKPOINT INPUT`` reads a depth image (a 16-bit PNG in
millimetres, a ``.npy`` array in metres, or the id of a sample in ``--data``),
and writes JSON: per detected object its box, category, score and grasp
candidates (rectangle, stability, task distribution), best stability first.
``--image OUT.png`` draws the top-5 stable grasps of every object coloured by
their most likely task, as the paper's figure 7 does. ``--task NAME`` picks
the single grasp for a task as the paper's robot does (Section V-C): the
largest P(task | stable) over all detected objects; for "no task" and
"hand over", which nearly every object affords, the object category must be
named with ``--category``. Our addition: only candidates with P(stable) of
at least ``--min-stability`` (default 0.5) compete, so that an unstable
candidate with a confident task label is not chosen; if none reaches it,
all candidates compete.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any

import cv2
import numpy as np
import torch
import typer
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle

from osgd.contract.samples import iter_samples, sample_shards, samples_vocabulary
from osgd.contract.taxonomy import HAND_OVER, NO_TASK, VOCABULARY, task_palette
from togcrf.checkpoint import check_vocabulary, load_checkpoint
from togcrf.data import depth_to_tensor
from togcrf.engine import run_model
from togcrf.evaluate import write_json
from togcrf.geometry import rectangle_corners
from togcrf.metrics import Detections

log = logging.getLogger(__name__)

#: Tasks nearly every object affords: the paper names a category first (Section V-C).
TASKS_NEEDING_CATEGORY = (NO_TASK, HAND_OVER)

#: Grasps drawn per object, as in figure 7 (top-5 stable grasps).
DRAWN_GRASPS = 5


#: Smallest depth image side the detector takes, pixels (its coarsest feature map has a stride of 32).
MIN_DEPTH_SIDE = 32


def _checked_size(path: Path, depth: np.ndarray) -> np.ndarray:
    """``depth``, if both its sides are at least ``MIN_DEPTH_SIDE`` pixels."""
    if min(depth.shape) < MIN_DEPTH_SIDE:
        raise ValueError(f"{path}: a depth image of {depth.shape[1]} x {depth.shape[0]} px; expected at least "
                         f"{MIN_DEPTH_SIDE} x {MIN_DEPTH_SIDE}")
    return depth


def load_depth(source: str, data_dir: Path | None = None, pipeline: str | None = None
               ) -> tuple[np.ndarray, Any | None]:
    """A depth image in metres from a file or a sample id.

    Parameters
    ----------
    source : str
        A ``.png`` (16-bit, millimetres, 0 = no reading), a ``.npy`` (float,
        metres) or a sample id in ``data_dir``.
    data_dir : path, optional
        Needed for a sample id.
    pipeline : str, optional
        Restrict the sample lookup to this pipeline's manifest.

    Returns
    -------
    depth : (H, W) float32
        Metres, 0 = no reading.
    sample : ``osgd.contract.samples.Sample`` or None
        The sample, when ``source`` named one.

    Raises
    ------
    FileNotFoundError, ValueError, KeyError
        With the file or id and the problem.
    """
    path = Path(source)
    suffix = path.suffix.lower()
    if suffix == ".png":
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such depth image")
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None or image.dtype != np.uint16 or image.ndim != 2:
            found = "unreadable" if image is None else f"{image.dtype} with shape {image.shape}"
            raise ValueError(f"{path}: expected a single-channel 16-bit PNG of depth in millimetres, got {found}")
        return _checked_size(path, image.astype(np.float32) / 1000.0), None
    if suffix == ".npy":
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such depth array")
        try:
            depth = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as error:
            raise ValueError(f"{path}: not a numpy array of depth in metres ({error})") from error
        if depth.ndim != 2 or not np.issubdtype(depth.dtype, np.floating):
            raise ValueError(f"{path}: expected a 2-D float array of depth in metres, got {depth.dtype} "
                             f"with shape {depth.shape}")
        return _checked_size(path, np.nan_to_num(depth.astype(np.float32), nan=0.0)), None
    if data_dir is None:
        raise ValueError(f"{source!r} is neither a .png nor a .npy file; to name a sample id, give --data")

    for sample in iter_samples(data_dir, pipeline=pipeline):
        if sample.sample_id == source:
            return sample.depth, sample
    raise KeyError(f"{data_dir}: no sample with id {source!r}")


def predict_depth(model: torch.nn.Module, depth: np.ndarray, image_size: int | None, device: str = "cpu",
                  depth_reference: str = "table", views: int = 1) -> Detections:
    """Detections of a model on a depth image (metres), in the image's pixels.

    ``image_size`` and ``depth_reference`` are the training config's (:func:`togcrf.data.depth_to_tensor`);
    ``views`` > 1 averages the grasp candidates over test-time views (:mod:`togcrf.tta`).
    """

    image, scale = depth_to_tensor(depth, image_size, depth_reference)
    model.eval()
    return run_model(model, image.to(device), scale, views)


def keep_confident(detections: Detections, min_score: float) -> Detections:
    """Only the detections with a score of at least ``min_score``."""
    keep = np.asarray(detections.scores) >= min_score
    return Detections(detections.boxes[keep], detections.categories[keep], detections.scores[keep],
                      detections.grasps[keep], detections.grasp_stability[keep], detections.grasp_task_probs[keep])


def prediction_document(detections: Detections, grasps_per_object: int | None = None,
                        vocabulary: Mapping[str, Sequence[str]] = VOCABULARY) -> dict[str, Any]:
    """Detections as a JSON-ready document.

    Parameters
    ----------
    detections : Detections
    grasps_per_object : int, optional
        Keep only this many candidates per object (highest stability first).

    Returns
    -------
    dict
        ``tasks`` (the order of every ``task_probs``) and ``objects``: list of
        ``box`` [x1, y1, x2, y2] px, ``category``, ``score`` and ``grasps``:
        list of ``rectangle`` [x, y, h, w, theta] (px, rad), ``stability``,
        ``task`` (most likely) and ``task_probs`` (P(task | stable) for each task of the model's
        ``vocabulary``).
    """
    tasks, categories = vocabulary["tasks"], vocabulary["categories"]
    objects = []
    for index in range(len(detections.scores)):
        stability = detections.grasp_stability[index]
        order = np.argsort(-stability, kind="stable")[:grasps_per_object]
        grasps = [{
            "rectangle": [float(value) for value in detections.grasps[index, candidate]],
            "stability": float(stability[candidate]),
            "task": tasks[int(np.argmax(detections.grasp_task_probs[index, candidate]))],
            "task_probs": [float(value) for value in detections.grasp_task_probs[index, candidate]],
        } for candidate in order]
        objects.append({
            "box": [float(value) for value in detections.boxes[index]],
            "category": categories[int(detections.categories[index])],
            "score": float(detections.scores[index]),
            "grasps": grasps,
        })
    return {"tasks": list(tasks), "objects": objects}


def best_grasp_for_task(detections: Detections, task: str, category: str | None = None,
                        min_stability: float = 0.5, vocabulary: Mapping[str, Sequence[str]] = VOCABULARY,
                        ) -> dict[str, Any]:
    """The grasp for a task: the largest P(task | stable) over all detected objects.

    Parameters
    ----------
    detections : Detections
    task : str
        A task of the model's ``vocabulary``.
    category : str, optional
        Only objects of this category; required for "no task" and "hand over".
    min_stability : float
        Candidates less stable than this do not compete (unless none is stable).
    vocabulary : mapping
        The model's categories and tasks (default Table I's).

    Returns
    -------
    dict
        ``task``, ``object`` (row in the detections), ``category``,
        ``rectangle``, ``stability``, ``task_probability``.

    Raises
    ------
    ValueError
        For an unknown task or category, a missing category where one is
        required, or when no object (of the category) was detected.
    """
    tasks, categories = list(vocabulary["tasks"]), list(vocabulary["categories"])
    if task not in tasks:
        raise ValueError(f"unknown task {task!r}; expected one of {tasks}")
    if category is not None and category not in categories:
        raise ValueError(f"unknown category {category!r}; expected one of {categories}")
    if task in TASKS_NEEDING_CATEGORY and category is None:
        raise ValueError(f"task {task!r} needs --category: nearly every object affords it (paper, Section V-C)")
    objects = np.arange(len(detections.scores))
    if category is not None:
        objects = objects[detections.categories == categories.index(category)]
    candidates = [(obj, k) for obj in objects for k in range(detections.grasps.shape[1])]
    if not candidates:
        raise ValueError(f"no {'object' if category is None else category} with grasp candidates detected")
    task_index = tasks.index(task)
    probability = np.array([detections.grasp_task_probs[obj, k, task_index] for obj, k in candidates])
    stability = np.array([detections.grasp_stability[obj, k] for obj, k in candidates])
    stable = stability >= min_stability
    if stable.any():
        probability = np.where(stable, probability, -np.inf)
    obj, k = candidates[int(np.argmax(probability))]
    return {
        "task": task,
        "object": int(obj),
        "category": categories[int(detections.categories[obj])],
        "rectangle": [float(value) for value in detections.grasps[obj, k]],
        "stability": float(detections.grasp_stability[obj, k]),
        "task_probability": float(detections.grasp_task_probs[obj, k, task_index]),
    }


def task_colours(tasks: Sequence[str] = VOCABULARY["tasks"]) -> np.ndarray:
    """One RGB colour (floats in [0, 1]) per task, in the order of ``tasks``: (T, 3).

    The rows of ``taxonomy.task_palette``, the palette every picture colours tasks with.
    """
    palette = task_palette(tasks)
    return np.array([palette[task] for task in tasks], dtype=np.float64)


def draw_prediction(depth: np.ndarray, detections: Detections, path: Path, grasps_per_object: int = DRAWN_GRASPS,
                    chosen: dict[str, Any] | None = None, vocabulary: Mapping[str, Sequence[str]] = VOCABULARY,
                    ) -> None:
    """Draw detections like the paper's figure 7 and save a PNG.

    The depth image is the grey background; every box carries its category
    and score; the ``grasps_per_object`` most stable candidates of each box
    are drawn as rectangles in the colour of their most likely task, the
    finger sides thick. A ``chosen`` grasp (from :func:`best_grasp_for_task`)
    is drawn on top, larger and outlined. Names and colours are those of the model's ``vocabulary``.
    """
    tasks, categories = list(vocabulary["tasks"]), vocabulary["categories"]
    colours = task_colours(tasks)
    height, width = depth.shape
    figure = Figure(figsize=(8, 8 * height / width + 0.8), dpi=100)
    axes = figure.subplots()
    valid = depth > 0
    shown = np.where(valid, depth, np.nan)
    low, high = (np.percentile(depth[valid], [1, 99]) if valid.any() else (0.0, 1.0))
    span = max(high - low, 1e-3)
    # A widened range keeps the table mid-grey and objects light, so every task colour stands out.
    axes.imshow(shown, cmap="gray_r", vmin=low - 0.6 * span, vmax=high + 0.6 * span)
    axes.set_facecolor("black")
    used_tasks = set()

    def draw_rectangle(rectangle: np.ndarray, colour: np.ndarray, thin: float, thick: float) -> None:
        corners = rectangle_corners(rectangle)
        # Corners 0-1 and 2-3 are the finger sides (across the closing direction).
        for start, end, line_width in ((0, 1, thick), (1, 2, thin), (2, 3, thick), (3, 0, thin)):
            axes.plot(corners[[start, end], 0], corners[[start, end], 1], color=colour, linewidth=line_width)

    for index in range(len(detections.scores)):
        x1, y1, x2, y2 = detections.boxes[index]
        axes.add_patch(Rectangle((x1, y1), x2 - x1, y2 - y1, fill=False, edgecolor="yellow", linewidth=1.2))
        axes.text(x1, y1 - 2, f"{categories[int(detections.categories[index])]} {detections.scores[index]:.2f}",
                  color="black", fontsize=8, backgroundcolor="yellow")
        order = np.argsort(-detections.grasp_stability[index], kind="stable")[:grasps_per_object]
        for candidate in order[::-1]:
            task = int(np.argmax(detections.grasp_task_probs[index, candidate]))
            used_tasks.add(task)
            draw_rectangle(detections.grasps[index, candidate], colours[task], 1.2, 3.0)
    if chosen is not None:
        task = tasks.index(chosen["task"])
        used_tasks.add(task)
        draw_rectangle(np.asarray(chosen["rectangle"]), np.array([0.0, 0.0, 0.0]), 4.0, 7.0)
        draw_rectangle(np.asarray(chosen["rectangle"]), colours[task], 2.0, 4.0)
        axes.set_title(f"{chosen['task']}: {chosen['category']}, P(task | stable) = {chosen['task_probability']:.2f}, "
                       f"P(stable) = {chosen['stability']:.2f}", fontsize=9)
    else:
        count = len(detections.scores)
        # An empty picture must say that nothing was detected, not look like a failed drawing.
        axes.set_title(f"{count} object{'s' if count != 1 else ''} detected" if count else
                       "no object detected above the score threshold", fontsize=9)
    axes.set_xlim(0, width)
    axes.set_ylim(height, 0)
    axes.set_axis_off()
    handles = [Line2D([0], [0], color=colours[task], linewidth=3, label=tasks[task]) for task in sorted(used_tasks)]
    if handles:
        axes.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.01), ncol=min(6, len(handles)),
                    fontsize=8, frameon=True, facecolor="#444444", edgecolor="none", labelcolor="white")
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path)


def predict_command(
    checkpoint: Annotated[Path, typer.Argument(help="A checkpoint.pt written by `togcrf train`.")],
    source: Annotated[str, typer.Argument(metavar="INPUT",
                                          help="16-bit PNG (mm), .npy (m), or a sample id looked up in --data.")],
    *,
    data: Annotated[Path | None, typer.Option("--data", help="Data dir, to look up a sample id.")] = None,
    pipeline: Annotated[str | None, typer.Option(help="Look the sample id up in this pipeline only.")] = None,
    out: Annotated[Path | None, typer.Option(help="Write the JSON here instead of printing it.")] = None,
    image: Annotated[Path | None, typer.Option("--image", help="Draw the top-5 stable grasps per object.")] = None,
    task: Annotated[str | None, typer.Option(help="Pick the single best grasp for this task.")] = None,
    category: Annotated[str | None, typer.Option(help="Category for --task (required: no task, hand over).")] = None,
    min_score: Annotated[float, typer.Option(help="Keep detections with at least this score.")] = 0.5,
    min_stability: Annotated[float, typer.Option(help="For --task: candidates at least this stable compete.")] = 0.5,
    grasps_per_object: Annotated[int | None, typer.Option(help="Candidates per object in the JSON (all).")] = None,
    device: Annotated[str, typer.Option(help="torch device.")] = "cpu",
    views: Annotated[int, typer.Option(help="Test-time views: average the grasp candidates over 1 (off), 2, 4 "
                                            "or 8 flipped and turned copies of the image (togcrf.tta).")] = 1,
) -> None:
    """Detect objects and task-oriented grasps on one depth image; JSON out, optional picture."""

    depth, sample = load_depth(source, data, pipeline)
    if not Path(checkpoint).is_file():
        raise FileNotFoundError(f"{checkpoint}: no such checkpoint")
    model, config = load_checkpoint(checkpoint, device=device)
    if sample is not None:
        check_vocabulary(config["vocabulary"], samples_vocabulary(sample_shards(data, pipeline)),
                         str(checkpoint), f"{data}/samples")
    detections = keep_confident(predict_depth(model, depth, config.get("image_size"), device,
                                                 config["depth_reference"], views), min_score)
    vocabulary = config["vocabulary"]
    chosen = None if task is None else best_grasp_for_task(detections, task, category, min_stability, vocabulary)
    document = {"input": source, "model": config.get("model"), "checkpoint": str(checkpoint),
                "height": int(depth.shape[0]), "width": int(depth.shape[1]), "min_score": min_score,
                "test_time_views": views,
                **prediction_document(detections, grasps_per_object, vocabulary)}
    if sample is not None:
        document["sample_id"] = sample.sample_id
    if chosen is not None:
        document["chosen"] = chosen
    if image is not None:
        draw_prediction(depth, detections, image, chosen=chosen, vocabulary=vocabulary)
    if out is not None:
        write_json(out, document)
        typer.echo(f"{len(document['objects'])} objects; written to {out}" + (f" and {image}" if image else ""))
    else:
        typer.echo(json.dumps(document, indent=2))


def register(app: typer.Typer) -> None:
    """Add ``predict`` to the ``togcrf`` command line."""
    app.command("predict")(predict_command)
