"""`togcrf eval`, `togcrf table` and `togcrf figures` on checkpoints made by togcrf.train."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import write_synthetic_samples
from typer.testing import CliRunner

from osgd.contract.taxonomy import TASKS
from osgd.store import ShardStore
from togcrf.checkpoint import load_checkpoint
from togcrf.cli import app
from togcrf.evaluate import TABLE_COLUMNS, evaluate_model, format_table, table_row
from togcrf.train import TrainConfig, train


def train_briefly(data_dir: Path, run_dir: Path, model: str) -> Path:
    """One training step of a ResNet-18 model on two synthetic samples; returns the checkpoint."""
    train(TrainConfig(data=str(data_dir), out=str(run_dir), pipeline="synthetic", model=model, backbone="resnet18",
                      epochs=1, batch_size=2, max_samples=2, augment=False, warmup_steps=1, device="cpu",
                      amp=False, model_options={"box_head.detections_per_image": 5, "rpn.post_nms_test": 50}))
    return run_dir / "checkpoint.pt"


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A data dir of synthetic samples and a briefly trained TOG-CRFs checkpoint."""
    torch.manual_seed(0)
    root = tmp_path_factory.mktemp("eval")
    data_dir = root / "data"
    write_synthetic_samples(ShardStore(data_dir), 10, test_every=5)  # samples 0 and 5 are test
    return data_dir, train_briefly(data_dir, root / "run", "tog-crfs")


def test_eval_writes_the_table_row(trained: tuple[Path, Path], tmp_path: Path) -> None:
    data_dir, checkpoint = trained
    out = tmp_path / "eval.json"
    result = CliRunner().invoke(app, ["eval", str(checkpoint), "--data", str(data_dir), "--pipeline", "synthetic",
                                      "--out", str(out), "--speed-images", "1"])
    assert result.exit_code == 0, result.output
    assert "TOG-CRFs" in result.output and "mAP-G" in result.output
    document = json.loads(out.read_text())  # strict JSON: NaN would have been written as null
    assert document["model"] == "tog-crfs" and document["split"] == "test" and document["seed"] == 0
    assert document["metrics"]["images"] == 2
    for column in ("mAP", "mAP-G", "Acc-T top1", "Acc-T top5", "Acc-T top10"):
        value = document["metrics"][column]
        assert value is None or 0.0 <= value <= 1.0
    assert document["metrics"]["mAP-G"] <= document["metrics"]["mAP"]
    assert document["speed"]["fps"] > 0 and document["speed"]["device"] == "cpu"
    # TOG-CRFs: the CRF's share of the time, a part of the whole
    assert 0.0 < document["speed"]["crf_share"] < 1.0
    assert 0.0 < document["speed"]["crf_seconds_per_image"] < 1.0 / document["speed"]["fps"]
    assert set(document["row"]) == set(TABLE_COLUMNS)

    # `table` prints rows side by side from run dirs or evaluation files.
    second = tmp_path / "run2"
    second.mkdir()
    (second / "eval.json").write_text(json.dumps({**document, "model": "tog"}))
    table_json = tmp_path / "table.json"
    result = CliRunner().invoke(app, ["table", str(out), str(second), "--out", str(table_json)])
    assert result.exit_code == 0, result.output
    lines = result.output.strip().splitlines()
    assert lines[0].split()[0] == "Algorithm" and lines[2].startswith("TOG-CRFs") and lines[3].startswith("TOG ")
    assert [row["name"] for row in json.loads(table_json.read_text())["rows"]] == ["TOG-CRFs", "TOG"]


def test_eval_under_the_lab_protocol(trained: tuple[Path, Path], tmp_path: Path) -> None:
    """`eval --protocol lab` scores the same checkpoint by the lab's rules and says so (Acc-T is shared)."""
    data_dir, checkpoint = trained
    documents = {}
    for protocol in ("ours", "lab"):
        out = tmp_path / f"{protocol}.json"
        result = CliRunner().invoke(app, ["eval", str(checkpoint), "--data", str(data_dir), "--pipeline",
                                          "synthetic", "--out", str(out), "--speed-images", "0",
                                          "--protocol", protocol])
        assert result.exit_code == 0, result.output
        assert result.output.startswith(f"Algorithm [protocol: {protocol}]")
        documents[protocol] = json.loads(out.read_text())
        assert documents[protocol]["protocol"] == documents[protocol]["metrics"]["protocol"] == protocol
        assert documents[protocol]["command"].startswith("togcrf ")  # the process's own command line
    assert documents["lab"]["metrics"]["Acc-T top1"] == documents["ours"]["metrics"]["Acc-T top1"]


