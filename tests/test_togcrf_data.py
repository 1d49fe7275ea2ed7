"""The training data: streaming dataset, depth normalisation, augmentation that keeps rectangles right."""

from __future__ import annotations

import itertools
import math
import subprocess
import sys

import cv2
import numpy as np
import pytest
import torch
from helpers import write_synthetic_samples

from osgd.contract.samples import iter_samples
from osgd.store import ShardStore
from togcrf.data import (
    DEPTH_UNIT,
    Augmentation,
    SamplesDataset,
    ShardGroupedSampler,
    augment,
    collate,
    depth_to_tensor,
    normalise_depth,
)


@pytest.fixture(scope="module")
def synthetic_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("samples")
    write_synthetic_samples(ShardStore(root), 20, seed=3)
    return root


def rectangle_points(rectangle: np.ndarray) -> dict[str, np.ndarray]:
    """Probe points of a grasp rectangle: its centre, the jaw ends along the closing direction."""
    x, y, opening, _, theta = rectangle
    closing = np.array([math.cos(theta), math.sin(theta)])
    centre = np.array([x, y])
    return {"centre": centre[None], "beyond_jaws": np.stack([centre + 0.6 * opening * closing,
                                                              centre - 0.6 * opening * closing])}


def labels_at(mask: np.ndarray, points: np.ndarray) -> np.ndarray:
    columns = np.clip(np.rint(points[:, 0]).astype(int), 0, mask.shape[1] - 1)
    rows = np.clip(np.rint(points[:, 1]).astype(int), 0, mask.shape[0] - 1)
    return mask[rows, columns]


def neighbourhood(points: np.ndarray, radius: float) -> np.ndarray:
    offsets = np.array([[dx, dy] for dx in (-radius, 0, radius) for dy in (-radius, 0, radius)])
    return (points[:, None, :] + offsets[None]).reshape(-1, 2)


def grasp_fits(mask: np.ndarray, rectangle: np.ndarray, owner_label: int, radius: float = 0.0) -> bool:
    """The centre is on the owner and both jaw ends are off it (the bar lies across the closing line).

    With ``radius`` > 0 this must hold on a 3 x 3 neighbourhood of each probe
    point: grasps far from other objects' edges, so that resampling cannot flip a probe.
    """
    points = rectangle_points(rectangle)
    return bool((labels_at(mask, neighbourhood(points["centre"], radius)) == owner_label).all()
                and (labels_at(mask, neighbourhood(points["beyond_jaws"], radius)) != owner_label).all())


AUGMENTATIONS = [
    Augmentation(flip_x=True),
    Augmentation(flip_y=True),
    Augmentation(quarter_turns=1),
    Augmentation(quarter_turns=3, flip_x=True),
    Augmentation(flip_x=True, flip_y=True, quarter_turns=2, scale=1.1),
    Augmentation(quarter_turns=1, flip_y=True, scale=0.9),
]


@pytest.mark.parametrize("augmentation", AUGMENTATIONS)
def test_augmentation_keeps_rectangles_on_the_same_object_pixels(synthetic_dir, augmentation):
    checked = 0
    for sample in iter_samples(synthetic_dir, pipeline="synthetic"):
        images, boxes, rectangles = augment(
            [normalise_depth(sample.depth), sample.mask], sample.boxes, sample.grasp_rectangles, augmentation,
            base_scale=1.5, interpolations=[cv2.INTER_LINEAR, cv2.INTER_NEAREST])
        mask = images[1]
        for grasp, (before, after) in enumerate(zip(sample.grasp_rectangles, rectangles, strict=True)):
            label = int(sample.object_indices[sample.grasp_objects[grasp]]) + 1
            if not grasp_fits(sample.mask, before, label, radius=2.0):
                continue  # near another bar's edge in the original: nothing reliable to compare
            assert grasp_fits(mask, after, label), (sample.sample_id, grasp, augmentation)
            checked += 1
        # boxes stay tight around the object's pixels (to the resampling of the mask)
        for row, index in enumerate(sample.object_indices):
            ys, xs = np.nonzero(mask == index + 1)
            assert np.allclose(boxes[row], [xs.min(), ys.min(), xs.max(), ys.max()], atol=2.0)
        # the sizes scale with the image
        assert np.allclose(rectangles[:, 2:4], sample.grasp_rectangles[:, 2:4] * 1.5 * augmentation.scale,
                           rtol=1e-5)
        assert (rectangles[:, 4] >= -math.pi / 2).all() and (rectangles[:, 4] < math.pi / 2).all()
    assert checked > 50


