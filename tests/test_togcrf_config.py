"""One definition of each training setting: the config type, its presets, the options derived from it, the
checkpoints of earlier code, one-line errors, and an import graph without circles."""

from __future__ import annotations

import ast
import json
import re
from dataclasses import fields
from pathlib import Path

import pytest
import torch
from helpers import write_synthetic_samples
from typer.testing import CliRunner

from osgd.store import ShardStore
from togcrf.checkpoint import load_checkpoint
from togcrf.cli import app
from togcrf.config import CPU, PRESETS, TrainConfig, config_from_command, option_name, preset
from togcrf.model import model_options, options_dict, stored_options
from togcrf.model.options import FLAT_NAMES, REMOVED_FLAT_OPTIONS

ROOT = Path(__file__).resolve().parents[1]
TRACES = Path(__file__).resolve().parent / "traces"

#: A small model that keeps CPU runs quick.
SMALL = {"grasp_head.channels": 32, "box_head.size": 128, "box_head.batch_per_image": 64, "rpn.pre_nms_train": 200,
         "rpn.post_nms_train": 100, "rpn.pre_nms_test": 100, "rpn.post_nms_test": 50,
         "grasp_head.rois_per_image": 4, "box_head.detections_per_image": 10}


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("config")
    write_synthetic_samples(ShardStore(root), 12, seed=11)
    return root


def _invoke(*arguments: str):
    return CliRunner().invoke(app, list(arguments))


def test_every_training_option_is_an_option_of_both_commands():
    train_help = _invoke("train", "--help").output
    reproduce_help = _invoke("reproduce", "--help").output
    for spec in fields(TrainConfig):
        assert spec.name == "eval_max_samples" or f"--{option_name(spec.name)}" in train_help, spec.name
        assert spec.metadata["help"].split()[0] in train_help + reproduce_help, spec.name
        per_model = spec.name in ("data", "out", "pipeline", "model", "device", "seed", "resume", "init",
                                  "train_only", "split")
        assert per_model or f"--{option_name(spec.name)}" in reproduce_help, spec.name
    assert "--preset" in train_help and "--scale" in reproduce_help
    # an option left out takes the preset's value (or the field's default without a preset)
    assert config_from_command(TrainConfig(), {}) == TrainConfig()
    assert config_from_command(CPU, {"epochs": None, "lr_decay_epochs": []}) == CPU


def test_a_preset_is_a_complete_config_and_the_options_given_override_it(data_dir, tmp_path):
    assert set(PRESETS) == {"paper", "gpu", "cpu", "small"}
    for name, config in PRESETS.items():
        config.validate()
        assert preset(name) == config and preset(name) is not config
    out = tmp_path / "run"
    result = _invoke("train", "--preset", "cpu", "--data", str(data_dir), "--pipeline", "synthetic", "--out", str(out),
                     "--model", "tog", "--epochs", "1", "--batch-size", "2", "--max-samples", "2", "--image-size",
                     "64", "--time-budget", "0", "--val-samples", "0", "--device", "cpu", "--no-cpu-bf16",
                     "--option", "grasp_head.channels=16", "--option", "box_head.size=64")
    assert result.exit_code == 0, result.output
    stored = json.loads((out / "config.json").read_text())
    # the options given ...
    assert (stored["epochs"], stored["batch_size"], stored["image_size"], stored["time_budget_minutes"]) == (
        1, 2, 64, None)
    assert stored["model_options"]["grasp_head"]["channels"] == 16 and stored["cpu_bf16"] is False
    # ... over the preset's, which the run keeps where nothing was given
    assert (stored["optimizer"], stored["lr_schedule"], stored["warmup_steps"]) == ("adamw", "cosine", 200)
    assert stored["model_options"]["rpn"]["anchor_sizes"] == [27, 53, 107]
    assert stored["model_options"]["backbone"] == options_dict(CPU.model_options)["backbone"]
    # the resolved config is the checkpoint's
    _, checkpoint_config = load_checkpoint(out / "checkpoint.pt")
    assert checkpoint_config["model_options"] == stored["model_options"]


