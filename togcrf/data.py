"""Training data: a torch Dataset over ``samples`` shards, depth normalisation and augmentation.

Streaming: the dataset keeps only an index of ``(shard, row)`` pairs (built by
reading the small ``split`` column of each shard) and reads one shard at a
time when an item is asked for; :class:`ShardGroupedSampler` visits shards
in a seeded random order and the rows of each shard together, so every shard
is decoded once per epoch and the data set never has to fit in memory.

Depth normalisation (:func:`normalise_depth`): the table plane is fitted
to the image (:func:`table_depth`: a plane's inverse depth is affine in the
pixel coordinates, fitted robustly so that the objects on it do not pull it
up) and the image becomes the height above it in units of ``DEPTH_UNIT``
(0.1 m): ``(table - depth) / 0.1``. The table is 0 everywhere, also where
the camera is tilted (a median left a 2-3 cm ramp across the image, as
large as the tools' heights), objects a few centimetres high are
about 0.2-1, independent of the camera distance. Pixels without a reading
are 0.

Augmentation (:func:`augment`): random horizontal and vertical flips,
rotations by multiples of 90 degrees (all exact pixel permutations) and a
small isotropic scale jitter, applied to the image, the boxes and the grasp
rectangles together; ``theta`` is transformed with the closing direction.

Pixel convention: pixel ``(row, column)`` has its centre at ``x = column,
y = row`` (the convention of the renderer's boxes and rectangles). A flip of
an image of width ``W`` maps ``x`` to ``W - 1 - x``; a scale by ``s`` maps
``x`` to ``s * x``, so that dividing outputs by the scale gives the sample's
pixels back (the contract of :func:`depth_to_tensor`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Collection, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyarrow.parquet as pq
import torch
from torch.utils.data import Dataset, Sampler

from osgd.contract.files import is_uri
from osgd.contract.samples import Sample, decode_row, sample_shards, samples_vocabulary, shard_sample_models

logger = logging.getLogger(__name__)

#: Unit of the normalised depth image, metres (our choice: tools are 1-10 cm high).
DEPTH_UNIT = 0.1

#: Default range of the scale jitter (our choice: "small", down to -10 %).
DEFAULT_SCALE_JITTER = 0.1


#: What the depth image is measured from (:func:`normalise_depth`): ``"table"``, the fitted table
#: plane (the default), or ``"median"``, the image's median depth (which leaves the camera-tilt ramp
#: of the table in the image).
DEPTH_REFERENCES = ("table", "median")

#: Pixels closer than the fitted table by more than this are not table (metres, our choice: above the noise).
TABLE_TOLERANCE = 0.004

#: Refits of the table plane, each on the pixels the last fit called table.
TABLE_FIT_ROUNDS = 4

#: Every this many pixels per side enter the table fit (speed; the plane has 3 parameters).
TABLE_FIT_STRIDE = 4


def table_depth(depth: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The depth of the table plane under every pixel.

    A plane's inverse depth is affine in pixel coordinates, ``1 / z = a x + b
    y + c``; it is fitted by least squares to the valid pixels, then refitted
    ``TABLE_FIT_ROUNDS`` times to the pixels no more than ``TABLE_TOLERANCE``
    in front of the last fit, which drops the objects lying on it.

    Parameters
    ----------
    depth : (H, W) float32
        Metres.
    valid : (H, W) bool
        Pixels with a reading.

    Returns
    -------
    (H, W) float32
        Metres; the median depth everywhere if the fit is degenerate.
    """
    rows, columns = np.mgrid[0:depth.shape[0]:TABLE_FIT_STRIDE, 0:depth.shape[1]:TABLE_FIT_STRIDE]
    sampled = depth[rows, columns].astype(np.float64)
    keep = valid[rows, columns]
    design = np.stack([columns.ravel(), rows.ravel(), np.ones(rows.size)], axis=1).astype(np.float64)
    sampled, keep = sampled.ravel(), keep.ravel()
    inverse = np.zeros_like(sampled)
    inverse[keep] = 1.0 / sampled[keep]
    coefficients = None
    for _ in range(TABLE_FIT_ROUNDS):
        if keep.sum() < 3:
            break
        coefficients = np.linalg.lstsq(design[keep], inverse[keep], rcond=None)[0]
        fitted = 1.0 / np.maximum(design @ coefficients, 1e-6)
        keep = keep & (sampled >= fitted - TABLE_TOLERANCE)
    if coefficients is None:
        return np.full(depth.shape, float(np.median(depth[valid])), dtype=np.float32)
    full_rows, full_columns = np.mgrid[0:depth.shape[0], 0:depth.shape[1]]
    plane = coefficients[0] * full_columns + coefficients[1] * full_rows + coefficients[2]
    return (1.0 / np.maximum(plane, 1e-6)).astype(np.float32)


