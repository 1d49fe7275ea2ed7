"""The data contract (osgd.contract): the boundary between the generator and the detector, and the vocabulary.

togcrf reads the generator's data through ``osgd.contract`` only; its robot
experiment, which runs the generator's physics and renderer, also through
``osgd.simulation``;
the contract imports only the standard library, numpy, pyarrow and OpenCV.
Samples shards and checkpoints record the vocabulary they were labelled
and trained with, and a model refuses data labelled with another.
"""

from __future__ import annotations

import ast
import json
import logging
import shutil
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import torch
from helpers import write_synthetic_samples
from typer.testing import CliRunner

from osgd.contract.samples import sample_shards, samples_vocabulary, shard_vocabulary
from osgd.contract.shards import file_sha256
from osgd.contract.taxonomy import VOCABULARY
from osgd.samples.export import export
from osgd.store import ShardStore, canonical_json
from togcrf.checkpoint import load_checkpoint, read_checkpoint, save_checkpoint
from togcrf.cli import app
from togcrf.train import TrainConfig, train

ROOT = Path(__file__).resolve().parents[1]

#: What the contract may import besides the standard library and itself.
CONTRACT_DEPENDENCIES = {"numpy", "pyarrow", "cv2"}


def imported_modules(path: Path) -> list[str]:
    """Every module a Python file imports, anywhere in it (lazy imports included)."""
    names = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.extend(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.append(node.module)
    return names


def test_the_detector_reads_the_generator_only_through_the_contract() -> None:
    """togcrf imports osgd.contract only; its robot experiment also osgd.simulation, the generator's physics and
    renderer (docs/architecture.md)."""
    offenders = []
    for path in sorted((ROOT / "togcrf").rglob("*.py")):
        robot = "robot" in path.relative_to(ROOT / "togcrf").parts
        for name in imported_modules(path):
            if name.split(".")[0] != "osgd" or name == "osgd.contract" or name.startswith("osgd.contract."):
                continue
            if not (robot and name == "osgd.simulation"):
                offenders.append(f"{path.relative_to(ROOT)}: {name}")
    assert not offenders, ("togcrf imports osgd outside osgd.contract (and, in togcrf/robot, osgd.simulation):\n"
                           + "\n".join(offenders))


def test_the_contract_imports_only_numpy_pyarrow_and_opencv() -> None:
    offenders = []
    for path in sorted((ROOT / "osgd" / "contract").glob("*.py")):
        for name in imported_modules(path):
            top = name.split(".")[0]
            allowed = (top in sys.stdlib_module_names or top in CONTRACT_DEPENDENCIES or top == "__future__"
                       or name.startswith("osgd.contract"))
            if not allowed:
                offenders.append(f"{path.relative_to(ROOT)}: {name}")
    assert not offenders, "\n".join(offenders)


def test_importing_the_contract_loads_nothing_of_the_generator() -> None:
    code = ("import sys, osgd.contract.samples, osgd.contract.shards, osgd.contract.schemas, "
            "osgd.contract.taxonomy, osgd.contract.encoding; print('\\n'.join(sorted(sys.modules)))")
    modules = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True,
                             cwd=ROOT).stdout.split()
    generator = [name for name in modules if name.startswith("osgd.") and not name.startswith("osgd.contract")]
    heavy = [name for name in modules if name.split(".")[0] in {"torch", "trimesh", "pybullet", "scipy", "coacd"}]
    assert not generator and not heavy, (generator, heavy)


def write_foreign_vocabulary(path: Path, vocabulary: dict[str, list[str]]) -> None:
    """Rewrite a samples shard as a build with another taxonomy would have written it (checksum file included)."""
    table = pq.read_table(path)
    metadata = dict(table.schema.metadata)
    metadata[b"osgd.vocabulary"] = json.dumps(vocabulary).encode()
    pq.write_table(table.replace_schema_metadata(metadata), path)
    checksum = path.with_suffix(".sha256")
    record = json.loads(checksum.read_text())
    record["sha256"] = file_sha256(path)
    checksum.write_text(canonical_json(record) + "\n")


