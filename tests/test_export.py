"""Export formats read back: osgd text, Cornell rectangles, COCO boxes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from test_samples_fixtures import write_fixture_inputs

from osgd.contract.encoding import decode_depth
from osgd.contract.samples import iter_samples
from osgd.contract.schemas import samples_schema
from osgd.contract.taxonomy import CATEGORIES, TASK_FILE_STEM, TASKS, read_taxonomy
from osgd.samples.export import export
from osgd.samples.projection import rectangles_from_corners, wrap_half_turn
from osgd.samples.stage import SamplesStage, SamplesStageParams, sample_payload
from osgd.stage import WorkItem
from osgd.store import ShardStore


@pytest.fixture(scope="module")
def samples_store(tmp_path_factory) -> ShardStore:
    store = ShardStore(tmp_path_factory.mktemp("export-data"))
    keys = write_fixture_inputs(store)
    params = SamplesStageParams(renderer="embree", image_width=256, image_height=212, fx=183.0, fy=183.0,
                                test_fraction=0.5)
    item = WorkItem("samples_scenes_0000", sample_payload(params.key_dict(), 0, "s"),
                    {table: tuple(values) for table, values in keys.items()})
    store.write("samples", "e" * 64, "samples_scenes_0000", SamplesStage().build(item, store).table)
    return store


def same_rectangles(found: np.ndarray, expected: np.ndarray) -> None:
    assert found.shape == expected.shape
    assert np.allclose(found[:, :4], expected[:, :4], atol=0.01)
    assert np.allclose(wrap_half_turn(found[:, 4] - expected[:, 4]), 0.0, atol=1e-3)


def test_osgd_text_format_reads_back(samples_store, tmp_path):
    message = export(samples_store, tmp_path, "osgd")
    assert "wrote 3 samples" in message
    stems = {stem: task for task, stem in TASK_FILE_STEM.items()}
    for sample in iter_samples(samples_store.root):
        folder = tmp_path / sample.split
        lines = (folder / f"{sample.sample_id}.txt").read_text().splitlines()
        fields = [line.split() for line in lines]
        assert all(len(parts) == 10 for parts in fields)
        corners = np.array([[float(value) for value in parts[:8]] for parts in fields]).reshape(-1, 4, 2)
        same_rectangles(rectangles_from_corners(corners), sample.grasp_rectangles)
        assert [int(parts[8]) for parts in fields] == sample.grasp_objects.tolist()
        assert [stems[parts[9]] for parts in fields] == [TASKS[task] for task in sample.grasp_tasks]
        objects = [line.split() for line in (folder / f"{sample.sample_id}_objects.txt").read_text().splitlines()]
        assert [parts[4] for parts in objects] == list(sample.categories)
        assert np.allclose([[float(value) for value in parts[:4]] for parts in objects], sample.boxes)
        depth = decode_depth((folder / f"{sample.sample_id}_depth.png").read_bytes())
        assert np.array_equal(depth, sample.depth)


def test_cornell_rectangles_read_back(samples_store, tmp_path):
    export(samples_store, tmp_path, "cornell")
    for sample in iter_samples(samples_store.root):
        folder = tmp_path / sample.split
        points = np.loadtxt(folder / f"{sample.sample_id}cpos.txt", ndmin=2)
        assert points.shape == (4 * len(sample.grasp_rectangles), 2)
        same_rectangles(rectangles_from_corners(points.reshape(-1, 4, 2)), sample.grasp_rectangles)
        assert (folder / f"{sample.sample_id}d.png").exists()


def test_coco_boxes_read_back(samples_store, tmp_path):
    export(samples_store, tmp_path, "coco")
    samples = {sample.sample_id: sample for sample in iter_samples(samples_store.root)}
    seen = 0
    for split in {sample.split for sample in samples.values()}:
        document = json.loads((tmp_path / split / f"{split}.json").read_text())
        names = {category["id"]: category["name"] for category in document["categories"]}
        assert sorted(names.values()) == sorted(CATEGORIES)
        for image in document["images"]:
            sample = samples[image["sample_id"]]
            seen += 1
            assert (image["height"], image["width"]) == sample.depth.shape
            assert (tmp_path / split / image["file_name"]).exists()
            annotations = [entry for entry in document["annotations"] if entry["image_id"] == image["id"]]
            assert [names[entry["category_id"]] for entry in annotations] == list(sample.categories)
            boxes = np.array([entry["bbox"] for entry in annotations]).reshape(-1, 4)
            recovered = np.column_stack([boxes[:, 0], boxes[:, 1], boxes[:, 0] + boxes[:, 2] - 1,
                                         boxes[:, 1] + boxes[:, 3] - 1])
            assert np.allclose(recovered, sample.boxes)
            assert sum(len(entry["grasps"]) for entry in annotations) == len(sample.grasp_rectangles)
        ids = [entry["id"] for entry in document["annotations"]]
        assert len(ids) == len(set(ids))
    assert seen == len(samples)


def test_unknown_format_is_refused(samples_store, tmp_path):
    with pytest.raises(ValueError, match="unknown export format"):
        export(samples_store, tmp_path, "voc")


def test_empty_data_dir_says_so(tmp_path):
    with pytest.raises(FileNotFoundError, match="no samples"):
        export(ShardStore(tmp_path / "empty"), tmp_path / "out", "osgd")


def test_a_taxonomys_own_category_and_task_are_exported(samples_store, tmp_path):
    """The fixture's samples relabelled into the kitchen taxonomy: its first object a mug, held for pouring."""
    kitchen = read_taxonomy(Path(__file__).resolve().parents[1] / "pipelines/kitchen/taxonomy.toml")
    rows = samples_store.read("samples", "e" * 64).to_pylist()
    first = rows[0]
    mug = first["objects"][0]["object_index"]
    first["objects"][0]["category"] = "mug"
    for grasp in first["grasps"]:
        if grasp["object_index"] == mug:
            grasp["task"] = "pour"
    store = ShardStore(tmp_path / "kitchen")
    store.write("samples", "f" * 64, "samples_scenes_0000",
                pa.Table.from_pylist(rows, schema=samples_schema(kitchen.vocabulary)))
    export(store, tmp_path / "coco", "coco")
    document = json.loads((tmp_path / "coco" / first["split"] / f"{first['split']}.json").read_text())
    assert [category["name"] for category in document["categories"]] == list(kitchen.category_names)
    image = next(image["id"] for image in document["images"] if image["sample_id"] == first["sample_id"])
    names = {category["id"]: category["name"] for category in document["categories"]}
    assert names[next(entry["category_id"] for entry in document["annotations"] if entry["image_id"] == image)] == "mug"
    export(store, tmp_path / "osgd", "osgd")
    lines = (tmp_path / "osgd" / first["split"] / f"{first['sample_id']}.txt").read_text().splitlines()
    pours = sum(grasp["object_index"] == mug for grasp in first["grasps"])
    assert pours > 0 and sum(line.split()[9] == "pour" for line in lines) == pours
