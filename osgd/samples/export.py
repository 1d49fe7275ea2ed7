"""Write samples in formats peers' tools read: osgd, cornell, coco, hf.

``hf`` (a Hugging Face dataset folder, :mod:`osgd.export.hf`) writes Parquet
files per split and a dataset card; what follows is about the other three.

Every format writes each sample's noisy depth as a 16-bit PNG of
millimetres (0 = no reading), beside its annotations, under
``<out_dir>/<split>/``.

``osgd`` (the original OSGD text format, REFERENCE section 2)
    ``<sample_id>.txt``: one grasp per line,
    ``x0 y0 x1 y1 x2 y2 x3 y3 obj_idx task_name``, where ``p0 -> p1`` is a
    finger plate edge (length ``w``) and ``p1 -> p2`` runs along the closing
    direction (length ``h``); ``obj_idx`` is the line of the object in
    ``<sample_id>_objects.txt`` (0-based), whose lines are
    ``x1 y1 x2 y2 category``; task names use the annotation file stems
    (``hand_over``, ``no_task``) so a line splits on whitespace.
``cornell`` (the Cornell grasping data set's rectangle files)
    ``<sample_id>cpos.txt``: each grasp as four lines ``x y``, its corners in
    the order above (Cornell's first edge is the gripper plate too); every
    stored grasp is positive, so there is no ``cneg`` file. The depth image is
    ``<sample_id>d.png``.
``coco`` (COCO object detection JSON)
    ``<split>.json`` with ``images`` (file name, size), ``categories`` (those of
    the samples' vocabulary, id = their index + 1: Table I's
    ``taxonomy.CATEGORY_INDEX + 1``) and ``annotations``: ``bbox = [x, y,
    width, height]`` where ``x, y`` are the box's first column and row and
    ``width = x2 - x1 + 1`` pixels (the box covers whole pixels), plus the
    object's ``visible_fraction`` and its grasps as ``grasps``:
    ``[x, y, h, w, theta, task]``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from osgd.contract.encoding import encode_depth
from osgd.contract.samples import Sample, iter_samples, sample_shards, samples_vocabulary
from osgd.contract.taxonomy import task_file_stem
from osgd.samples.projection import rectangle_corners
from osgd.store import ShardStore

#: Formats :func:`export` writes.
FORMATS: tuple[str, ...] = ("osgd", "cornell", "coco", "hf")


def _write_depth(sample: Sample, path: Path) -> None:
    path.write_bytes(encode_depth(sample.depth))


def _osgd_files(sample: Sample, folder: Path, tasks: Sequence[str]) -> None:
    _write_depth(sample, folder / f"{sample.sample_id}_depth.png")
    object_lines = [
        f"{box[0]:.1f} {box[1]:.1f} {box[2]:.1f} {box[3]:.1f} {category}"
        for box, category in zip(sample.boxes, sample.categories, strict=True)
    ]
    (folder / f"{sample.sample_id}_objects.txt").write_text("".join(line + "\n" for line in object_lines))
    grasp_lines = []
    for corners, owner, task in zip(
        rectangle_corners(sample.grasp_rectangles), sample.grasp_objects, sample.grasp_tasks, strict=True
    ):
        points = " ".join(f"{value:.3f}" for value in corners.reshape(-1))
        grasp_lines.append(f"{points} {int(owner)} {task_file_stem(tasks[task])}")
    (folder / f"{sample.sample_id}.txt").write_text("".join(line + "\n" for line in grasp_lines))


def _cornell_files(sample: Sample, folder: Path) -> None:
    _write_depth(sample, folder / f"{sample.sample_id}d.png")
    lines = [f"{x:.3f} {y:.3f}" for corners in rectangle_corners(sample.grasp_rectangles) for x, y in corners]
    (folder / f"{sample.sample_id}cpos.txt").write_text("".join(line + "\n" for line in lines))


def _coco_entries(sample: Sample, image_id: int, first_annotation: int, file_name: str,
                  vocabulary: Mapping[str, Sequence[str]]) -> tuple[dict, list[dict]]:
    image = {"id": image_id, "file_name": file_name, "width": int(sample.depth.shape[1]),
             "height": int(sample.depth.shape[0]), "sample_id": sample.sample_id, "scene_id": sample.scene_id}
    annotations = []
    for row, (box, category) in enumerate(zip(sample.boxes, sample.categories, strict=True)):
        x1, y1, x2, y2 = (float(value) for value in box)
        width, height = x2 - x1 + 1, y2 - y1 + 1
        grasps = [
            [*(round(float(value), 4) for value in rectangle), vocabulary["tasks"][task]]
            for rectangle, owner, task in zip(
                sample.grasp_rectangles, sample.grasp_objects, sample.grasp_tasks, strict=True)
            if owner == row
        ]
        annotations.append({
            "id": first_annotation + row, "image_id": image_id,
            "category_id": list(vocabulary["categories"]).index(category) + 1,
            "bbox": [x1, y1, width, height], "area": width * height, "iscrowd": 0,
            "visible_fraction": round(float(sample.visible_fraction[row]), 4), "grasps": grasps,
        })
    return image, annotations


def export(store: ShardStore, out_dir: str | Path, format: str = "osgd", pipeline: str | None = None) -> str:
    """Write every verified sample of a data dir in one format.

    Parameters
    ----------
    store : ShardStore
    out_dir : path
        Created if needed; files go under ``<out_dir>/<split>/`` (``hf``: see :mod:`osgd.export.hf`).
    format : {"osgd", "cornell", "coco", "hf"}
    pipeline : str, optional
        Whose samples (its manifest's shards); default: the data dir's only pipeline with samples.

    Returns
    -------
    str
        What was written.

    Raises
    ------
    ValueError
        If the format is unknown.
    FileNotFoundError
        If the data dir holds no samples.
    """
    if format not in FORMATS:
        raise ValueError(f"unknown export format {format!r}; choose one of {list(FORMATS)}")
    if format == "hf":
        from osgd.export.hf import export_hf  # noqa: PLC0415 (one format of four)

        return export_hf(store, out_dir, pipeline)
    out = Path(out_dir)
    vocabulary = samples_vocabulary(sample_shards(store.root, pipeline))
    counts: dict[str, int] = {}
    coco: dict[str, dict] = {}
    next_annotation = 1
    for sample in iter_samples(store.root, pipeline):
        folder = out / sample.split
        folder.mkdir(parents=True, exist_ok=True)
        counts[sample.split] = counts.get(sample.split, 0) + 1
        if format == "osgd":
            _osgd_files(sample, folder, vocabulary["tasks"])
        elif format == "cornell":
            _cornell_files(sample, folder)
        else:
            file_name = f"{sample.sample_id}_depth.png"
            _write_depth(sample, folder / file_name)
            document = coco.setdefault(sample.split, {
                "info": {"description": "osgd samples (depth, 16-bit PNG, millimetres)"},
                "images": [], "annotations": [],
                "categories": [{"id": index + 1, "name": name}
                               for index, name in enumerate(vocabulary["categories"])],
            })
            image, annotations = _coco_entries(sample, len(document["images"]) + 1, next_annotation, file_name,
                                               vocabulary)
            next_annotation += len(annotations)
            document["images"].append(image)
            document["annotations"].extend(annotations)
    for split, document in coco.items():
        (out / split / f"{split}.json").write_text(json.dumps(document, indent=1))
    total = int(np.sum(list(counts.values()))) if counts else 0
    splits = ", ".join(f"{split} {count}" for split, count in sorted(counts.items()))
    return f"wrote {total} samples ({splits}) to {out} in the {format} format"
