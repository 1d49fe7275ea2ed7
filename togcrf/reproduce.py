"""Reproduce Table II: train and evaluate the five models on one data dir.

``togcrf reproduce --data DIR --out runs/table2`` (``make table``) trains FCGN + Task, TOG, TOG-CRFs omega,
TOG-CRFs mu and TOG-CRFs with the same options, evaluates each on the test split, and writes:

- ``OUT/<model>/`` the run dir of each model (checkpoint.pt, metrics.csv, config.json, train.log,
  eval.json and eval-lab.json: the evaluation under our protocol and the lab's, ``togcrf.metrics``);
- ``OUT/table2.txt`` and ``OUT/table2.json``: the table (our protocol); ``OUT/table2-lab.txt`` and
  ``OUT/table2-lab.json``: the lab's;
- with ``--test-set NAME=PIPELINE`` (repeatable): ``OUT/<model>/eval-sets.json`` and ``OUT/table2-sets.txt`` /
  ``.json``: every model on the test split of each named pipeline of the data dir (seen tools, novel tools,
  the authors' models), both protocols, one table (``togcrf.evaluate``, "Test sets");
- ``OUT/figures/``: figure 5 (omega and mu of TOG-CRFs);
- ``OUT/prediction.png``: a figure-7-like picture of TOG-CRFs on the first test sample.

``--scale`` names the preset of ``togcrf.config.PRESETS`` every model trains with (``auto``, the default,
takes ``paper`` where CUDA is available and ``cpu`` otherwise); every option given explicitly overrides
it. A model whose run dir already holds a complete checkpoint is not trained again (interrupted runs
resume), so re-running only re-evaluates. Several seeds: run once per ``--seed`` into separate folders
and put the rows side by side with ``togcrf table``.
"""

from __future__ import annotations

import inspect
import logging
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any

import torch
import typer

from osgd.contract.samples import iter_samples, sample_shards, samples_vocabulary
from togcrf.checkpoint import load_checkpoint, read_checkpoint
from togcrf.config import TrainConfig, command_parameters, config_from_command, preset
from togcrf.engine import resolve_device
from togcrf.evaluate import (
    EVAL_FILE,
    TEST_SETS_FILE,
    check_test_sets,
    command_line,
    evaluate_checkpoint,
    evaluate_test_sets,
    format_table,
    format_test_sets,
    parse_test_sets,
    row_name,
    write_json,
)
from togcrf.figures import crf_matrices, draw_crf_figures
from togcrf.metrics import PROTOCOLS
from togcrf.model import MODEL_NAMES
from togcrf.predict import draw_prediction, keep_confident, predict_depth
from togcrf.train import ProgressReport, train

log = logging.getLogger(__name__)

#: The models of Table II, in its order (the registry ``togcrf.model.MODELS``).
TABLE_MODELS = MODEL_NAMES

#: Fields of :class:`TrainConfig` that ``reproduce`` sets itself, per model, rather than take as options.
_SET_PER_MODEL = ("data", "out", "pipeline", "model", "device", "seed", "resume", "init", "train_only", "split")


def resolve_scale(name: str) -> TrainConfig:
    """The preset named ``paper``, ``gpu``, ``cpu``, ``small`` or ``auto`` (paper with CUDA, else cpu)."""
    return preset(name, torch.cuda.is_available())


def model_config(scale: TrainConfig, data_dir: Path, run_dir: Path, model: str, *, pipeline: str | None,
                 device: str, seed: int, resume: bool) -> TrainConfig:
    """The training config of one model of the table at a scale."""
    return replace(scale, data=str(data_dir), out=str(run_dir), pipeline=pipeline, model=model, device=device,
                   seed=seed, resume=resume)


def _trained_epochs(checkpoint: Path) -> int:
    """Epochs a checkpoint holds (it stores the index of its last, from 0)."""
    if not checkpoint.is_file():
        return 0
    last = read_checkpoint(checkpoint).get("epoch")
    return 0 if last is None else int(last) + 1