def normalise_depth(depth: np.ndarray, reference: str = "table") -> np.ndarray:
    """Height above the fitted table plane (or the median depth), in units of ``DEPTH_UNIT``.

    Parameters
    ----------
    depth : (H, W) float
        Metres, 0 or non-finite = no reading.
    reference : {"table", "median"}
        See ``DEPTH_REFERENCES``.

    Returns
    -------
    (H, W) float32
        ``(table - depth) / DEPTH_UNIT`` (:func:`table_depth`), or ``(median - depth) / DEPTH_UNIT``;
        pixels without a reading are 0.

    Raises
    ------
    ValueError
        If ``reference`` is not one of ``DEPTH_REFERENCES``.
    """
    if reference not in DEPTH_REFERENCES:
        raise ValueError(f"depth reference {reference!r}: expected one of {', '.join(DEPTH_REFERENCES)}")
    depth = np.asarray(depth, dtype=np.float32)
    valid = np.isfinite(depth) & (depth > 0)
    if not valid.any():
        return np.zeros(depth.shape, dtype=np.float32)
    if reference == "table":
        base = table_depth(depth, valid)
    else:
        base = np.float32(np.median(depth[valid]))
    height = np.where(valid, (base - depth) / DEPTH_UNIT, 0.0)
    return height.astype(np.float32)


def resize_scale(shape: tuple[int, int], image_size: int | None) -> float:
    """Scale factor that brings the longer side of an image of ``shape`` (H, W) to ``image_size`` px."""
    if image_size is None:
        return 1.0
    return float(image_size) / float(max(shape))