def test_depth_normalisation_is_height_above_the_table():
    depth = np.full((40, 60), 0.8, dtype=np.float32)
    depth[10:20, 10:30] = 0.75
    depth[0, 0] = 0.0  # no reading
    height = normalise_depth(depth)
    assert height[15, 15] == pytest.approx(0.05 / DEPTH_UNIT, abs=1e-5)
    assert height[30, 50] == 0.0
    assert height[0, 0] == 0.0
    tensor, scale = depth_to_tensor(depth, 120)
    assert scale == pytest.approx(2.0)
    assert tuple(tensor.shape) == (1, 80, 120)
    # pixels_out = pixels_in * scale: the raised block's centre lands at twice its coordinates
    assert tensor[0, 30, 40].item() == pytest.approx(0.5, abs=1e-5)


def test_depth_normalisation_removes_a_tilted_table():
    """A camera tilted over a table sees a depth ramp; the input is the height above the table everywhere."""
    rows, columns = np.mgrid[0:120, 0:160]
    inverse_depth = 1.0 / 0.8 + 0.0009 * (columns - 80) + 0.0004 * (rows - 60)  # a plane: 1/z affine in pixels
    table = 1.0 / inverse_depth
    assert table.max() - table.min() > 0.05  # a 5 cm ramp across the image, more than a tool's height
    depth = table.copy()
    depth[30:60, 20:70] -= 0.03  # a 3 cm high tool lying on the table
    depth[80:90, 100:150] -= 0.012
    depth[5, 5] = 0.0  # no reading
    height = normalise_depth(depth.astype(np.float32)) * DEPTH_UNIT
    assert np.abs(height[100:, :]).max() < 1e-4  # bare table: 0 everywhere despite the ramp
    assert height[45, 45] == pytest.approx(0.03, abs=2e-4)
    assert height[85, 120] == pytest.approx(0.012, abs=2e-4)
    assert height[5, 5] == 0.0
    # Before the recipe the height was measured from the median depth: the ramp stays in the input.
    from_median = normalise_depth(depth.astype(np.float32), "median") * DEPTH_UNIT
    assert np.ptp(from_median[100:, :]) > 0.03
    assert np.median(from_median[depth > 0]) == pytest.approx(0.0, abs=1e-6)
    assert torch.equal(depth_to_tensor(depth, None, "median")[0][0], torch.from_numpy(from_median / DEPTH_UNIT))
    with pytest.raises(ValueError, match="depth reference 'floor': expected one of table, median"):
        normalise_depth(depth, "floor")


def test_dataset_streams_the_split_with_targets_in_the_network_frame(synthetic_dir):
    train = SamplesDataset(synthetic_dir, pipeline="synthetic", split="train", image_size=96)
    test = SamplesDataset(synthetic_dir, pipeline="synthetic", split="test", image_size=96)
    assert len(train) == 16 and len(test) == 4
    samples = {sample.sample_id: sample for sample in iter_samples(synthetic_dir, pipeline="synthetic")}
    image, targets, sample_id = train[3]
    sample = samples[sample_id]
    assert sample.split == "train"
    assert tuple(image.shape) == (1, 96, 96)
    assert torch.allclose(targets["boxes"], torch.as_tensor(sample.boxes) * 0.75)
    assert torch.equal(targets["labels"], torch.as_tensor(sample.category_labels + 1))
    assert torch.allclose(targets["grasps"][:, :4], torch.as_tensor(sample.grasp_rectangles[:, :4]) * 0.75)
    assert torch.equal(targets["grasp_tasks"], torch.as_tensor(sample.grasp_tasks))
    images, batch_targets, ids = collate([train[0], train[1], train[2]])
    assert len(images) == 3 and len(batch_targets) == 3 and len(ids) == 3
    assert len(SamplesDataset(synthetic_dir, pipeline="synthetic", max_samples=5)) == 5


