"""Evaluate a checkpoint on a split of a data dir: the row of Table II.

``togcrf eval CHECKPOINT --data DIR`` runs the model on every sample of the
split (batch 1), scores it with :mod:`togcrf.metrics` and measures its speed;
``togcrf table RUN_DIR...`` prints the rows of several runs side by side, as
in the paper's Table II (percentages; speed in frames per second); runs of
one model with several seeds are told apart by the seed in the run's
``config.json`` (or in the ``MODEL-config.json`` beside an evaluation
committed as ``MODEL-eval.json``), and ``--mean`` prints each model's mean over its runs with
the sample standard deviation beneath.

An evaluation JSON (``eval.json`` next to the checkpoint unless ``--out``
says otherwise) holds ``model``, ``seed`` (the training seed), ``checkpoint``, ``data``, ``pipeline``,
``split``, ``protocol`` (``ours`` or ``lab``, the rules of mAP and mAP-G,
see :mod:`togcrf.metrics`; a file without it predates the option and is
``ours``), ``metrics`` (fractions; see :meth:`TableTwoEvaluator.result`),
``speed`` (see :func:`togcrf.metrics.measure_speed`) and ``row`` (the Table
II numbers as printed).

Test sets: ``togcrf eval CHECKPOINT --data DIR --test-set seen=PIPELINE
--test-set novel=PIPELINE ...`` scores the test split of each named
pipeline of the data dir under both protocols in one pass per set and prints
one table (a row per set and protocol). Each set also says how many of its
test tools (the model ids its test samples show) the checkpoint never saw in
training (``data.models`` of the checkpoint, the tools of its training
samples). Its JSON (``eval-sets.json`` by the checkpoint unless ``--out``)
holds ``model``, ``seed``, ``checkpoint``, ``data``, ``speed`` and ``test_sets``: for each name,
``pipeline``, ``images``, ``tools``, ``novel_tools`` (None for a checkpoint
that does not record its training tools), and ``metrics`` and ``row`` per
protocol.
"""

from __future__ import annotations

import json
import logging
import math
import shlex
import sys
from collections.abc import Iterable, Iterator, Sequence
from itertools import islice
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import torch
import typer

from osgd.contract.samples import iter_samples, sample_shards, samples_vocabulary
from togcrf.checkpoint import check_vocabulary, load_checkpoint
from togcrf.engine import evaluate_model, resolve_device
from togcrf.metrics import PROTOCOLS
from togcrf.model import PAPER_NAMES
from togcrf.tta import check_view_count, views_label

log = logging.getLogger(__name__)

#: Column names of Table II, in the paper's order.
TABLE_COLUMNS = ("mAP", "mAP-G", "Acc-T top1", "Acc-T top5", "Acc-T top10", "fps")

#: Name of the evaluation file a run dir holds.
EVAL_FILE = "eval.json"

#: Name of the file of an evaluation on several test sets.
TEST_SETS_FILE = "eval-sets.json"


def table_row(result: dict[str, Any]) -> dict[str, float | None]:
    """The Table II numbers of an evaluation: metrics in percent, speed in fps (None if missing)."""
    metrics = result.get("metrics", {})
    row: dict[str, float | None] = {}
    for column in TABLE_COLUMNS[:-1]:
        value = metrics.get(column)
        row[column] = None if value is None or (isinstance(value, float) and math.isnan(value)) else 100 * value
    speed = result.get("speed") or {}
    row["fps"] = speed.get("fps")
    return row