def reproduce(
    data_dir: Path,
    out_dir: Path,
    scale: TrainConfig,
    *,
    pipeline: str | None = None,
    models: tuple[str, ...] = TABLE_MODELS,
    device: str = "auto",
    seed: int = 0,
    speed_images: int = 10,
    progress: Callable[[Path, TrainConfig], Callable[[Any], None] | None] | None = None,
    test_sets: dict[str, str] | None = None,
) -> dict[str, Any]:
    """Train and evaluate the models; write the table, figure 5 and a prediction picture.

    ``progress(run_dir, scale)``, when given, makes the progress callback of
    each model's training (``togcrf.train.Progress`` events); ``test_sets``
    (name -> pipeline) adds the table per test set.

    Returns
    -------
    dict
        ``rows``: list of (name, Table II row); ``table``: the text.
    """
    eval_device = str(resolve_device(device))
    if test_sets:  # before an hour of training, not after
        check_test_sets(data_dir, test_sets, samples_vocabulary(sample_shards(data_dir, pipeline)))
    rows: dict[str, list] = {protocol: [] for protocol in PROTOCOLS}
    set_documents: list[tuple[str, dict[str, Any]]] = []
    for model in models:
        run_dir = out_dir / model
        checkpoint = run_dir / "checkpoint.pt"
        done = _trained_epochs(checkpoint)
        if done < scale.epochs:
            log.info("training %s (%d of %d epochs done)", model, done, scale.epochs)
            report = progress(run_dir, scale) if progress is not None else None
            try:
                train(model_config(scale, data_dir, run_dir, model, pipeline=pipeline, device=device, seed=seed,
                                   resume=done > 0), report)
            finally:
                if report is not None:
                    report.close()
        for protocol in PROTOCOLS:
            document = evaluate_checkpoint(checkpoint, data_dir, pipeline=pipeline, split="test",
                                           device=eval_device, max_samples=scale.eval_max_samples,
                                           speed_images=speed_images, protocol=protocol)
            write_json(run_dir / eval_file(protocol), {**document, "command": command_line()})
            rows[protocol].append((row_name(document), document["row"]))
            log.info("%s, protocol %s: %s", model, protocol, document["row"])
        if test_sets:
            document = evaluate_test_sets(checkpoint, data_dir, test_sets, device=eval_device,
                                          max_samples=scale.eval_max_samples, speed_images=speed_images)
            write_json(run_dir / TEST_SETS_FILE, {**document, "command": command_line()})
            set_documents.append((row_name(document), document))
    for protocol, protocol_rows in rows.items():
        suffix = "" if protocol == "ours" else f"-{protocol}"
        (out_dir / f"table2{suffix}.txt").write_text(format_table(protocol_rows, protocol) + "\n")
        write_json(out_dir / f"table2{suffix}.json", {
            "command": command_line(), "data": str(data_dir), "pipeline": pipeline, "device": eval_device,
            "protocol": protocol,
            "scale": {key: value for key, value in scale.as_dict().items() if key not in _SET_PER_MODEL},
            "rows": [{"name": name, **row} for name, row in protocol_rows]})
    table = format_table(rows["ours"], "ours")
    if set_documents:
        table += "\n\n" + format_test_sets(set_documents)
        (out_dir / "table2-sets.txt").write_text(format_test_sets(set_documents) + "\n")
        write_json(out_dir / "table2-sets.json", {"command": command_line(), "data": str(data_dir),
                                                  "test_sets": test_sets, "runs": dict(set_documents)})
    if "tog-crfs" in models:
        model, _ = load_checkpoint(out_dir / "tog-crfs" / "checkpoint.pt")
        draw_crf_figures(crf_matrices(model), out_dir / "figures", model.vocabulary["tasks"])
        _draw_first_test_sample(out_dir / "tog-crfs" / "checkpoint.pt", data_dir, pipeline, out_dir / "prediction.png")
    return {"rows": rows["ours"], "table": table}