def test_data_order_is_seeded_and_reads_each_shard_once(synthetic_dir):
    dataset = SamplesDataset(synthetic_dir, pipeline="synthetic", split=None)
    sampler = ShardGroupedSampler(dataset, seed=7)
    first = list(sampler)
    assert first == list(ShardGroupedSampler(dataset, seed=7))
    assert sorted(first) == list(range(len(dataset)))
    sampler.set_epoch(1)
    assert list(sampler) != first
    shards = [dataset.index[item][0] for item in first]
    changes = sum(1 for before, after in itertools.pairwise(shards) if before != after)
    assert changes == len(set(shards)) - 1


def test_augmentation_draws_depend_on_seed_epoch_and_item(synthetic_dir):
    dataset = SamplesDataset(synthetic_dir, pipeline="synthetic", augment=True, seed=1)
    first = dataset[2][1]["grasps"]
    assert torch.equal(first, dataset[2][1]["grasps"])
    dataset.set_epoch(1)
    draws = [dataset[2][1]["grasps"]]
    dataset.set_epoch(2)
    draws.append(dataset[2][1]["grasps"])
    assert any(not torch.equal(first, other) for other in draws)


def test_missing_data_names_the_directory(tmp_path):
    with pytest.raises(FileNotFoundError, match=str(tmp_path.name)):
        SamplesDataset(tmp_path)


def test_a_data_dir_is_read_through_its_manifest(tmp_path):
    """Shards of earlier parameters stay on disk as cache; only the manifest's are read."""
    import shutil  # noqa: PLC0415

    from osgd.contract.samples import sample_shards  # noqa: PLC0415

    store = ShardStore(tmp_path)
    write_synthetic_samples(store, 8, seed=1)  # an earlier run: its shard stays on disk
    current = write_synthetic_samples(store, 16, seed=2)  # rewrites the synthetic manifest
    assert len(store.keys_on_disk("samples")) == 3
    assert [path.stem for path in sample_shards(tmp_path)] == current
    assert len(list(iter_samples(tmp_path))) == 16
    # A manifest whose shards are not here (data/manifests/golden.json in a clone) does not count.
    foreign = store.read_manifest("synthetic")
    foreign["stages"]["samples"]["shards"] = [{**entry, "key": "f" * 64} for entry in
                                              foreign["stages"]["samples"]["shards"]]
    store.write_manifest("committed", foreign)
    assert [path.stem for path in sample_shards(tmp_path)] == current
    # A second pipeline with samples: the reader will not guess which one.
    shutil.copy(store.manifest_path("synthetic"), store.manifest_path("other"))
    with pytest.raises(ValueError, match="several pipelines have samples"):
        sample_shards(tmp_path)
    assert [path.stem for path in sample_shards(tmp_path, "other")] == current


def test_the_training_package_leaves_the_generator_dependencies_out():
    """togcrf reads shards only: importing all of it loads no physics, mesh or ray-casting library."""
    heavy = ("pybullet", "trimesh", "coacd", "embreex", "manifold3d", "rtree", "osgd.models", "osgd.grasps",
             "osgd.checks", "osgd.scenes", "osgd.physics", "osgd.raycast")
    script = ("import sys, togcrf.cli, togcrf.train, togcrf.evaluate, togcrf.predict, togcrf.figures, "
              "togcrf.reproduce, togcrf.fcgn\n"
              f"print(sorted(name for name in sys.modules if name.split('.')[0] in {heavy!r} or name in {heavy!r}))")
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]", result.stdout
