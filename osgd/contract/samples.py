"""Read training samples as numpy arrays.

Example
-------
>>> from osgd.contract.samples import iter_samples
>>> for sample in iter_samples("data", pipeline="default", split="train"):  # doctest: +SKIP
...     depth = sample.depth                    # (H, W) float32, metres, 0 = no reading
...     boxes = sample.boxes                    # (N, 4) float32, x1 y1 x2 y2 pixels
...     rectangles = sample.grasp_rectangles    # (G, 5) float32, x y h w theta
...     owners = sample.grasp_objects           # (G,) int64, row of `boxes` each grasp belongs to

Streaming: shards are read one at a time and rows decoded lazily, so a data
set never has to fit in memory. This module needs only numpy, pyarrow and
OpenCV.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from osgd.contract.encoding import decode_depth, decode_mask
from osgd.contract.files import Location
from osgd.contract.shards import ShardError, ShardReader
from osgd.contract.taxonomy import VOCABULARY, vocabulary_difference

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Sample:
    """One rendered depth image and its annotations.

    Attributes
    ----------
    sample_id, scene_id, split : str
    depth : (H, W) float32
        Noisy depth, metres, 0 = no reading.
    depth_clean : (H, W) float32
        Noise-free depth, metres.
    mask : (H, W) uint8
        0 background, ``object_index + 1`` on each object's visible pixels.
    intrinsics : (4,) float64
        ``fx, fy, cx, cy`` in pixels.
    camera_position : (3,) float64
        Camera origin in the world frame, metres.
    camera_quaternion : (4,) float64
        Camera (OpenCV) frame in the world frame, ``(x, y, z, w)``.
    object_indices : (N,) int64
        Index of each annotated object in its scene.
    categories : tuple of str
    category_labels : (N,) int64
        Index into the shard's vocabulary's ``categories`` (Table I: ``taxonomy.CATEGORY_INDEX``), no
        background offset.
    boxes : (N, 4) float32
        ``x1, y1, x2, y2`` pixels, tight around the visible pixels.
    visible_fraction : (N,) float32
    grasp_rectangles : (G, 5) float32
        ``x, y, h, w, theta``: centre (px), opening (px), finger width (px),
        angle of the closing direction to the image x axis (rad, [-pi/2, pi/2)).
    grasp_objects : (G,) int64
        Row of ``boxes`` each grasp belongs to.
    grasp_tasks : (G,) int64
        Index into the shard's vocabulary's ``tasks`` (Table I: ``taxonomy.TASK_INDEX``).
    grasp_positions : (G, 3) float64
        3-D grasp centres in the camera frame, metres.
    grasp_quaternions : (G, 4) float64
        Gripper frames in the camera frame.
    model_ids : tuple of str
        The model id of each annotated object (row of ``boxes``).
    """

    sample_id: str
    scene_id: str
    split: str
    depth: np.ndarray
    depth_clean: np.ndarray
    mask: np.ndarray
    intrinsics: np.ndarray
    camera_position: np.ndarray
    camera_quaternion: np.ndarray
    object_indices: np.ndarray
    categories: tuple[str, ...]
    category_labels: np.ndarray
    boxes: np.ndarray
    visible_fraction: np.ndarray
    grasp_rectangles: np.ndarray
    grasp_objects: np.ndarray
    grasp_tasks: np.ndarray
    grasp_positions: np.ndarray
    grasp_quaternions: np.ndarray
    model_ids: tuple[str, ...] = ()


def decode_row(row: dict[str, Any], vocabulary: Mapping[str, Sequence[str]] | None = None) -> Sample:
    """Decode one row of the ``samples`` table (as from ``Table.to_pylist()``).

    Parameters
    ----------
    row : dict
    vocabulary : mapping, optional
        The vocabulary of its shard (:func:`shard_vocabulary`), which the labels index; default Table I's.

    Raises
    ------
    ValueError
        If a grasp names an object that is not among the sample's objects, or a category or task is not in
        the vocabulary.
    """
    vocabulary = VOCABULARY if vocabulary is None else vocabulary
    objects = row["objects"]
    object_indices = np.array([obj["object_index"] for obj in objects], dtype=np.int64)
    row_of_object = {int(index): position for position, index in enumerate(object_indices)}
    grasps = row["grasps"]
    try:
        grasp_objects = np.array([row_of_object[int(grasp["object_index"])] for grasp in grasps], dtype=np.int64)
    except KeyError as error:
        raise ValueError(f"sample {row['sample_id']}: a grasp names object {error} that has no box") from error
    return Sample(
        sample_id=row["sample_id"],
        scene_id=row["scene_id"],
        split=row["split"],
        depth=decode_depth(row["depth"]),
        depth_clean=decode_depth(row["depth_clean"]),
        mask=decode_mask(row["mask"]),
        intrinsics=np.asarray(row["intrinsics"], dtype=np.float64),
        camera_position=np.asarray(row["camera_position"], dtype=np.float64),
        camera_quaternion=np.asarray(row["camera_quaternion"], dtype=np.float64),
        object_indices=object_indices,
        categories=tuple(obj["category"] for obj in objects),
        category_labels=_labels(row, "categories", [obj["category"] for obj in objects], vocabulary),
        boxes=np.array([obj["box"] for obj in objects], dtype=np.float32).reshape(-1, 4),
        visible_fraction=np.array([obj["visible_fraction"] for obj in objects], dtype=np.float32),
        grasp_rectangles=np.array([grasp["rectangle"] for grasp in grasps], dtype=np.float32).reshape(-1, 5),
        grasp_objects=grasp_objects,
        grasp_tasks=_labels(row, "tasks", [grasp["task"] for grasp in grasps], vocabulary),
        grasp_positions=np.array([grasp["position"] for grasp in grasps], dtype=np.float64).reshape(-1, 3),
        grasp_quaternions=np.array([grasp["quaternion"] for grasp in grasps], dtype=np.float64).reshape(-1, 4),
        model_ids=tuple(str(obj["model_id"]) for obj in objects),
    )


def sample_shards(data_dir: str | Path, pipeline: str | None = None) -> list[Location]:
    """The verified ``samples`` shards of a data dir.

    Parameters
    ----------
    data_dir : path
    pipeline : str, optional
        Only the shards the manifest of this pipeline lists, in its order.
        Without it: the pipeline of the data dir's only manifest whose
        samples shards are on disk, or, where no manifest has, every verified shard in
        ``<data_dir>/samples/``, sorted. Shards left over from earlier
        parameters stay on disk (they are the cache), so a data dir is read
        through its manifest whenever it has one.

    Raises
    ------
    FileNotFoundError
        If there is no such manifest, or no samples at all.
    ValueError
        If no pipeline is given and several manifests have samples.
    """
    store = ShardReader(data_dir)
    if pipeline is None:
        pipeline = _only_samples_pipeline(store)
    if pipeline is not None:
        manifest = store.read_manifest(pipeline)
        if manifest is None:
            raise FileNotFoundError(f"{store.manifest_path(pipeline)}: no manifest; build the pipeline first")
        entries = manifest.get("stages", {}).get("samples", {}).get("shards", [])
        keys = [entry["key"] for entry in entries]
    else:
        keys = store.keys_on_disk("samples")
    paths = []
    for key in keys:
        try:
            store.verify("samples", key)
        except ShardError as error:
            log.warning("left out of the samples: %s", error)
            continue
        paths.append(store.shard_path("samples", key))
    if not paths:
        raise FileNotFoundError(f"{store.root / 'samples'}: no samples shards; run `osgd render` first")
    return paths


def held_out_models(data_dir: str | Path, pipeline: str | None = None) -> frozenset[str]:
    """The model ids a data dir's manifest declares held out of training: its tools of the test split.

    Where the scenes stage splits by model (``[scenes.split] by = "model"``),
    the manifest's samples entry lists them under ``split.test_models``
    (docs/scenes.md, "Splits by tool"). Empty where the split is by scene, or
    where no manifest has samples.

    Parameters
    ----------
    data_dir : path
    pipeline : str, optional
        The manifest to read; as :func:`sample_shards` chooses it otherwise.

    Raises
    ------
    ValueError
        If no pipeline is given and several manifests have samples, or the
        list is not a list of strings.
    """
    store = ShardReader(data_dir)
    if pipeline is None:
        pipeline = _only_samples_pipeline(store)
    manifest = store.read_manifest(pipeline) if pipeline is not None else None
    models = ((manifest or {}).get("stages", {}).get("samples", {}).get("split") or {}).get("test_models", [])
    if not isinstance(models, list) or not all(isinstance(model, str) for model in models):
        raise ValueError(f"{store.manifest_path(pipeline)}: stages.samples.split.test_models is {models!r}, "
                         "expected a list of model ids")
    return frozenset(models)


def shard_sample_models(path: Location) -> list[tuple[str, str, tuple[str, ...]]]:
    """``(sample_id, split, model ids of its objects)`` of every row of a samples shard, in row order.

    Reads only the ``sample_id``, ``split`` and ``objects`` columns.

    Raises
    ------
    ShardError
        If the file is not readable Parquet of the samples schema.
    """
    try:
        table = pq.read_table(path, columns=["sample_id", "split", "objects"])
    except (OSError, ValueError, KeyError) as error:
        raise ShardError(f"{path}: cannot read the sample ids, splits and objects ({error})") from error
    return [(row["sample_id"], row["split"], tuple(str(obj["model_id"]) for obj in row["objects"]))
            for row in table.to_pylist()]


def _only_samples_pipeline(store: ShardReader) -> str | None:
    names = []
    for name in store.files.names("manifests", ".json"):
        manifest = store.read_manifest(name) or {}
        entries = manifest.get("stages", {}).get("samples", {}).get("shards", [])
        # A committed manifest (data/manifests/golden.json) names shards that were never built here.
        if any(store.shard_exists("samples", entry["key"]) for entry in entries):
            names.append(name)
    if len(names) > 1:
        raise ValueError(f"{store.root / 'manifests'}: several pipelines have samples ({', '.join(names)}); "
                         "name one (--pipeline)")
    return names[0] if names else None


def shard_vocabulary(path: Location) -> dict[str, list[str]]:
    """The vocabulary a samples shard was labelled with (``osgd.vocabulary`` in its metadata).

    A shard written before shards recorded it (samples stage version 3 and
    older) was labelled with the vocabulary of schema version 1, which is
    :data:`~osgd.contract.taxonomy.VOCABULARY`, Table I's.

    Raises
    ------
    ShardError
        If the file is not readable Parquet or its vocabulary is not JSON.
    """
    try:
        metadata = pq.read_schema(path).metadata or {}
    except (OSError, ValueError) as error:
        raise ShardError(f"{path}: unreadable Parquet ({error})") from error
    return metadata_vocabulary(metadata, str(path))


def metadata_vocabulary(metadata: Mapping[bytes, bytes] | None, source: str) -> dict[str, list[str]]:
    """The vocabulary of a samples table's Parquet metadata (:func:`shard_vocabulary`), ``source`` naming it.

    Raises
    ------
    ShardError
        If its ``osgd.vocabulary`` is not JSON.
    """
    text = (metadata or {}).get(b"osgd.vocabulary")
    if text is None:
        return {field: list(names) for field, names in VOCABULARY.items()}
    try:
        return {field: list(names) for field, names in json.loads(text).items()}
    except (ValueError, AttributeError, TypeError) as error:
        raise ShardError(f"{source}: unreadable osgd.vocabulary metadata ({error})") from error


def samples_vocabulary(shards: Sequence[Location]) -> dict[str, list[str]]:
    """The one vocabulary of several samples shards.

    Raises
    ------
    ValueError
        If two shards were labelled with different vocabularies (naming both).
    """
    if not shards:
        return {field: list(names) for field, names in VOCABULARY.items()}
    first = shard_vocabulary(shards[0])
    for path in shards[1:]:
        difference = vocabulary_difference(shard_vocabulary(path), first)
        if difference is not None:
            raise ValueError(f"{path}: labelled with another vocabulary than {shards[0]}: {difference}")
    return first


#: What one entry of each vocabulary field is called, for messages.
_FIELD_ENTRY = {"categories": "category", "tasks": "task"}


def _labels(row: dict[str, Any], field: str, names: list[str], vocabulary: Mapping[str, Sequence[str]]
            ) -> np.ndarray:
    """The indices of ``names`` in the vocabulary's ``field`` (int64)."""
    index = {name: position for position, name in enumerate(vocabulary[field])}
    try:
        return np.array([index[name] for name in names], dtype=np.int64)
    except KeyError as error:
        raise ValueError(f"sample {row['sample_id']}: {_FIELD_ENTRY[field]} {error} is not in its shard's "
                         f"vocabulary {list(vocabulary[field])}") from error


def iter_samples(
    data_dir: str | Path,
    pipeline: str | None = None,
    split: str | None = None,
    shards: Sequence[Location] | None = None,
) -> Iterator[Sample]:
    """Stream decoded samples, one shard in memory at a time.

    Parameters
    ----------
    data_dir : path
    pipeline : str, optional
        See :func:`sample_shards`.
    split : {"train", "test"}, optional
        Only samples of this split.
    shards : sequence of path, optional
        Read these files instead of looking them up.
    """
    for path in shards if shards is not None else sample_shards(data_dir, pipeline):
        vocabulary = shard_vocabulary(path)
        parquet = pq.ParquetFile(path)
        for batch in parquet.iter_batches(batch_size=16):
            for row in batch.to_pylist():
                if split is None or row["split"] == split:
                    yield decode_row(row, vocabulary)