def test_eval_with_test_time_views_keeps_the_boxes_and_says_so(trained: tuple[Path, Path], tmp_path: Path) -> None:
    """Views change only the grasp candidates: box mAP stays; the JSON and the row name say how many views."""
    data_dir, checkpoint = trained
    documents = {}
    for views in (1, 4):
        out = tmp_path / f"views{views}.json"
        result = CliRunner().invoke(app, ["eval", str(checkpoint), "--data", str(data_dir), "--pipeline", "synthetic",
                                          "--out", str(out), "--speed-images", "1", "--views", str(views)])
        assert result.exit_code == 0, result.output
        documents[views] = json.loads(out.read_text())
        assert documents[views]["test_time_views"] == views
    assert documents[4]["metrics"]["mAP"] == documents[1]["metrics"]["mAP"]
    assert "TOG-CRFs [4 views]" in result.output and documents[4]["speed"]["fps"] > 0
    result = CliRunner().invoke(app, ["eval", str(checkpoint), "--data", str(data_dir), "--views", "3"])
    assert result.exit_code == 1 and "1, 2, 4, 8" in result.output


def test_eval_errors_name_the_problem(trained: tuple[Path, Path], tmp_path: Path) -> None:
    data_dir, checkpoint = trained
    result = CliRunner().invoke(app, ["eval", str(tmp_path / "missing.pt"), "--data", str(data_dir)])
    assert result.exit_code == 1 and "missing.pt" in result.output
    result = CliRunner().invoke(app, ["eval", str(checkpoint), "--data", str(data_dir), "--split", "validation"])
    assert result.exit_code == 1 and "validation" in result.output
    result = CliRunner().invoke(app, ["table", str(tmp_path)])
    assert result.exit_code == 1 and "eval.json" in result.output


def test_evaluate_model_sees_the_sample_frame(trained: tuple[Path, Path]) -> None:
    """Evaluating at half the native size gives boxes in the sample's pixels, not the network's."""
    from osgd.contract.samples import iter_samples  # noqa: PLC0415

    data_dir, checkpoint = trained
    model, _ = load_checkpoint(checkpoint)
    model.roi_heads.score_thresh = 0.0
    samples = list(iter_samples(data_dir, pipeline="synthetic", split="test"))
    native = evaluate_model(model, samples[:1], None, speed_images=0)
    half = evaluate_model(model, samples[:1], 64, speed_images=0)
    assert native["speed"] is None and half["metrics"]["images"] == 1
    for result in (native, half):
        assert 0.0 <= result["metrics"]["mAP"] <= 1.0


def test_an_image_without_any_detection_scores_zero(trained: tuple[Path, Path]) -> None:
    """An untrained model can leave whole images without a box above the threshold."""
    from osgd.contract.samples import iter_samples  # noqa: PLC0415

    data_dir, checkpoint = trained
    model, _ = load_checkpoint(checkpoint)
    model.roi_heads.score_thresh = 1.1  # no score reaches it
    samples = list(iter_samples(data_dir, pipeline="synthetic", split="test"))
    result = evaluate_model(model, samples, None, speed_images=0)
    assert result["metrics"]["images"] == len(samples)
    assert result["metrics"]["mAP"] == 0.0 and result["metrics"]["mAP-G"] == 0.0