def eval_file(protocol: str) -> str:
    """The evaluation file of a run dir under a protocol: ``eval.json`` (ours) or ``eval-lab.json``."""
    return EVAL_FILE if protocol == "ours" else f"eval-{protocol}.json"


def _draw_first_test_sample(checkpoint: Path, data_dir: Path, pipeline: str | None, path: Path) -> None:
    model, config = load_checkpoint(checkpoint)
    sample = next(iter_samples(data_dir, pipeline=pipeline, split="test"), None)
    if sample is None:
        return
    detections = keep_confident(predict_depth(model, sample.depth, config.get("image_size"),
                                                 depth_reference=config["depth_reference"]), 0.5)
    draw_prediction(sample.depth, detections, path, vocabulary=model.vocabulary)


def reproduce_command(data: Path, out: Path, pipeline: str | None = None, scale: str = "auto",
                      models: str = ",".join(TABLE_MODELS), device: str = "auto", seed: int = 0,
                      speed_images: int = 10, test_set: list[str] | None = None, **given: Any) -> None:
    """Train and evaluate the five models of Table II; print and write the table.

    ``--scale`` is the preset every model trains with (paper, gpu, cpu, small; auto: paper with CUDA, else
    cpu; ``togcrf.config``); every training option given overrides it.
    """
    chosen = config_from_command(resolve_scale(scale), given)
    chosen.validate()
    sets = parse_test_sets(test_set or [])
    selected = tuple(name.strip() for name in models.split(",") if name.strip())
    unknown = [name for name in selected if name not in TABLE_MODELS]
    if unknown or not selected:
        raise ValueError(f"--models {models!r}: expected names among {', '.join(TABLE_MODELS)}")
    result = reproduce(data, out, chosen, pipeline=pipeline, models=selected, device=device, seed=seed,
                       speed_images=speed_images, progress=lambda run_dir, size: ProgressReport(run_dir, size.epochs),
                       test_sets=sets)
    typer.echo(result["table"])
    typer.echo(f"written to {out}/table2.txt and table2.json (our protocol), table2-lab.txt and table2-lab.json "
               "(the lab's), figures/, prediction.png")


def _own_parameters() -> list[inspect.Parameter]:
    """The options of ``reproduce`` that are not training options."""
    def option(name: str, kind: Any, default: Any, *flags: str, help: str) -> inspect.Parameter:
        spec = typer.Option(*flags, help=help)
        return inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY,
                                 default=inspect.Parameter.empty if default is ... else default,
                                 annotation=Annotated[kind, spec])

    return [
        option("data", Path, ..., "--data", help="Data dir with samples shards (train and test splits)."),
        option("out", Path, ..., "--out", help="Folder for the five run dirs, the table and figures."),
        option("pipeline", str | None, None, "--pipeline", help="Use the shards of this pipeline's manifest."),
        option("scale", str, "auto", "--scale", help="Preset: auto, paper, gpu, cpu or small (togcrf.config)."),
        option("models", str, ",".join(TABLE_MODELS), "--models", help="Comma-separated subset of the five models."),
        option("device", str, "auto", "--device", help="auto, cpu or cuda."),
        option("seed", int, 0, "--seed", help="Training seed."),
        option("speed_images", int, 10, "--speed-images", help="Images timed for the speed column."),
        option("test_set", list[str] | None, None, "--test-set",
               help="NAME=PIPELINE: also a table of every model on the test split of this pipeline of the data "
                    "dir, both protocols (repeat for several; table2-sets.txt)."),
    ]


def register(app: typer.Typer) -> None:
    """Add ``reproduce`` to the ``togcrf`` command line (its training options derived from ``TrainConfig``)."""
    def command(**given: Any) -> None:
        reproduce_command(**given)

    command.__doc__ = reproduce_command.__doc__
    training = command_parameters(excluded=_SET_PER_MODEL, defaults_shown=False)
    command.__signature__ = inspect.Signature([*_own_parameters(), *training])
    command.__annotations__ = {name: item.annotation for name, item in command.__signature__.parameters.items()}
    app.command("reproduce")(command)