def another_vocabulary() -> dict[str, list[str]]:
    """Today's vocabulary with two task labels swapped: the same size, another meaning."""
    tasks = list(VOCABULARY["tasks"])
    tasks[1], tasks[2] = tasks[2], tasks[1]
    return {"categories": list(VOCABULARY["categories"]), "tasks": tasks}


@pytest.fixture
def samples_dir(tmp_path: Path) -> Path:
    write_synthetic_samples(ShardStore(tmp_path / "data"), 12, test_every=4)
    return tmp_path / "data"


def test_samples_shards_record_their_vocabulary(samples_dir: Path) -> None:
    shards = sample_shards(samples_dir, "synthetic")
    assert len(shards) == 2
    expected = {field: list(names) for field, names in VOCABULARY.items()}
    assert [shard_vocabulary(path) for path in shards] == [expected, expected]
    write_foreign_vocabulary(shards[1], another_vocabulary())
    assert shard_vocabulary(shards[1]) == another_vocabulary()
    with pytest.raises(ValueError, match=f"{shards[1].name}.*another vocabulary than.*{shards[0].name}"):
        samples_vocabulary(shards)


def a_larger_vocabulary() -> dict[str, list[str]]:
    """Table I with a new category and a new task, as a user's taxonomy would label its samples."""
    tasks = list(VOCABULARY["tasks"])
    tasks.insert(-1, "pour")
    return {"categories": [*VOCABULARY["categories"], "mug"], "tasks": tasks}


def quick_training(samples_dir: Path, run_dir: Path, **changes: object) -> TrainConfig:
    return TrainConfig(**{"data": str(samples_dir), "out": str(run_dir), "pipeline": "synthetic", "model": "tog-crfs",
                          "backbone": "resnet18", "epochs": 1, "batch_size": 2, "max_samples": 2, "augment": False,
                          "warmup_steps": 1, "device": "cpu", "amp": False,
                          "model_options": {"box_head.detections_per_image": 5, "rpn.post_nms_test": 50},
                          **changes})


def test_the_detector_takes_the_vocabulary_of_its_data(samples_dir: Path, tmp_path: Path) -> None:
    """Classes, task logits and the CRF's matrices are sized by the data's vocabulary; the checkpoint keeps it,
    evaluation scores the data under it, and a model of it refuses data of Table I."""
    table_one = tmp_path / "table1"
    shutil.copytree(samples_dir, table_one)
    for path in sample_shards(samples_dir, "synthetic"):
        write_foreign_vocabulary(path, a_larger_vocabulary())
    train(quick_training(samples_dir, tmp_path / "run"))
    model, config = load_checkpoint(tmp_path / "run")
    assert config["vocabulary"] == a_larger_vocabulary()
    assert model.vocabulary == {field: tuple(names) for field, names in a_larger_vocabulary().items()}
    assert model.roi_heads.box_predictor.cls_score.out_features == len(VOCABULARY["categories"]) + 2  # mug, background
    assert model.grasp_head.task_count == model.crf.omega.shape[0] == model.crf.mu.shape[1] == 13
    arguments = ["eval", str(tmp_path / "run" / "checkpoint.pt"), "--data", str(samples_dir), "--pipeline",
                 "synthetic", "--speed-images", "0", "--out", str(tmp_path / "eval.json")]
    assert CliRunner().invoke(app, arguments).exit_code == 0
    arguments[3] = str(table_one)
    result = CliRunner().invoke(app, arguments)
    assert result.exit_code == 1 and "labelled with another vocabulary" in result.output
    assert "categories ['knife'" in result.output and "'pliers'] against ['knife'" in result.output
    assert "'pliers', 'mug']" in result.output  # the data's categories, then the model's