def test_figures_draw_omega_and_mu(trained: tuple[Path, Path], tmp_path: Path) -> None:
    _, checkpoint = trained
    result = CliRunner().invoke(app, ["figures", str(checkpoint), "--out", str(tmp_path / "figures")])
    assert result.exit_code == 0, result.output
    for name in ("omega.png", "mu.png", "figure5.png"):
        assert (tmp_path / "figures" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    values = json.loads((tmp_path / "figures" / "crf.json").read_text())
    assert values["tasks"] == list(TASKS)
    model, _ = load_checkpoint(checkpoint)
    assert np.allclose(values["omega"], model.crf.omega.detach().numpy())
    assert np.asarray(values["mu"]).shape == (12, 12)


def test_format_table_and_missing_values() -> None:
    row = table_row({"metrics": {"mAP": 0.5, "mAP-G": float("nan"), "Acc-T top1": 1.0, "Acc-T top5": 0.25,
                                 "Acc-T top10": 0.0}, "speed": {"fps": 3.0}})
    assert row["mAP"] == 50.0 and row["mAP-G"] is None and row["fps"] == 3.0
    text = format_table([("TOG", row)])
    cells = text.splitlines()[2].split()
    assert cells == ["TOG", "50.0", "-", "100.0", "25.0", "0.0", "3.0"]
    assert not math.isnan(row["Acc-T top1"])


def _evaluated_run(folder: Path, model: str, seed: int | None, map_percent: float, fps: float | None,
                   protocol: str = "ours") -> Path:
    """A run dir with a hand-made eval.json (the Table II row in percent) and, with a seed, its config.json."""
    folder.mkdir(parents=True, exist_ok=True)
    row = {column: None for column in TABLE_COLUMNS} | {"mAP": map_percent, "mAP-G": map_percent / 4, "fps": fps}
    (folder / "eval.json").write_text(json.dumps({"model": model, "protocol": protocol, "row": row}))
    if seed is not None:
        (folder / "config.json").write_text(json.dumps({"seed": seed, "model": model}))
    return folder


def test_table_names_the_seeds_and_averages_over_them(tmp_path: Path) -> None:
    """Runs of one model are told apart by their seed; --mean gives each model's mean and sample sd."""
    runs = [_evaluated_run(tmp_path / "s0" / "tog", "tog", 0, 10.0, 20.0),
            _evaluated_run(tmp_path / "s1" / "tog", "tog", 1, 14.0, None),
            _evaluated_run(tmp_path / "s0" / "tog-crfs", "tog-crfs", 0, 12.0, 30.0)]
    # a run dir or the evaluation file in it: the seed comes from the config.json beside the evaluation
    result = CliRunner().invoke(app, ["table", str(runs[0]), str(runs[1] / "eval.json"), str(runs[2])])
    assert result.exit_code == 0, result.output
    names = [line.split("  ")[0] for line in result.output.strip().splitlines()[2:]]
    assert names == ["TOG [seed 0]", "TOG [seed 1]", "TOG-CRFs"]

    out = tmp_path / "means.json"
    result = CliRunner().invoke(app, ["table", *map(str, runs), "--mean", "--out", str(out)])
    assert result.exit_code == 0, result.output
    lines = result.output.strip().splitlines()[2:]
    assert lines[0].split()[:6] == ["TOG", "(mean", "of", "2)", "12.0", "3.0"]
    assert lines[1].split()[:3] == ["sd", f"{math.sqrt(8):.1f}", f"{math.sqrt(8) / 4:.1f}"]
    means = json.loads(out.read_text())["means"]
    assert [(entry["name"], entry["runs"], entry["seeds"]) for entry in means] == [("TOG", 2, [0, 1]),
                                                                                  ("TOG-CRFs", 1, [0])]
    assert means[0]["mean"]["fps"] == 20.0  # a run without the column does not count towards its mean
    assert means[0]["mean"]["Acc-T top1"] is None and means[1]["sd"]["mAP"] is None
    # without a config.json, or with one seed twice, the runs of one model are numbered among themselves
    for name, seed in (("bare", None), ("twin", 3)):
        alike = [_evaluated_run(tmp_path / f"{name}{index}", "tog", seed, 5.0, None) for index in range(2)]
        result = CliRunner().invoke(app, ["table", str(alike[0]), str(runs[2]), str(alike[1])])
        names = [line.split("  ")[0] for line in result.output.strip().splitlines()[2:]]
        assert names == ["TOG [run 1]", "TOG-CRFs", "TOG [run 2]"], result.output
    # an evaluation committed as MODEL-eval.json takes its seed from MODEL-config.json beside it
    committed = tmp_path / "committed"
    committed.mkdir()
    for seed in (4, 5):
        (committed / f"s{seed}-eval-lab.json").write_text((runs[0] / "eval.json").read_text())
        (committed / f"s{seed}-config.json").write_text(json.dumps({"seed": seed, "model": "tog"}))
    result = CliRunner().invoke(app, ["table", *(str(committed / f"s{seed}-eval-lab.json") for seed in (4, 5))])
    names = [line.split("  ")[0] for line in result.output.strip().splitlines()[2:]]
    assert names == ["TOG [seed 4]", "TOG [seed 5]"], result.output
    # one run under both protocols, --mixed: each row marked with its protocol, no seed needed
    lab = _evaluated_run(tmp_path / "lab" / "tog", "tog", 0, 11.0, None, protocol="lab")
    result = CliRunner().invoke(app, ["table", str(runs[0]), str(lab), "--mixed"])
    names = [line.split("  ")[0] for line in result.output.strip().splitlines()[2:]]
    assert names == ["TOG [ours]", "TOG [lab]"], result.output
    result = CliRunner().invoke(app, ["table", str(runs[0]), str(lab), "--mixed", "--mean"])
    assert result.exit_code == 1 and "--mean averages one protocol" in result.output


def test_eval_on_test_sets_scores_each_set_under_both_protocols_and_counts_novel_tools(
    trained: tuple[Path, Path], tmp_path: Path
) -> None:
    """--test-set: one table of every (set, protocol); the tools never trained on are counted by model id."""
    _, checkpoint = trained
    data = tmp_path / "data"
    for pipeline in ("synthetic", "novel"):  # the training pipeline, and one of other tools in the same data dir
        write_synthetic_samples(ShardStore(data), 10, seed=0 if pipeline == "synthetic" else 4, test_every=5,
                                pipeline=pipeline)
    out = tmp_path / "sets.json"
    result = CliRunner().invoke(app, ["eval", str(checkpoint), "--data", str(data), "--test-set", "seen=synthetic",
                                      "--test-set", "novel=novel", "--out", str(out), "--speed-images", "1"])
    assert result.exit_code == 0, result.output
    for name in ("seen", "novel"):
        assert all(f"{name} [{protocol}]" in result.output for protocol in ("ours", "lab"))
    document = json.loads(out.read_text())
    seen, novel = document["test_sets"]["seen"], document["test_sets"]["novel"]
    trained_models = set(load_checkpoint(checkpoint)[1]["data"]["models"])
    assert trained_models and all(model.startswith("synthetic") for model in trained_models)
    assert seen["novel_tools"] == 0 and novel["tools"] >= 1 and novel["novel_tools"] == novel["tools"]
    assert seen["images"] == novel["images"] == 2 and document["speed"]["fps"] > 0
    # one pass scores both protocols: each equals a plain evaluation under it
    for protocol in ("ours", "lab"):
        single = tmp_path / f"{protocol}.json"
        assert CliRunner().invoke(app, ["eval", str(checkpoint), "--data", str(data), "--pipeline", "synthetic",
                                        "--out", str(single), "--speed-images", "0",
                                        "--protocol", protocol]).exit_code == 0
        plain = json.loads(single.read_text())["metrics"]
        columns = TABLE_COLUMNS[:-1]
        assert {key: plain[key] for key in columns} == {key: seen["metrics"][protocol][key] for key in columns}
    bad = CliRunner().invoke(app, ["eval", str(checkpoint), "--data", str(data), "--test-set", "seen"])
    assert bad.exit_code != 0 and "NAME=PIPELINE" in bad.output
    for extra, message in ((["--protocol", "lab"], "leave out --pipeline"),
                           (["--test-set", "gone=nowhere"], "test set 'gone' (pipeline nowhere)")):
        bad = CliRunner().invoke(app, ["eval", str(checkpoint), "--data", str(data), "--test-set", "seen=synthetic",
                                       *extra])
        assert bad.exit_code != 0 and message in bad.output and len(bad.output.strip().splitlines()) == 1
