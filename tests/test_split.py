"""Splits by tool: held-out models, piles drawn from one side, the split recorded, and training refusing leaks."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from helpers import fixture_models
from pydantic import ValidationError
from test_samples import item_for
from test_samples_fixtures import write_fixture_inputs
from test_togcrf_train import quick_config

from osgd.config import ConfigError
from osgd.contract.samples import held_out_models, iter_samples, shard_sample_models
from osgd.executor import SerialExecutor
from osgd.pipeline import load_pipeline, plan_pipeline, run_stages
from osgd.samples.stage import SamplesStage, SamplesStageParams, sample_payload
from osgd.scenes.params import ScenesStageParams
from osgd.scenes.split import SplitParams, model_sides, unit_hash
from osgd.stage import WorkItem
from osgd.store import ShardStore
from togcrf.train import train

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = ROOT / "data"
#: The tools the pipeline test holds out, by name: three of the golden pipeline's ten categories.
HELD_OUT = ("procedural/hammer_00", "procedural/knife_00", "procedural/spoon_00")
SPLIT_OVERRIDES = ("scenes.split.by=model", "scenes.split.model_fraction=0",
                   f"scenes.split.test_models={json.dumps(list(HELD_OUT))}", "scenes.split.scene_fraction=0.5",
                   "scenes.count=6", "scenes.scenes_per_shard=3", "scenes.min_objects=2", "scenes.max_objects=3")


def rows_of(categories: dict[str, int]) -> list[dict]:
    return [{"model_id": f"{category}-{index}", "name": f"tools/{category}_{index}", "category": category}
            for category, count in categories.items() for index in range(count)]


def test_the_default_split_keeps_every_key_and_manifest_entry() -> None:
    assert "split" not in ScenesStageParams().key_dict()
    assert ScenesStageParams(split=SplitParams()).key_dict() == ScenesStageParams().key_dict()
    payload = sample_payload(SamplesStageParams().key_dict(), 0, "scenes_000")
    assert "split" not in payload
    committed = json.loads((GOLDEN / "manifests" / "golden.json").read_text())["stages"]
    planned = plan_pipeline(load_pipeline(ROOT / "pipelines" / "golden.toml"))
    for stage in ("scenes", "samples"):
        assert [shard.key for shard in planned[stage]] == [shard["key"] for shard in committed[stage]["shards"]]
        assert "split" not in committed[stage] and "split" not in committed[stage]["params"]


def test_models_are_held_out_per_category_by_model_id_hash_and_by_name() -> None:
    rows = rows_of({"hammer": 1, "knife": 2, "spoon": 5, "pen": 10})
    sides = model_sides(rows, SplitParams(by="model", model_fraction=0.2))
    held = {category: sorted(row["model_id"] for row in rows if row["category"] == category
                             and sides[row["model_id"]] == "test") for category in ("hammer", "knife", "spoon", "pen")}
    # ceil(0.2 n), at most n - 1: a lone model trains, every category of two or more holds one out
    assert {category: len(ids) for category, ids in held.items()} == {"hammer": 0, "knife": 1, "spoon": 1, "pen": 2}
    pens = sorted((row["model_id"] for row in rows if row["category"] == "pen"), key=unit_hash)
    assert held["pen"] == sorted(pens[:2])  # the lowest model-id hashes
    # by name or id, beside the fraction; the order of the list changes nothing
    named = model_sides(rows, SplitParams(by="model", model_fraction=0.2, test_models=("hammer-0", "tools/pen_9")))
    fraction_picks = {*held["knife"], *held["spoon"], *held["pen"]}
    assert {model for model, side in named.items() if side == "test"} == {*fraction_picks, "hammer-0", "pen-9"}
    assert SplitParams(by="model", test_models=("b", "a")) == SplitParams(by="model", test_models=("a", "b"))
    # without per_category: a model is test when its hash is below the fraction
    flat = model_sides(rows, SplitParams(by="model", model_fraction=0.5, per_category=False))
    assert flat == {row["model_id"]: "test" if unit_hash(row["model_id"]) < 0.5 else "train" for row in rows}
    with pytest.raises(ValueError, match=r"test_models = \['tools/saw_0'\]: no model"):
        model_sides(rows, SplitParams(by="model", test_models=("tools/saw_0",)))


def test_bad_split_settings_are_one_line_naming_the_key() -> None:
    with pytest.raises(ValidationError, match=r"by = 'scene' .* uses none of model_fraction"):
        SplitParams(model_fraction=0.3)
    with pytest.raises(ValidationError, match="holds out no model"):
        SplitParams(by="model", model_fraction=0.0)
    with pytest.raises(ConfigError, match=r"\[scenes\] split.by = 'tool': Input should be 'scene' or 'model'"):
        load_pipeline(ROOT / "pipelines" / "golden.toml", ["scenes.split.by=tool"])
    with pytest.raises(ConfigError, match=r"split.ratio = 1: unknown key; allowed keys: by, model_fraction"):
        load_pipeline(ROOT / "pipelines" / "golden.toml", ["scenes.split.ratio=1"])


def test_a_pile_that_mixes_train_and_test_models_is_test(tmp_path: Path) -> None:
    store = ShardStore(tmp_path)
    keys = write_fixture_inputs(store)  # 0: hammer, screwdriver, block; 1: hammer, block; 2: hammer alone
    screwdriver = fixture_models()[1]
    split = SplitParams(by="model", test_models=(screwdriver["name"],)).model_dump(mode="json")
    params = SamplesStageParams(renderer="embree")
    item = item_for(keys, params)
    item = WorkItem(item.item_id, sample_payload(params.key_dict(), 0, "scenes_0000", split), item.inputs)
    result = SamplesStage().build(item, store)
    assert dict(zip(result.table["scene_id"].to_pylist(), result.table["split"].to_pylist(), strict=True)) == {
        "scene_000000": "test", "scene_000001": "train", "scene_000002": "train"}
    assert any("1 of 3 scenes mix train and test models" in note for note in result.notes)
    # the split settings are in the key: another payload
    assert item.payload != item_for(keys, params).payload


@pytest.fixture(scope="module")
def split_by_model(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """The golden pipeline with three tools held out and six small piles, half of them test.

    The models, grasps and checks are the committed golden shards (the split changes none of them); the scenes
    and samples are built.
    """
    root = tmp_path_factory.mktemp("split")
    store = ShardStore(root)
    committed = json.loads((GOLDEN / "manifests" / "golden.json").read_text())["stages"]
    for stage in ("models", "grasps", "checks"):
        for shard in committed[stage]["shards"]:
            store.write(stage, shard["key"], shard["item"],
                        pq.read_table(GOLDEN / "golden" / stage / f"{shard['key']}.parquet"))
    config = load_pipeline(ROOT / "pipelines" / "golden.toml", SPLIT_OVERRIDES)
    reports = run_stages(config, store, SerialExecutor(), ["models", "grasps", "checks", "scenes", "samples"])
    assert all(report.ok for report in reports)
    assert [report.built for report in reports] == [0, 0, 0, 2, 2]
    return root, json.loads((root / "manifests" / "golden.json").read_text())


def test_split_by_model_draws_each_pile_from_one_side_and_records_it(split_by_model: tuple[Path, dict]) -> None:
    root, manifest = split_by_model
    store = ShardStore(root)
    models = store.read_many("models", [shard["key"] for shard in manifest["stages"]["models"]["shards"]],
                             columns=["model_id", "name"]).to_pylist()
    held_out = {row["model_id"] for row in models if row["name"] in HELD_OUT}
    assert len(held_out) == 3
    entry = manifest["stages"]["samples"]
    assert entry["split"]["by"] == "model" and entry["split"]["test_models"] == sorted(held_out)
    assert sorted(entry["split"]["train_models"]) == sorted({row["model_id"] for row in models} - held_out)
    assert manifest["stages"]["scenes"]["params"]["split"]["test_models"] == sorted(HELD_OUT)
    assert held_out_models(root) == held_out

    scenes = [row for shard in manifest["stages"]["scenes"]["shards"]
              for row in store.read("scenes", shard["key"]).to_pylist()]
    sides = {scene["scene_id"]: {obj["model_id"] in held_out for obj in scene["objects"]} for scene in scenes}
    assert all(len(side) == 1 for side in sides.values()), sides  # no pile mixes train and test tools
    samples = list(iter_samples(root, "golden"))
    test = [sample for sample in samples if sample.split == "test"]
    training = [sample for sample in samples if sample.split == "train"]
    assert test and training
    assert all(sides[sample.scene_id] == {sample.split == "test"} for sample in samples)
    assert any(held_out & set(sample.model_ids) for sample in test)  # a test pile shows a held-out tool
    assert all(set(sample.model_ids) <= held_out for sample in test)
    assert not any(held_out & set(sample.model_ids) for sample in training)
    # the same rows through the reader of the objects column alone
    for shard in entry["shards"]:
        for sample_id, split, model_ids in shard_sample_models(store.shard_path("samples", shard["key"])):
            assert (split == "test") == bool(held_out & set(model_ids)), sample_id


def test_training_refuses_training_samples_that_show_test_models(split_by_model: tuple[Path, dict],
                                                                 tmp_path: Path) -> None:
    root, manifest = split_by_model
    config = quick_config(root, tmp_path / "run", pipeline="golden", max_samples=None)
    assert train(config)  # the split the pipeline built trains
    # The same samples declared with another rule: a tool they train on is now a test tool.
    store = ShardStore(root)
    training = list(iter_samples(root, "golden", split="train"))
    leaked = sorted({model for sample in training for model in sample.model_ids})[:2]
    declared = json.loads(json.dumps(manifest))
    declared["stages"]["samples"]["split"]["test_models"] += leaked
    store.write_manifest("golden", declared)
    try:
        with pytest.raises(ValueError, match=r"show 2 of them: " + ", ".join(leaked) + r" \(e\.g\. in scene_"):
            train(quick_config(root, tmp_path / "leaked", pipeline="golden"))
    finally:
        store.write_manifest("golden", manifest)