def test_model_options_come_nested_or_dotted_and_unknown_names_are_refused():
    nested = model_options({"rpn": {"anchor_sizes": [27, 53, 107]}, "loss": {"ranking_weight": 0.2}})
    dotted = model_options({"rpn.anchor_sizes": [27, 53, 107], "loss.ranking_weight": 0.2})
    assert nested == dotted and nested.rpn.anchor_sizes == (27, 53, 107)
    assert model_options(options_dict(nested)) == nested
    with pytest.raises(ValueError, match=r"unknown model option rpn\.anchors; known: backbone\.norm"):
        model_options({"rpn.anchors": [1]})
    assert model_options({"crf.bandwidth": 1}).crf.bandwidth == 1.0  # a whole number where a number is asked
    for values, message in (({"box_head.size": 1.5}, "box_head.size=1.5: expected a whole number"),
                            ({"backbone.fpn_norm": "False"}, "backbone.fpn_norm='False': expected true or false"),
                            ({"rpn.anchor_sizes": "abc"}, "rpn.anchor_sizes='abc': expected a list of whole numbers"),
                            ({"grasp_head.channels": [1]}, "grasp_head.channels=[1]: expected a whole number")):
        with pytest.raises(ValueError, match=re.escape(message)):
            model_options(values)


def test_the_stored_options_of_the_code_before_the_groups_migrate():
    """The config.json of a checkpoint written before the options were grouped (recorded at d9d70b4)."""
    old = json.loads((TRACES / "tog-crfs-config-d9d70b4.json").read_text())["model_options"]
    migrated = stored_options(old)
    assert migrated.backbone.fpn_channels == old["fpn_channels"] == 32
    assert migrated.rpn.anchor_sizes == tuple(old["rpn_anchor_sizes"])
    assert migrated.loss.ranking_weight == old["grasp_ranking_weight"] == 0.2
    assert migrated.grasp_head.rois_per_image == old["grasp_rois_per_image"]
    # every stored value lands somewhere, and every removed option held its neutral value
    assert set(old) == set(FLAT_NAMES) - {name for name in FLAT_NAMES if name.startswith("fcgn_")} | set(
        REMOVED_FLAT_OPTIONS)
    fcgn = json.loads((TRACES / "fcgn-task-config-d9d70b4.json").read_text())["model_options"]
    assert stored_options(fcgn).fcgn.channels == fcgn["fcgn_channels"] == 32
    with pytest.raises(ValueError, match=r"grasp_object_map=True.*evaluate it at the commit that trained it"):
        stored_options({**old, "grasp_object_map": True})
    # an option that changed only the training targets: the model loads, its training cannot go on
    trained_otherwise = {**old, "grasp_regression_radius": 1.0}
    assert stored_options(trained_otherwise) == migrated
    with pytest.raises(ValueError, match=r"trained with .*grasp_regression_radius=1\.0.*train it at the commit"):
        stored_options(trained_otherwise, training=True)


def test_a_checkpoint_with_flat_options_loads_and_predicts_the_same(data_dir, tmp_path):
    result = _invoke("train", "--data", str(data_dir), "--pipeline", "synthetic", "--out", str(tmp_path / "run"),
                     "--model", "tog", "--backbone", "resnet18", "--epochs", "1", "--max-samples", "2",
                     "--image-size", "64", "--device", "cpu", *[item for name, value in SMALL.items()
                                                                for item in ("--option", f"{name}={value}")])
    assert result.exit_code == 0, result.output
    path = tmp_path / "run" / "checkpoint.pt"
    checkpoint = torch.load(path, weights_only=True)
    flat_names = {dotted: flat for flat, dotted in FLAT_NAMES.items()}
    grouped = checkpoint["config"]["model_options"]
    checkpoint["config"]["model_options"] = {
        **REMOVED_FLAT_OPTIONS, **{flat_names[f"{group}.{name}"]: value for group, values in grouped.items()
                                   for name, value in values.items() if not group == "fcgn"}}
    torch.save(checkpoint, tmp_path / "flat.pt")
    model, _ = load_checkpoint(path)
    flat_model, _ = load_checkpoint(tmp_path / "flat.pt")
    assert flat_model.options == model.options
    image = torch.rand(1, 64, 64)
    torch.manual_seed(0)
    with torch.inference_mode():
        expected, got = model([image])[0], flat_model([image])[0]
    assert all(torch.equal(expected[key], got[key]) for key in expected)
    checkpoint["config"]["model_options"]["grasp_grid"] = 14
    torch.save(checkpoint, tmp_path / "removed.pt")
    refused = _invoke("eval", str(tmp_path / "removed.pt"), "--data", str(data_dir), "--pipeline", "synthetic")
    assert refused.exit_code == 1 and refused.output.count("\n") == 1, refused.output
    assert "removed.pt: cannot build its model" in refused.output and "grasp_grid=14" in refused.output


