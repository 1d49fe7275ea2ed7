"""``osgd export --format hf``: a folder the real ``datasets`` library opens offline.

Synthetic samples (train and test) go through the command line; ``datasets.load_dataset`` then reads the
folder with its card, and also as plain Parquet files, with the PNG columns as Image features.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from helpers import write_synthetic_samples
from typer.testing import CliRunner

from osgd.cli import app
from osgd.contract.samples import iter_samples
from osgd.contract.schemas import SAMPLES
from osgd.store import ShardStore

datasets = pytest.importorskip("datasets")
yaml = pytest.importorskip("yaml")
runner = CliRunner()


@pytest.fixture(autouse=True)
def _offline(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """No hub: the library must read only the local files."""
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_DATASETS_OFFLINE", "1")
    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf-home"))


@pytest.fixture
def exported(tmp_path: Path) -> tuple[ShardStore, Path]:
    store = ShardStore(tmp_path / "data")
    write_synthetic_samples(store, 12, test_every=4, height=48, width=64)
    out = tmp_path / "hf"
    result = runner.invoke(app, ["--data-dir", str(store.root), "export", "--format", "hf", str(out)])
    assert result.exit_code == 0, result.output
    assert "wrote 12 samples (train 9, test 3)" in result.output
    return store, out


def _card(out: Path) -> dict:
    text = (out / "README.md").read_text()
    assert text.startswith("---\n")
    return yaml.safe_load(text.split("---\n")[1])


def test_load_dataset_opens_the_folder_with_train_and_test_splits(exported) -> None:
    store, out = exported
    loaded = datasets.load_dataset(str(out))
    assert sorted(loaded) == ["test", "train"]
    assert (loaded["train"].num_rows, loaded["test"].num_rows) == (9, 3)
    assert set(loaded["test"]["split"]) == {"test"}
    for name in ("depth", "depth_clean", "mask"):
        assert isinstance(loaded["train"].features[name], datasets.Image)
    expected = {sample.sample_id: sample for sample in iter_samples(store.root)}
    for row in loaded["test"]:
        sample = expected[row["sample_id"]]
        depth = np.asarray(row["depth"])
        assert depth.dtype == np.uint16 and depth.shape == (48, 64)
        np.testing.assert_allclose(depth / 1000.0, np.nan_to_num(sample.depth), atol=5e-4)
        assert np.array_equal(np.asarray(row["mask"]), sample.mask)
        assert [obj["category"] for obj in row["objects"]] == list(sample.categories)


def test_plain_parquet_data_dir_opens_too(exported) -> None:
    _, out = exported
    loaded = datasets.load_dataset("parquet", data_dir=str(out / "data"))
    assert sorted(loaded) == ["test", "train"] and loaded["train"].num_rows == 9
    assert isinstance(loaded["train"].features["depth"], datasets.Image)


def test_the_card_declares_configs_features_splits_licence_and_source(exported) -> None:
    _, out = exported
    card = _card(out)
    files = {entry["split"]: entry["path"] for entry in card["configs"][0]["data_files"]}
    assert files == {"train": "data/train-*.parquet", "test": "data/test-*.parquet"}
    assert card["license"] == "unknown" and "license_name" in card
    features = datasets.Features._from_yaml_list(card["dataset_info"]["features"])
    assert features == datasets.load_dataset(str(out))["train"].features
    assert {split["name"]: split["num_examples"] for split in card["dataset_info"]["splits"]} == {
        "train": 9, "test": 3}
    assert card["osgd"]["pipeline"] == "synthetic" and card["osgd"]["manifest"] == "osgd-manifest.json"
    manifest = json.loads((out / "osgd-manifest.json").read_text())
    assert manifest["pipeline"] == "synthetic" and manifest["stages"]["samples"]["shards"]
    assert "millimetres" in card["osgd"]["columns"]["depth"]


def test_each_column_carries_its_description_and_units(exported) -> None:
    _, out = exported
    schema = pq.read_schema(next((out / "data").glob("train-*.parquet")))
    for field in SAMPLES:
        description = schema.field(field.name).metadata[b"description"].decode()
        assert description
        doc = (field.metadata or {}).get(b"doc")
        if doc:
            assert doc.decode() in description
    info = json.loads(schema.metadata[b"huggingface"])["info"]
    assert info["features"]["depth"] == {"_type": "Image"}
    assert "camera origin in the world, m" in info["description"]


def test_files_are_split_into_numbered_parts(tmp_path: Path) -> None:
    from osgd.export.hf import export_hf  # noqa: PLC0415

    store = ShardStore(tmp_path / "data")
    write_synthetic_samples(store, 10, test_every=100, height=32, width=32)
    export_hf(store, tmp_path / "hf", rows_per_file=4)
    names = sorted(path.name for path in (tmp_path / "hf" / "data").iterdir())
    # Sample 0 is the one test sample; nine train samples make files of 4, 4 and 1 rows.
    assert names == ["test-00000-of-00001.parquet", *(f"train-{index:05d}-of-00003.parquet" for index in range(3))]
    loaded = datasets.load_dataset(str(tmp_path / "hf"))
    assert (loaded["train"].num_rows, loaded["test"].num_rows) == (9, 1)


def test_a_folder_that_is_not_empty_is_refused_in_one_line(exported) -> None:
    store, out = exported
    result = runner.invoke(app, ["--data-dir", str(store.root), "export", "--format", "hf", str(out)])
    assert result.exit_code == 2
    assert f"{out}: not empty" in result.output and "Traceback" not in result.output