def test_exports_name_the_categories_and_tasks_of_their_samples_vocabulary(samples_dir: Path, tmp_path: Path) -> None:
    for path in sample_shards(samples_dir, "synthetic"):
        write_foreign_vocabulary(path, a_larger_vocabulary())
    store = ShardStore(samples_dir)
    export(store, tmp_path / "coco", "coco", "synthetic")
    document = json.loads((tmp_path / "coco" / "train" / "train.json").read_text())
    assert document["categories"][-1] == {"id": 11, "name": "mug"}
    tasks = {grasp[-1] for annotation in document["annotations"] for grasp in annotation["grasps"]}
    assert "hand over" in tasks and tasks <= set(a_larger_vocabulary()["tasks"])
    export(store, tmp_path / "osgd", "osgd", "synthetic")
    grasp_files = (tmp_path / "osgd" / "train").glob("*[0-9].txt")
    lines = [line for path in grasp_files for line in path.read_text().splitlines()]
    assert lines and any(line.endswith(" hand_over") for line in lines)
    export(store, tmp_path / "hf", "hf", "synthetic")
    written = pq.read_schema(next((tmp_path / "hf" / "data").glob("train-*.parquet")))
    assert json.loads(written.metadata[b"osgd.vocabulary"]) == a_larger_vocabulary()


def test_training_from_weights_of_another_vocabulary_is_refused(samples_dir: Path, tmp_path: Path) -> None:
    train(quick_training(samples_dir, tmp_path / "first"))
    for path in sample_shards(samples_dir, "synthetic"):
        write_foreign_vocabulary(path, another_vocabulary())
    expected = r"the data trained on is labelled with another vocabulary than --init .*first.checkpoint\.pt: tasks"
    with pytest.raises(ValueError, match=expected):
        train(quick_training(samples_dir, tmp_path / "second", init=str(tmp_path / "first" / "checkpoint.pt")))
    # resuming the first run on the relabelled data: refused too
    with pytest.raises(ValueError, match=r"the data trained on is labelled with another vocabulary than .*first"):
        train(quick_training(samples_dir, tmp_path / "first", epochs=2, resume=True))


def test_a_checkpoint_of_another_vocabulary_is_refused(samples_dir: Path, tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    train(TrainConfig(data=str(samples_dir), out=str(run_dir), pipeline="synthetic", model="tog",
                      backbone="resnet18", epochs=1, batch_size=2, max_samples=2, augment=False, warmup_steps=1,
                      device="cpu", amp=False,
                      model_options={"box_head.detections_per_image": 5, "rpn.post_nms_test": 50}))
    # what a training run saves loads without unpickling code, vocabulary and schema included
    checkpoint = torch.load(run_dir / "checkpoint.pt", weights_only=True)
    assert checkpoint["vocabulary"] == {field: list(names) for field, names in VOCABULARY.items()}
    assert {"schema_version", "model", "config"} <= set(checkpoint)
    assert {"scaler", "optimizer", "scheduler"} <= set(torch.load(run_dir / "training-state.pt", weights_only=True))
    arguments = ["eval", str(run_dir / "checkpoint.pt"), "--data", str(samples_dir), "--pipeline", "synthetic",
                 "--speed-images", "0", "--out", str(tmp_path / "eval.json")]
    assert CliRunner().invoke(app, arguments).exit_code == 0

    foreign = tmp_path / "foreign.pt"
    state = {key: value for key, value in checkpoint.items() if key not in ("vocabulary", "schema_version")}
    save_checkpoint(foreign, state, another_vocabulary())
    assert read_checkpoint(foreign)["vocabulary"] == another_vocabulary()
    arguments[1] = str(foreign)
    result = CliRunner().invoke(app, arguments)
    assert result.exit_code == 1
    assert str(foreign) in result.output and f"{samples_dir}/samples" in result.output
    assert "tasks ['no task', 'cut', 'screw'" in result.output  # the data's, then the checkpoint's
    assert "against ['no task', 'screw', 'cut'" in result.output


def test_a_corrupt_shard_is_reported_not_dropped_silently(samples_dir: Path,
                                                         caplog: pytest.LogCaptureFixture) -> None:
    shards = sample_shards(samples_dir, "synthetic")
    shards[0].write_bytes(shards[0].read_bytes()[:-100])
    with caplog.at_level(logging.WARNING, logger="osgd.contract.samples"):
        assert sample_shards(samples_dir, "synthetic") == shards[1:]
    assert any(str(shards[0]) in record.getMessage() and "checksum" in record.getMessage()
               for record in caplog.records), caplog.text