def scale_image(image: np.ndarray, scale: float, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    """Resize an image by ``scale`` with the mapping ``x_out = scale * x_in``.

    Parameters
    ----------
    image : (H, W) array
    scale : float
    interpolation : OpenCV flag
        ``cv2.INTER_NEAREST`` for label images.

    Returns
    -------
    (round(H * scale), round(W * scale)) array, same dtype; outside pixels 0.
    """
    if scale == 1.0:
        return image
    height, width = image.shape[:2]
    size = (max(1, round(width * scale)), max(1, round(height * scale)))
    matrix = np.array([[scale, 0.0, 0.0], [0.0, scale, 0.0]], dtype=np.float64)
    # without WARP_INVERSE_MAP OpenCV treats the matrix as the forward map src -> dst
    return cv2.warpAffine(image, matrix, size, flags=interpolation, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def depth_to_tensor(depth: np.ndarray, image_size: int | None, depth_reference: str = "table"
                    ) -> tuple[torch.Tensor, float]:
    """The network input of a depth map.

    Parameters
    ----------
    depth : (H, W) float
        Metres, 0 = no reading.
    image_size : int or None
        Longer side of the output, pixels; None keeps the size.
    depth_reference : {"table", "median"}
        What the height is measured from (``DEPTH_REFERENCES``; the training config's).

    Returns
    -------
    tensor : (1, h, w) float32
        Normalised depth (:func:`normalise_depth`).
    scale : float
        ``pixels_out = pixels_in * scale``.
    """
    scale = resize_scale(depth.shape, image_size)
    image = scale_image(normalise_depth(depth, depth_reference), scale)
    return torch.from_numpy(np.ascontiguousarray(image))[None], scale


@dataclass(frozen=True)
class Augmentation:
    """One draw of the random augmentation.

    Attributes
    ----------
    flip_x, flip_y : bool
        Mirror left-right / top-bottom (applied first).
    quarter_turns : int
        Then ``np.rot90`` this many times (counter-clockwise as displayed).
    scale : float
        Then scale by this factor (multiplies the resize to ``image_size``).
    """

    flip_x: bool = False
    flip_y: bool = False
    quarter_turns: int = 0
    scale: float = 1.0

    @staticmethod
    def draw(rng: np.random.Generator, scale_jitter: float = DEFAULT_SCALE_JITTER) -> Augmentation:
        """A random augmentation: fair coin flips, a uniform quarter-turn count, a uniform scale in [1 - jitter, 1].

        Never above 1: an image larger than ``image_size`` would be padded to the
        next multiple of 32 px, a third more pixels per step at 192 px.
        """
        return Augmentation(
            flip_x=bool(rng.integers(2)),
            flip_y=bool(rng.integers(2)),
            quarter_turns=int(rng.integers(4)),
            scale=float(rng.uniform(1.0 - scale_jitter, 1.0)),
        )


def transform_points(points: np.ndarray, shape: tuple[int, int], augmentation: Augmentation,
                     base_scale: float) -> np.ndarray:
    """Apply the flips, quarter turns and scale to (n, 2) pixel points of an image of ``shape``."""
    height, width = shape
    x, y = points[:, 0].astype(np.float64), points[:, 1].astype(np.float64)
    if augmentation.flip_x:
        x = width - 1 - x
    if augmentation.flip_y:
        y = height - 1 - y
    for _ in range(augmentation.quarter_turns % 4):
        # np.rot90: out[r, c] = in[c, W - 1 - r], so an input pixel (x, y) lands at (y, W - 1 - x)
        x, y = y, width - 1 - x
        height, width = width, height
    scale = augmentation.scale * base_scale
    return np.stack([x * scale, y * scale], axis=1)


def transform_angles(theta: np.ndarray, augmentation: Augmentation) -> np.ndarray:
    """Closing-direction angles (rad) after the flips and quarter turns, in ``[-pi/2, pi/2)``."""
    angle = theta.astype(np.float64)
    if augmentation.flip_x:
        angle = math.pi - angle
    if augmentation.flip_y:
        angle = -angle
    # a direction (dx, dy) becomes (dy, -dx) under one turn: its angle decreases by 90 degrees
    angle = angle - (augmentation.quarter_turns % 4) * math.pi / 2
    return np.remainder(angle + math.pi / 2, math.pi) - math.pi / 2


def augment(
    images: Sequence[np.ndarray],
    boxes: np.ndarray,
    rectangles: np.ndarray,
    augmentation: Augmentation,
    base_scale: float = 1.0,
    interpolations: Sequence[int] | None = None,
) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """Apply one augmentation (and the resize ``base_scale``) to images and their annotations.

    Parameters
    ----------
    images : sequence of (H, W) arrays
        Images of the same size (e.g. the normalised depth and a mask).
    boxes : (N, 4) float
        ``x1, y1, x2, y2`` pixels.
    rectangles : (G, 5) float
        ``x, y, h, w, theta``.
    augmentation : Augmentation
    base_scale : float
        Resize factor applied with the jitter (e.g. from :func:`resize_scale`).
    interpolations : sequence of OpenCV flags, optional
        Per image; linear by default.

    Returns
    -------
    images : list of arrays
    boxes : (N, 4) float32
    rectangles : (G, 5) float32
    """
    shape = images[0].shape[:2]
    out_images = []
    for index, image in enumerate(images):
        if image.shape[:2] != shape:
            raise ValueError(f"augment: image {index} has shape {image.shape[:2]}, expected {shape}")
        result = image
        if augmentation.flip_x:
            result = result[:, ::-1]
        if augmentation.flip_y:
            result = result[::-1, :]
        result = np.ascontiguousarray(np.rot90(result, augmentation.quarter_turns % 4))
        interpolation = interpolations[index] if interpolations is not None else cv2.INTER_LINEAR
        out_images.append(scale_image(result, augmentation.scale * base_scale, interpolation))
    scale = augmentation.scale * base_scale
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    corners = np.concatenate([boxes[:, [0, 1]], boxes[:, [2, 3]]], axis=0)
    moved = transform_points(corners, shape, augmentation, base_scale).reshape(2, -1, 2)
    new_boxes = np.concatenate([moved.min(axis=0), moved.max(axis=0)], axis=1)
    rectangles = np.asarray(rectangles, dtype=np.float64).reshape(-1, 5)
    new_rectangles = rectangles.copy()
    new_rectangles[:, :2] = transform_points(rectangles[:, :2], shape, augmentation, base_scale)
    new_rectangles[:, 2:4] *= scale
    new_rectangles[:, 4] = transform_angles(rectangles[:, 4], augmentation)
    return out_images, new_boxes.astype(np.float32), new_rectangles.astype(np.float32)


def sample_targets(sample: Sample, boxes: np.ndarray, rectangles: np.ndarray) -> dict[str, torch.Tensor]:
    """The model's target dict of a sample (contract of ``togcrf.model``).

    Objects are numbered as in ``sample.boxes``; labels are category index + 1
    (0 is the background class).
    """
    targets = {
        "boxes": torch.as_tensor(boxes, dtype=torch.float32).reshape(-1, 4),
        "labels": torch.as_tensor(sample.category_labels + 1, dtype=torch.int64),
        "grasps": torch.as_tensor(rectangles, dtype=torch.float32).reshape(-1, 5),
        "grasp_objects": torch.as_tensor(sample.grasp_objects, dtype=torch.int64),
        "grasp_tasks": torch.as_tensor(sample.grasp_tasks, dtype=torch.int64),
    }
    return targets


def drop_degenerate_objects(targets: dict[str, torch.Tensor], min_size: float = 1.0) -> dict[str, torch.Tensor]:
    """Remove objects whose box is thinner than ``min_size`` px (and their grasps), renumbering the rest.

    torchvision's detection losses reject boxes of zero width or height.
    """
    boxes = targets["boxes"]
    keep = ((boxes[:, 2] - boxes[:, 0]) >= min_size) & ((boxes[:, 3] - boxes[:, 1]) >= min_size)
    if bool(keep.all()):
        return targets
    new_index = torch.cumsum(keep.to(torch.int64), 0) - 1
    grasp_keep = keep[targets["grasp_objects"]] if len(targets["grasp_objects"]) else keep[:0]
    return {
        "boxes": boxes[keep],
        "labels": targets["labels"][keep],
        "grasps": targets["grasps"][grasp_keep],
        "grasp_objects": new_index[targets["grasp_objects"][grasp_keep]],
        "grasp_tasks": targets["grasp_tasks"][grasp_keep],
    }


class SamplesDataset(Dataset):
    """Samples of a data dir as ``(image (1, h, w), targets, sample_id)`` items.

    Parameters
    ----------
    data_dir : path
    pipeline : str, optional
        Read the shards listed by this pipeline's manifest; otherwise every
        verified shard in ``<data_dir>/samples``.
    split : {"train", "test"} or None
        Keep only this split.
    image_size : int or None
        Longer image side fed to the network, pixels (None: the sample's).
    augment : bool
        Random flips, quarter turns and scale jitter (seeded per item and epoch).
    seed : int
        Seed of the augmentation draws.
    max_samples : int, optional
        Keep the first this many samples (in shard order) for quick runs.
    scale_jitter : float
        Scale range ``[1 - scale_jitter, 1]`` when augmenting.
    depth_reference : {"table", "median"}
        What the input height is measured from (``DEPTH_REFERENCES``).

    Raises
    ------
    FileNotFoundError
        If the data dir has no samples (or none of the split).
    """

    def __init__(
        self,
        data_dir: str | Path,
        pipeline: str | None = None,
        split: str | None = "train",
        image_size: int | None = None,
        augment: bool = False,
        seed: int = 0,
        max_samples: int | None = None,
        scale_jitter: float = DEFAULT_SCALE_JITTER,
        depth_reference: str = "table",
    ) -> None:
        self.data_dir = data_dir if is_uri(data_dir) else Path(data_dir)
        self.pipeline = pipeline
        self.split = split
        self.image_size = image_size
        self.augment = augment
        self.seed = seed
        self.scale_jitter = scale_jitter
        self.depth_reference = depth_reference
        self.epoch = 0
        self.shards = sample_shards(self.data_dir, pipeline)
        #: The categories and tasks the shards were labelled with (``osgd.contract.taxonomy.VOCABULARY``).
        self.vocabulary = samples_vocabulary(self.shards)
        index: list[tuple[int, int]] = []
        for shard_number, path in enumerate(self.shards):
            try:
                splits = pq.read_table(path, columns=["split"]).column("split").to_pylist()
            except Exception as error:
                raise ValueError(f"{path}: cannot read the split column of a samples shard: {error}") from error
            index.extend((shard_number, row) for row, name in enumerate(splits) if split is None or name == split)
        if max_samples is not None:
            index = index[:max_samples]
        if not index:
            raise FileNotFoundError(f"{self.data_dir}: no samples of split {split!r} in {len(self.shards)} shards")
        self.index = index
        self._cached_shard: int | None = None
        self._cached_rows: Any = None
        logger.info("%s: %d samples of split %s in %d shards", self.data_dir, len(index), split, len(self.shards))

    def __len__(self) -> int:
        return len(self.index)

    def set_epoch(self, epoch: int) -> None:
        """Augmentation draws depend on the epoch (call before iterating a DataLoader)."""
        self.epoch = epoch

    def shard_keys(self) -> list[str]:
        """Keys (file stems) of the shards read, in order."""
        return [path.stem for path in self.shards]

    def models_shown(self, model_ids: Collection[str] | None = None) -> dict[str, str]:
        """Which of ``model_ids`` (None: every model) the objects of this dataset's items show, each with the first
        sample showing it.

        Reads the ``objects`` column of each shard (``osgd.contract.samples.shard_sample_models``); the
        objects are the sample's annotated ones, those visible enough to keep (docs/samples.md, "Objects").
        """
        wanted = None if model_ids is None else set(model_ids)
        rows: dict[int, set[int]] = {}
        for shard_number, row in self.index:
            rows.setdefault(shard_number, set()).add(row)
        shown: dict[str, str] = {}
        for shard_number in sorted(rows) if wanted is None or wanted else ():
            for row, (sample_id, _, models) in enumerate(shard_sample_models(self.shards[shard_number])):
                if row in rows[shard_number]:
                    for model_id in models if wanted is None else wanted.intersection(models):
                        shown.setdefault(model_id, sample_id)
        return shown

    def read_sample(self, item: int) -> Sample:
        """The decoded sample of item ``item``; keeps the last shard read in memory."""
        shard_number, row = self.index[item]
        if self._cached_shard != shard_number:
            path = self.shards[shard_number]
            try:
                self._cached_rows = pq.read_table(path)
            except Exception as error:
                raise ValueError(f"{path}: cannot read the samples shard: {error}") from error
            self._cached_shard = shard_number
        return decode_row(self._cached_rows.slice(row, 1).to_pylist()[0], self.vocabulary)

    def __getitem__(self, item: int) -> tuple[torch.Tensor, dict[str, torch.Tensor], str]:
        sample = self.read_sample(item)
        base_scale = resize_scale(sample.depth.shape, self.image_size)
        if self.augment:
            rng = np.random.default_rng([self.seed, self.epoch, item])
            augmentation = Augmentation.draw(rng, self.scale_jitter)
        else:
            augmentation = Augmentation()
        height = normalise_depth(sample.depth, self.depth_reference)
        images, boxes, rectangles = augment([height], sample.boxes, sample.grasp_rectangles, augmentation, base_scale,
                                            (cv2.INTER_LINEAR,))
        image = torch.from_numpy(np.ascontiguousarray(images[0]))[None]
        targets = drop_degenerate_objects(sample_targets(sample, boxes, rectangles))
        return image, targets, sample.sample_id


class ShardGroupedSampler(Sampler[int]):
    """Seeded random order that keeps the items of a shard together.

    Shards are visited in a random order and the items of each shard in a
    random order, so a streaming dataset decodes each shard once per epoch.
    The order depends only on ``seed`` and the epoch (set with
    :meth:`set_epoch`).

    For ``world`` processes of data-parallel training (``togcrf.distributed``)
    each rank takes, from every ``world * batch_size`` items of that order,
    its own ``batch_size`` (rank 0 the first), so that the processes' step
    ``k`` together holds the items of step ``k`` of one process at batch
    ``world * batch_size``; the last, incomplete global batch is dropped so
    that every rank takes the same number of steps.
    """

    def __init__(self, dataset: SamplesDataset, seed: int = 0, shuffle: bool = True, *, rank: int = 0,
                 world: int = 1, batch_size: int = 1) -> None:
        self.groups: dict[int, list[int]] = {}
        for item, (shard_number, _) in enumerate(dataset.index):
            self.groups.setdefault(shard_number, []).append(item)
        self.seed = seed
        self.shuffle = shuffle
        self.epoch = 0
        self.rank, self.world, self.batch_size = rank, world, batch_size
        global_batch = world * batch_size
        self.length = len(dataset) if world == 1 else len(dataset) // global_batch * batch_size

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return self.length

    def __iter__(self) -> Iterator[int]:
        order = self._order()
        if self.world == 1:
            yield from order
            return
        global_batch = self.world * self.batch_size
        for start in range(0, len(order) - global_batch + 1, global_batch):
            first = start + self.rank * self.batch_size
            yield from order[first:first + self.batch_size]

    def _order(self) -> list[int]:
        """Every item in this epoch's order."""
        shards = sorted(self.groups)
        if not self.shuffle:
            return [item for shard in shards for item in self.groups[shard]]
        rng = np.random.default_rng([self.seed, self.epoch])
        order = []
        for shard in rng.permutation(shards):
            items = self.groups[int(shard)]
            order.extend(items[int(position)] for position in rng.permutation(len(items)))
        return order


def collate(batch: Sequence[tuple[torch.Tensor, dict[str, torch.Tensor], str]]
            ) -> tuple[list[torch.Tensor], list[dict[str, torch.Tensor]], list[str]]:
    """Keep images and targets as lists: counts of objects and grasps vary per image."""
    images, targets, sample_ids = zip(*batch, strict=True)
    return list(images), list(targets), list(sample_ids)