@pytest.mark.parametrize(("arguments", "message"), [
    (("--option", "nosuch=1"), "unknown model option nosuch"),
    (("--option", "novalue"), "--option 'novalue': expected GROUP.NAME=VALUE"),
    (("--epochs", "0"), "--epochs 0: expected 1 or more"),
    (("--optimizer", "adam"), "--optimizer 'adam': expected one of sgd, adamw"),
    (("--resume",), "--resume: "),
])
def test_a_bad_training_option_is_one_line(data_dir, tmp_path, arguments, message):
    out = tmp_path / "run"
    result = _invoke("train", "--data", str(data_dir), "--out", str(out), *arguments)
    assert result.exit_code == 1 and message in result.output and result.output.count("\n") == 1, result.output
    assert not (out / "train.log").exists()  # nothing is written for a run that cannot start


def test_a_file_as_run_dir_and_a_foreign_checkpoint_are_one_line_and_debug_shows_the_traceback(data_dir, tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("x")
    result = _invoke("train", "--data", str(data_dir), "--out", str(afile), "--epochs", "1")
    assert result.exit_code == 1 and "--out" in result.output and "is a file" in result.output, result.output
    foreign = tmp_path / "foreign.pt"
    torch.save({"model": torch.nn.Linear(2, 2)}, foreign)  # a pickled module: weights_only refuses its code
    result = _invoke("eval", str(foreign), "--data", str(data_dir))
    assert result.exit_code == 1 and result.output.startswith(f"error: {foreign}: not a readable togcrf checkpoint")
    assert result.output.count("\n") == 1, result.output
    debug = CliRunner().invoke(app, ["--debug", "eval", str(foreign), "--data", str(data_dir)])
    assert debug.exit_code == 1 and isinstance(debug.exception, ValueError)


def _module_imports(path: Path) -> tuple[set[str], list[tuple[int, str]]]:
    """The togcrf modules a file imports at module level, and its function-level imports (line, source)."""
    tree = ast.parse(path.read_text())
    top = set()
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("togcrf"):
            top.add(node.module)
        elif isinstance(node, ast.Import):
            top |= {alias.name for alias in node.names if alias.name.startswith("togcrf")}
    lines = path.read_text().splitlines()
    lazy = [(node.lineno, lines[node.lineno - 1]) for function in ast.walk(tree)
            if isinstance(function, ast.FunctionDef | ast.AsyncFunctionDef)
            for node in ast.walk(function) if isinstance(node, ast.Import | ast.ImportFrom)]
    return top, lazy


def test_the_detector_has_no_import_circle_and_lazy_imports_only_for_optional_dependencies():
    modules = {}
    lazy_without_reason = []
    for path in sorted((ROOT / "togcrf").rglob("*.py")):
        name = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
        imports, lazy = _module_imports(path)
        modules[name] = {module for module in imports if module != name}
        lazy_without_reason += [f"{path.relative_to(ROOT)}:{line}: {text.strip()}" for line, text in lazy
                                if "optional dependency" not in text]
    assert not lazy_without_reason, "\n".join(lazy_without_reason)
    visiting, done = [], set()

    def visit(module: str) -> None:
        if module in done:
            return
        assert module not in visiting, "import circle: " + " -> ".join([*visiting[visiting.index(module):], module])
        visiting.append(module)
        for imported in modules.get(module, ()):
            visit(imported)
        visiting.pop()
        done.add(module)

    for module in modules:
        visit(module)