def _json_safe(value: Any) -> Any:
    """NaN and infinity as null, numpy scalars as Python numbers: strict JSON."""
    if isinstance(value, dict):
        return {str(key): _json_safe(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(item) for item in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def command_line() -> str:
    """The command this process runs, as a shell line (``togcrf ...``), for the JSON it writes."""
    return shlex.join(["togcrf", *sys.argv[1:]])


def write_json(path: Path, document: dict[str, Any]) -> None:
    """Write strict JSON (no NaN), creating the parent folder."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_json_safe(document), indent=2, allow_nan=False) + "\n")


def evaluate_checkpoint(
    checkpoint: Path,
    data_dir: Path,
    *,
    pipeline: str | None = None,
    split: str = "test",
    device: str = "cpu",
    max_samples: int | None = None,
    speed_images: int = 10,
    unmatched_task: str = "nearest",
    protocol: str = "ours",
    views: int = 1,
) -> dict[str, Any]:
    """Load a checkpoint and evaluate it on a split of a data dir (``views``: :func:`evaluate_model`).

    Returns
    -------
    dict
        The evaluation document (see the module docstring).

    Raises
    ------
    FileNotFoundError
        If the checkpoint or the data do not exist.
    ValueError
        If the split has no samples, or the protocol is unknown.
    """

    if protocol not in PROTOCOLS:
        raise ValueError(f"unknown protocol {protocol!r}: expected one of {', '.join(PROTOCOLS)}")
    check_view_count(views)
    checkpoint = Path(checkpoint)
    if not checkpoint.is_file():
        raise FileNotFoundError(f"{checkpoint}: no such checkpoint")
    model, config = load_checkpoint(checkpoint, device=device)
    shards = sample_shards(data_dir, pipeline)
    check_vocabulary(config["vocabulary"], samples_vocabulary(shards), str(checkpoint), f"{data_dir}/samples")
    samples = iter_samples(data_dir, split=split, shards=shards)
    if max_samples is not None:
        samples = islice(samples, max_samples)
    try:
        result = evaluate_model(model, samples, config.get("image_size"), device=device,
                                speed_images=speed_images, unmatched_task=unmatched_task, protocol=protocol,
                                depth_reference=config["depth_reference"], views=views)
    except ValueError as error:
        raise ValueError(f"{data_dir}: split {split!r}: {error}") from error
    result = {
        "model": config.get("model", "unknown"),
        "seed": config.get("seed"),
        "checkpoint": str(checkpoint),
        "data": str(data_dir),
        "pipeline": pipeline,
        "split": split,
        "unmatched_task": unmatched_task,
        "protocol": protocol,
        "test_time_views": views,
        "torch_threads": torch.get_num_threads(),
        **result,
    }
    result["row"] = table_row(result)
    return result


def parse_test_sets(items: Sequence[str]) -> dict[str, str]:
    """``NAME=PIPELINE`` items (``--test-set``) as a name -> pipeline mapping, in the order given."""
    sets: dict[str, str] = {}
    for item in items:
        name, separator, pipeline = item.partition("=")
        if not separator or not name.strip() or not pipeline.strip():
            raise ValueError(f"--test-set {item!r}: expected NAME=PIPELINE, e.g. novel=recipe-novel")
        if name.strip() in sets:
            raise ValueError(f"--test-set {item!r}: the name {name.strip()!r} is given twice")
        sets[name.strip()] = pipeline.strip()
    return sets


def check_test_sets(data_dir: Path, test_sets: dict[str, str], vocabulary: dict[str, Any]) -> dict[str, list]:
    """Each test set's samples shards; fails now, naming the set, when its pipeline has none or another
    vocabulary."""
    shards_of: dict[str, list] = {}
    for name, pipeline in test_sets.items():
        try:
            shards_of[name] = sample_shards(data_dir, pipeline)
            check_vocabulary(vocabulary, samples_vocabulary(shards_of[name]), "the models", f"{data_dir}/samples")
        except (FileNotFoundError, ValueError) as error:
            raise ValueError(f"test set {name!r} (pipeline {pipeline}): {error}") from error
    return shards_of


def _recording_tools(samples: Iterable[Any], tools: set[str]) -> Iterator[Any]:
    """The samples, adding the model ids of each one's annotated objects to ``tools`` as it passes."""
    for sample in samples:
        tools.update(sample.model_ids)
        yield sample


def evaluate_test_sets(
    checkpoint: Path,
    data_dir: Path,
    test_sets: dict[str, str],
    *,
    device: str = "cpu",
    max_samples: int | None = None,
    speed_images: int = 10,
    unmatched_task: str = "nearest",
    views: int = 1,
) -> dict[str, Any]:
    """Table II of a checkpoint on the test split of each named pipeline, under every protocol.

    The speed is measured once, on the first set.

    Returns
    -------
    dict
        The document of the module docstring ("Test sets").

    Raises
    ------
    FileNotFoundError, ValueError
        As :func:`evaluate_checkpoint`, naming the set.
    """
    check_view_count(views)
    if not Path(checkpoint).is_file():
        raise FileNotFoundError(f"{checkpoint}: no such checkpoint")
    model, config = load_checkpoint(checkpoint, device=device)
    trained = (config.get("data") or {}).get("models")
    sets: dict[str, Any] = {}
    speed = None
    shards_of = check_test_sets(data_dir, test_sets, config["vocabulary"])
    for name, pipeline in test_sets.items():
        tools: set[str] = set()
        samples = iter_samples(data_dir, split="test", shards=shards_of[name])
        samples = _recording_tools(samples if max_samples is None else islice(samples, max_samples), tools)
        try:
            result = evaluate_model(model, samples,
                                    config.get("image_size"), device=device,
                                    speed_images=speed_images if speed is None else 0, unmatched_task=unmatched_task,
                                    depth_reference=config["depth_reference"], views=views, protocols=PROTOCOLS)
        except ValueError as error:
            raise ValueError(f"test set {name!r} ({data_dir}, pipeline {pipeline}): {error}") from error
        speed = speed or result["speed"]
        by_protocol = result["metrics_by_protocol"]
        sets[name] = {"pipeline": pipeline, "images": by_protocol[PROTOCOLS[0]]["images"], "tools": len(tools),
                      "novel_tools": None if trained is None else len(tools - set(trained)),
                      "metrics": by_protocol,
                      "row": {protocol: table_row({"metrics": metrics, "speed": speed})
                              for protocol, metrics in by_protocol.items()}}
    return {"model": config.get("model", "unknown"), "seed": config.get("seed"), "checkpoint": str(checkpoint),
            "data": str(data_dir), "unmatched_task": unmatched_task, "test_time_views": views,
            "torch_threads": torch.get_num_threads(), "speed": speed, "test_sets": sets}


def format_test_sets(documents: Sequence[tuple[str, dict[str, Any]]]) -> str:
    """One table of :func:`evaluate_test_sets` documents: a row per (run, set, protocol), then each set's tools.

    Parameters
    ----------
    documents : sequence of (str, dict)
        A name for each run ("" for one run) and its document.
    """
    rows = [(f"{run + ' / ' if run else ''}{name} [{protocol}]", row)
            for run, document in documents for name, entry in document["test_sets"].items()
            for protocol, row in entry["row"].items()]
    lines = [format_table(rows, title="Test set [protocol]")]
    for run, document in documents:
        for name, entry in document["test_sets"].items():
            novel = "not recorded by the checkpoint" if entry["novel_tools"] is None else \
                f"{entry['novel_tools']} never in training"
            lines.append(f"{run + ' / ' if run else ''}{name}: pipeline {entry['pipeline']}, {entry['images']} "
                         f"test images, {entry['tools']} tools ({novel})")
    return "\n".join(lines)


def format_table(rows: Sequence[tuple[str, dict[str, float | None]]], protocol: str | None = None,
                 title: str = "Algorithm") -> str:
    """Table II as fixed-width text: one line per (name, row).

    Parameters
    ----------
    rows : sequence of (str, dict)
        Name and :func:`table_row` of each line.
    protocol : str, optional
        Named in the header (``Algorithm [protocol: lab]``) when given.
    title : str
        The header of the name column.

    Returns
    -------
    str
    """
    title = title if protocol is None else f"{title} [protocol: {protocol}]"
    name_width = max([len(title), *(len(name) for name, _ in rows)])
    header = title.ljust(name_width) + "".join(f"{column:>13}" for column in TABLE_COLUMNS)
    lines = [header, "-" * len(header)]
    for name, row in rows:
        cells = "".join(f"{'-':>13}" if row.get(column) is None else f"{row[column]:>13.1f}"
                        for column in TABLE_COLUMNS)
        lines.append(name.ljust(name_width) + cells)
    return "\n".join(lines)


def run_seed(path: Path) -> int | None:
    """The training seed of an evaluation: ``seed`` of the run's config beside it (None if there is none).

    The config is ``config.json`` in the run dir, or, for an evaluation committed as ``MODEL-eval.json``
    or ``MODEL-eval-lab.json`` (as the model zoo in docs/zoo/ keeps them), ``MODEL-config.json`` beside it.

    Parameters
    ----------
    path : Path
        A run dir, or an evaluation JSON inside one (``eval.json``, ``eval-lab.json``) or beside its config.
    """
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    committed = not path.is_dir() and "-eval" in path.name
    own = [folder / f"{path.name.rsplit('-eval', 1)[0]}-config.json"] if committed else []
    for config in [*own, folder / "config.json"]:
        try:
            seed = json.loads(config.read_text()).get("seed")
        except (OSError, json.JSONDecodeError):
            continue
        return seed if isinstance(seed, int) else None
    return None


def evaluation_seed(path: Path, document: dict[str, Any]) -> int | None:
    """The training seed of an evaluation: its own ``seed``, else :func:`run_seed` of its path, else ``seed`` of the
    ``config.json`` in its checkpoint's run dir (None if none of them says)."""
    seed = document.get("seed")
    if isinstance(seed, int):
        return seed
    seed = run_seed(path)
    if seed is None and document.get("checkpoint"):
        seed = run_seed(Path(document["checkpoint"]).parent)
    return seed


def named_rows(models: Sequence[str], rows: Sequence[dict[str, float | None]], seeds: Sequence[int | None],
               protocols: Sequence[str], mixed: bool) -> list[tuple[str, dict[str, float | None]]]:
    """One (name, row) per evaluation, for :func:`format_table`.

    Parameters
    ----------
    models : sequence of str
        Each evaluation's model, as the paper names it (:func:`row_name`).
    rows : sequence of dict
        Each one's :func:`table_row`.
    seeds : sequence of int or None
        Each one's training seed (:func:`run_seed`).
    protocols : sequence of str
        Each one's protocol.
    mixed : bool
        Mark each row with its protocol (``TOG [lab]``).

    Returns
    -------
    list of (str, dict)
        The model's name, with ``[seed S]`` where the model (of one protocol) appears more than once,
        or ``[run N]`` (its place among them) where the seeds do not tell those runs apart.
    """
    keys = [(model, protocol if mixed else "") for model, protocol in zip(models, protocols, strict=True)]
    keyed_seeds = list(zip(keys, seeds, strict=True))
    named = []
    for index, (key, row, seed) in enumerate(zip(keys, rows, seeds, strict=True)):
        name = key[0]
        if keys.count(key) > 1:
            distinct = seed is not None and keyed_seeds.count((key, seed)) == 1
            name += f" [seed {seed}]" if distinct else f" [run {keys[:index + 1].count(key)}]"
        if mixed:
            name += f" [{key[1]}]"
        named.append((name, row))
    return named


def mean_rows(models: Sequence[str], rows: Sequence[dict[str, float | None]], seeds: Sequence[int | None],
              sources: Sequence[str]) -> list[dict[str, Any]]:
    """Each model's mean and sample standard deviation over its runs, in the order models first appear.

    Parameters
    ----------
    models : sequence of str
        The model each row belongs to (rows of one model are averaged).
    rows : sequence of dict
        The :func:`table_row` of each run.
    seeds, sources : sequences
        Each row's seed and where its evaluation was read, listed with its model's mean.

    Returns
    -------
    list of dict
        ``name``, ``runs`` (how many), ``mean`` and ``sd`` (column -> value; None where no run has the
        column, sd None for a single run), ``seeds`` and ``sources``.
    """
    members: dict[str, list[int]] = {}
    for index, model in enumerate(models):
        members.setdefault(model, []).append(index)
    summaries = []
    for model, indices in members.items():
        mean: dict[str, float | None] = {}
        sd: dict[str, float | None] = {}
        for column in TABLE_COLUMNS:
            values = [rows[index][column] for index in indices if rows[index].get(column) is not None]
            mean[column] = float(np.mean(values)) if values else None
            sd[column] = float(np.std(values, ddof=1)) if len(values) > 1 else None
        summaries.append({"name": model, "runs": len(indices), "mean": mean, "sd": sd,
                          "seeds": [seeds[index] for index in indices],
                          "sources": [sources[index] for index in indices]})
    return summaries


def format_mean_table(summaries: Sequence[dict[str, Any]], protocol: str | None = None) -> str:
    """:func:`mean_rows` as text: each model's mean, then its standard deviation on a line beneath."""
    lines = []
    for summary in summaries:
        lines.append((f"{summary['name']} (mean of {summary['runs']})", summary["mean"]))
        lines.append(("  sd", summary["sd"]))
    return format_table(lines, protocol=protocol)


def read_evaluation(path: Path) -> dict[str, Any]:
    """An evaluation JSON, from its path or from the run dir that holds ``eval.json``.

    Raises
    ------
    FileNotFoundError
        If there is no evaluation there.
    """
    path = Path(path)
    file = path / EVAL_FILE if path.is_dir() else path
    if not file.is_file():
        raise FileNotFoundError(f"{file}: no evaluation; run `togcrf eval {path}/checkpoint.pt --data DIR` first")
    try:
        return json.loads(file.read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"{file}: not an evaluation JSON ({error})") from error


def document_protocol(document: dict[str, Any]) -> str:
    """The protocol of an evaluation document; ``ours`` for one written before protocols existed."""
    return str(document.get("protocol") or document.get("metrics", {}).get("protocol") or "ours")


def row_name(document: dict[str, Any]) -> str:
    """The paper's name of an evaluated model, or its own name; with test-time views, how many."""
    model = str(document.get("model", "unknown"))
    return PAPER_NAMES.get(model, model) + views_label(document.get("test_time_views", 1))


# --------------------------------------------------------------------------- CLI


def eval_command(
    checkpoint: Annotated[Path, typer.Argument(help="A checkpoint.pt written by `togcrf train`.")],
    *,
    data: Annotated[Path, typer.Option("--data", help="Data dir holding samples shards.")],
    pipeline: Annotated[str | None, typer.Option(help="Only the samples of this pipeline's manifest.")] = None,
    split: Annotated[str, typer.Option(help="train or test.")] = "test",
    out: Annotated[Path | None, typer.Option(help=f"Evaluation JSON; default {EVAL_FILE} by the checkpoint.")] = None,
    device: Annotated[str, typer.Option(help="auto (CUDA where available), cpu or cuda.")] = "auto",
    max_samples: Annotated[int | None, typer.Option(help="Evaluate only the first N samples of the split.")] = None,
    speed_images: Annotated[int, typer.Option(help="Images timed for the speed (batch 1, after warm-up).")] = 10,
    unmatched_task: Annotated[str, typer.Option(help="Acc-T: 'nearest' or 'wrong' (togcrf.metrics).")] = "nearest",
    protocol: Annotated[str, typer.Option(help="mAP / mAP-G rules: 'ours' or 'lab' (the lab's evaluator; "
                                               "togcrf.metrics).")] = "ours",
    views: Annotated[int, typer.Option(help="Test-time views: average each detection's grasp candidates over "
                                            "1 (off), 2, 4 or 8 flipped and turned copies of the image "
                                            "(togcrf.tta); slower, and fps is measured with them.")] = 1,
    test_set: Annotated[list[str] | None, typer.Option(
        "--test-set", metavar="NAME=PIPELINE",
        help="Score the test split of this pipeline of the data dir as a named test set, under both protocols "
             f"(repeat for several: one table; written to {TEST_SETS_FILE}); replaces --pipeline, --split and "
             "--protocol.")] = None,
) -> None:
    """Evaluate a checkpoint: print its Table II row (mAP, mAP-G, Acc-T top-1/5/10, fps) and write JSON.

    With --test-set: Table II per test set (seen tools, novel tools, the authors' models...), both protocols.
    """
    if test_set:
        if pipeline is not None or split != "test" or protocol != "ours":
            raise ValueError("--test-set scores the test split of each named pipeline under both protocols; "
                             "leave out --pipeline, --split and --protocol")
        sets = parse_test_sets(test_set)
        document = evaluate_test_sets(checkpoint, data, sets, device=str(resolve_device(device)),
                                      max_samples=max_samples, speed_images=speed_images,
                                      unmatched_task=unmatched_task, views=views)
        path = out if out is not None else Path(checkpoint).parent / TEST_SETS_FILE
        write_json(path, {**document, "command": command_line()})
        typer.echo(format_test_sets([("", document)]))
        typer.echo(f"written to {path}")
        return
    document = evaluate_checkpoint(checkpoint, data, pipeline=pipeline, split=split,
                                   device=str(resolve_device(device)),
                                   max_samples=max_samples, speed_images=speed_images,
                                   unmatched_task=unmatched_task, protocol=protocol, views=views)
    path = out if out is not None else Path(checkpoint).parent / EVAL_FILE
    write_json(path, {**document, "command": command_line()})
    typer.echo(format_table([(row_name(document), document["row"])], protocol=document_protocol(document)))
    metrics = document["metrics"]
    typer.echo(f"{metrics['images']} images, {metrics['rois']} RoIs judged for Acc-T; "
               f"speed on {document['speed']['device'] if document['speed'] else '-'} "
               f"({document['torch_threads']} threads); written to {path}")


def table_command(
    run_dirs: Annotated[list[Path], typer.Argument(help=f"Run dirs holding {EVAL_FILE}, or evaluation JSONs.")],
    out: Annotated[Path | None, typer.Option(help="Also write the table as JSON here.")] = None,
    mixed: Annotated[bool, typer.Option("--mixed", help="Allow evaluations of different protocols, "
                                                        "each row marked with its own.")] = False,
    mean: Annotated[bool, typer.Option("--mean", help="One row per model: the mean over its runs (seeds), "
                                                      "with the sample standard deviation beneath.")] = False,
) -> None:
    """Print Table II for several evaluated runs side by side, headed by the protocol that made it."""
    documents = [read_evaluation(path) for path in run_dirs]
    protocols = [document_protocol(document) for document in documents]
    if len(set(protocols)) > 1 and not (mixed and not mean):
        listing = "; ".join(f"{path}: {protocol}" for path, protocol in zip(run_dirs, protocols, strict=True))
        hint = " (--mean averages one protocol)" if mean else ", or pass --mixed to print each row marked"
        typer.echo(f"error: the evaluations mix protocols ({listing}); evaluate them all with one "
                   f"`togcrf eval --protocol`{hint}", err=True)
        raise typer.Exit(1)
    protocol = protocols[0] if len(set(protocols)) == 1 else "mixed"
    models = [row_name(document) for document in documents]
    values = [document.get("row") or table_row(document) for document in documents]
    seeds = [evaluation_seed(path, document) for path, document in zip(run_dirs, documents, strict=True)]
    rows = named_rows(models, values, seeds, protocols, mixed=protocol == "mixed")
    table: dict[str, Any] = {"columns": list(TABLE_COLUMNS), "protocol": protocol}
    if mean:
        summaries = mean_rows(models, values, seeds, [str(path) for path in run_dirs])
        typer.echo(format_mean_table(summaries, protocol=protocol))
        table["means"] = summaries
    else:
        typer.echo(format_table(rows, protocol=protocol))
    table["rows"] = [{"name": name, "source": str(path), "protocol": row_protocol, "seed": seed, **row}
                     for (name, row), path, row_protocol, seed in zip(rows, run_dirs, protocols, seeds, strict=True)]
    if out is not None:
        write_json(out, table)


def register(app: typer.Typer) -> None:
    """Add ``eval`` and ``table`` to the ``togcrf`` command line."""
    app.command("eval")(eval_command)
    app.command("table")(table_command)
