"""The ``osgd`` command line.

Every stage is a command that takes ``--config PIPELINE.toml``; ``osgd run``
runs them all in order; ``osgd status`` shows what is built. Global options
come before the command: ``osgd --data-dir /scratch/osgd --workers 8 run
pipelines/default.toml``; ``osgd --executor ray --ray-address auto run ...``
runs the items on a Ray cluster (docs/scale-out.md).

What goes wrong is said in one line per problem (the file, the key or value,
what is allowed); items that fail are listed together at the end (stage,
item, file, cause) and the command exits 1. Tracebacks only with ``--debug``.
On a terminal progress is a set of live bars; elsewhere (a log file) it is a
line per stage every ``OSGD_PROGRESS_INTERVAL`` seconds (default 30).
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table
from rich.text import Text

from osgd.config import ConfigError, PipelineConfig, config_to_toml
from osgd.contract.files import is_uri
from osgd.contract.process_exit import run_then_exit
from osgd.contract.taxonomy import TABLE1, Taxonomy, TaxonomyError, read_taxonomy
from osgd.errors import describe
from osgd.executor import BACKENDS, Executor, ExecutorError, SerialExecutor, make_executor
from osgd.pipeline import (
    COMMAND_STAGES,
    STATUS_EXIT_CODES,
    MissingInputError,
    PlanError,
    load_pipeline,
    pipeline_status,
    run_stages,
    stage_by_name,
    stages,
    status_exit_code,
)
from osgd.progress import LineProgress, format_duration
from osgd.stage import ItemFailure, StageReport
from osgd.store import DataDirError, ShardStore, check_data_dir, write_problem

log = logging.getLogger(__name__)
console = Console(stderr=True)
app = typer.Typer(
    help="Build task-oriented grasping datasets of stacked objects.\n\n"
    "Data flows models -> grasps -> checks -> scenes -> samples; each stage writes "
    "content-addressed Parquet shards under the data dir, skips what is already built "
    "and resumes after an interruption.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
show_app = typer.Typer(help="Draw pictures of what a data dir holds.", no_args_is_help=True)
app.add_typer(show_app, name="show")


class _Global:
    data_dir: str = "data"
    workers: int | None = None
    debug: bool = False
    executor: str | None = None
    ray_address: str | None = None
    #: Whether this process's str hashes differ from its workers' (:func:`_seed_worker_hashes`).
    hash_seed_differs: bool = False


@app.callback()
def main(
    data_dir: Annotated[
        str, typer.Option(envvar="OSGD_DATA_DIR", help="Where shards and manifests are written: a folder, or an "
                          "object-store URI such as s3://bucket/osgd (one driver at a time; docs/scale-out.md).")
    ] = "data",
    workers: Annotated[
        int | None,
        typer.Option(min=1, help="Worker processes; default: one per core. 1 runs serially. "
                     "With --executor ray: the most items in flight (default: twice the cluster's CPUs)."),
    ] = None,
    executor: Annotated[
        str | None,
        typer.Option(envvar="OSGD_EXECUTOR", help="process (worker processes here) or ray (a Ray cluster); "
                     "default: the config's executor.backend, else process."),
    ] = None,
    ray_address: Annotated[
        str | None,
        typer.Option(help="The Ray cluster to join: auto, HOST:6379 or ray://HOST:10001; default: the config's "
                     "executor.ray_address, else RAY_ADDRESS, else a Ray instance on this machine."),
    ] = None,
    log_level: Annotated[
        str, typer.Option(help="debug, info, warning or error.", case_sensitive=False)
    ] = "warning",
    debug: Annotated[bool, typer.Option("--debug", help="Show the traceback of every error.")] = False,
) -> None:
    level = getattr(logging, log_level.upper(), None)
    if not isinstance(level, int):
        raise typer.BadParameter(f"unknown log level {log_level!r}; use debug, info, warning or error")
    if executor is not None and executor not in BACKENDS:
        raise typer.BadParameter(f"unknown executor {executor!r}; use {' or '.join(BACKENDS)}")
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    _Global.data_dir = data_dir
    _Global.workers = workers
    _Global.debug = debug
    _Global.executor = executor
    _Global.ray_address = ray_address


ConfigOption = Annotated[
    Path, typer.Option("--config", "-c", help="Pipeline config (TOML), e.g. pipelines/default.toml.")
]
SetOption = Annotated[
    list[str] | None,
    typer.Option("--set", "-s", help="Override a config value: section.key=value (repeatable)."),
]
ForceOption = Annotated[bool, typer.Option("--force", help="Rebuild shards even when they are done.")]


def _say(text: str, style: str | None = None) -> None:
    """Print text as it is: no markup (``[scenes]`` stays), no wrapping (one problem, one line)."""
    console.print(text, markup=False, highlight=False, soft_wrap=True, style=style)


def _fail(message: str) -> None:
    console.print(Text.assemble(("error: ", "red"), message), highlight=False, soft_wrap=True)
    raise typer.Exit(2)


def _load(config_path: Path, overrides: list[str] | None) -> PipelineConfig:
    try:
        return load_pipeline(config_path, overrides or [])
    except ConfigError as error:
        _fail(str(error))
        raise  # unreachable: _fail exits


def _store(writable: bool, absolute: bool = False) -> ShardStore:
    """The data dir's store, after checking it is a folder (and writable, when asked).

    ``absolute``: the store names the folder by its absolute path, as the
    workers of a Ray cluster, started elsewhere, must.
    """
    try:
        check_data_dir(_Global.data_dir, writable)
    except DataDirError as error:
        _fail(str(error))
    if is_uri(_Global.data_dir):
        return ShardStore(_Global.data_dir)
    return ShardStore(Path(_Global.data_dir).absolute() if absolute else _Global.data_dir)


def _executor(config: PipelineConfig) -> Executor:
    """The executor the options (else the config) ask for, started: a Ray cluster joined before anything runs."""
    backend = _Global.executor or config.executor.backend
    address = _Global.ray_address or config.executor.ray_address or None
    executor = make_executor(_Global.workers, backend, address)
    connect = getattr(executor, "connect", None)
    if connect is not None:
        try:
            connect()
        except ExecutorError as error:
            _fail(str(error))
    return executor


def _close(executor: Executor) -> None:
    """Let go of what the executor started (a local Ray instance)."""
    close = getattr(executor, "close", None)
    if close is not None:
        close()


def _bar_progress() -> tuple[Any, Any, Any]:
    """Live bars for a terminal: the context manager and the two callbacks of run_stages."""
    progress = Progress(
        TextColumn("[bold]{task.description:<8}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[status]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=False,
    )
    tasks: dict[str, Any] = {}
    counts: dict[str, dict[str, int]] = {}

    def on_stage(name: str, total: int) -> None:
        counts[name] = {"reused": 0, "built": 0, "failed": 0}
        tasks[name] = progress.add_task(name, total=total, status="")

    def on_item(name: str, item: str, status: str) -> None:
        counts[name][status] += 1
        summary = ", ".join(f"{count} {label}" for label, count in counts[name].items() if count)
        progress.update(tasks[name], advance=1, status=summary)

    return progress, on_stage, on_item


def _run(config_path: Path, overrides: list[str] | None, names: tuple[str, ...], force: bool) -> None:
    config = _load(config_path, overrides)
    store = _store(writable=True, absolute=(_Global.executor or config.executor.backend) == "ray")
    executor = _executor(config)
    _warn_if_built_with_other_hashes(executor)
    if console.is_terminal:
        progress, on_stage, on_item = _bar_progress()
    else:
        progress = LineProgress(_unrepeated(_say))
        on_stage, on_item = progress.on_stage, progress.on_item
    try:
        with progress:
            reports = run_stages(config, store, executor, names, force=force, on_item=on_item, on_stage=on_stage)
    except (MissingInputError, PlanError) as error:
        _print_reports(getattr(error, "reports", []), store)
        _fail(str(error))
    except OSError as error:  # writing the manifest: a full disk, a folder gone read-only
        _fail(write_problem(error))
    finally:
        _close(executor)
    failures = _print_reports(reports, store)
    _say(f"data dir: {store.root}   manifest: {store.manifest_path(config.pipeline.name)}")
    if failures:
        raise typer.Exit(1)


def _unrepeated(write: Callable[[str], None]) -> Callable[[str], None]:
    """``write``, less a line equal to the one before it.

    A stage's progress line is written when it starts and again every interval; until its
    first item ends the two are the same text (``checks: 10 items``), printed twice or more.
    """
    last: list[str] = []

    def write_new(line: str) -> None:
        if last and last[0] == line:
            return
        last[:] = [line]
        write(line)

    return write_new


def _print_reports(reports: list[StageReport], store: ShardStore) -> list[tuple[str, ItemFailure]]:
    """Each stage's report, the stage times and the table of failed items; the failures."""
    for report in reports:
        _print_report(report, store)
    if len(reports) > 1:
        _print_stage_times(reports)
    failures = [(report.stage, failure) for report in reports for failure in report.failures]
    if failures:
        _print_failures(failures)
    return failures


def _print_report(report: StageReport, store: ShardStore) -> None:
    stage = stage_by_name(report.stage)
    rows = sum(record.rows for record in report.records)
    _say(
        f"{report.stage}: {len(report.records)} shards, {rows} rows "
        f"({report.built} built, {report.reused} reused, {len(report.failures)} failed)",
        style="bold",
    )
    for problem in report.rebuilt:
        _say(f"  rebuilt {problem}")
    for item_id, warnings in sorted(report.warnings.items()):
        for warning in warnings:
            _say(f"  warning {item_id}: {warning}")
    for item_id, notes in sorted(report.notes.items()):
        for note in notes:
            _say(f"  note {item_id}: {note}")
    summarize = getattr(stage, "summary", None)
    if summarize is not None and report.records:
        text = summarize(store, report.records)
        if text:
            _say(text)


def stage_time_rows(reports: list[StageReport]) -> list[tuple[str, ...]]:
    """The stage-time table of a run: header, one row per stage, a total row.

    Rate: items built per second of the stage's wall time and, when every
    shard was built in this run, the rows (models, grasps, scenes, samples,
    ...) made per second.
    """
    rows = [("stage", "items", "built", "reused", "failed", "rows", "wall time", "share", "rate")]
    total = sum(report.seconds for report in reports)
    for report in reports:
        row_count = sum(record.rows for record in report.records)
        items = len(report.records) + len(report.failures)
        rate = "-"
        if report.built and report.seconds > 0:
            rate = f"{report.built / report.seconds:.2f} items/s"
            if not report.reused:
                rate += f", {row_count / report.seconds:.1f} rows/s"
        rows.append((report.stage, str(items), str(report.built), str(report.reused), str(len(report.failures)),
                     str(row_count), format_duration(report.seconds),
                     f"{100 * report.seconds / total:.0f} %" if total > 0 else "-", rate))
    rows.append(("total", "", "", "", "", "", format_duration(total), "", ""))
    return rows


def _print_stage_times(reports: list[StageReport]) -> None:
    rows = stage_time_rows(reports)
    widths = [max(len(row[column]) for row in rows) for column in range(len(rows[0]))]
    _say("stage times:", style="bold")
    for row in rows:
        cells = [cell.ljust(width) if column == 0 else cell.rjust(width)
                 for column, (cell, width) in enumerate(zip(row[:-1], widths, strict=False))]
        _say("  " + "  ".join(cells) + "  " + row[-1])


def _print_failures(failures: list[tuple[str, ItemFailure]]) -> None:
    """One table of the failed items: stage, item, file, cause; then tracebacks with --debug."""
    rows = [("stage", "item", "file", "cause")]
    rows += [(stage, failure.item_id, failure.file or "-", failure.cause or failure.error)
             for stage, failure in failures]
    widths = [max(len(row[column]) for row in rows) for column in range(3)]
    _say(f"{len(failures)} item(s) failed; the other items and stages were built without them. "
         "Fix the files and run again: only these and what depends on them are built.", style="red")
    for row in rows:
        _say("  " + "  ".join(cell.ljust(width) for cell, width in zip(row[:3], widths, strict=True)) + "  " + row[3])
    if _Global.debug:
        for stage, failure in failures:
            _say(f"\n{stage} {failure.item_id}:\n{failure.traceback}")
    else:
        _say("(--debug shows their tracebacks)")


def _stage_command(command: str, names: tuple[str, ...]) -> None:
    descriptions = " ".join(f"{name}: {stage_by_name(name).description}" for name in names)

    def run_command(config: ConfigOption, set_: SetOption = None, force: ForceOption = False) -> None:
        _run(config, set_, names, force)

    stages = " and ".join(names) + (" stages." if len(names) > 1 else " stage.")
    run_command.__doc__ = f"Run the {stages} {descriptions}"
    app.command(command)(run_command)


for _command, _names in COMMAND_STAGES.items():
    _stage_command(_command, _names)


@app.command("run")
def run_pipeline(
    config: Annotated[Path, typer.Argument(help="Pipeline config (TOML).")],
    set_: SetOption = None,
    force: ForceOption = False,
) -> None:
    """Run every stage of a pipeline config in order."""
    names = tuple(stage.name for stage in stages())
    _run(config, set_, names, force)


@app.command("config")
def show_config(config: ConfigOption, set_: SetOption = None) -> None:
    """Print the full config a pipeline runs with: every parameter of every stage,
    defaults filled in, each with its meaning. Valid TOML: save it to start a new pipeline."""
    pipeline = _load(config, set_)
    typer.echo(config_to_toml(pipeline), nl=False)


def _taxonomy_table(taxonomy: Taxonomy) -> Table:
    table = Table(title=escape(f"taxonomy {taxonomy.name}: {len(taxonomy.categories)} categories, "
                                f"{len(taxonomy.tasks)} tasks"))
    for column in ("category", "task", "held for the task", "left clear", "length, m", "density, kg/m^3"):
        table.add_column(column)
    for category in taxonomy.categories:
        table.add_row(category.name, category.task, ", ".join(category.handle), ", ".join(category.working),
                      f"{category.length_range[0]:g}-{category.length_range[1]:g}", f"{category.density:g}")
    return table


@app.command("taxonomy")
def show_taxonomy(
    file: Annotated[Path | None, typer.Argument(help="A taxonomy TOML to check (default: the packaged Table I).")
                    ] = None,
) -> None:
    """Check a taxonomy file (categories, parts, tasks and their rules) and print its categories; every mistake
    on a line of its own (exit 2). Without FILE: the packaged Table I (osgd/contract/table1.toml)."""
    try:
        taxonomy = TABLE1 if file is None else read_taxonomy(file)
    except (TaxonomyError, FileNotFoundError) as error:
        for line in str(error).splitlines():
            console.print(Text.assemble(("error: ", "red"), line), highlight=False, soft_wrap=True)
        raise typer.Exit(2) from error
    Console().print(_taxonomy_table(taxonomy))
    _say(f"tasks in logit order: {', '.join(taxonomy.tasks)}; parts: {', '.join(taxonomy.parts)}")


_STATUS_CODES_HELP = ", ".join(f"{code} {kind}" for kind, code in STATUS_EXIT_CODES.items())


@app.command("status", help=(
    "Per stage: shards done, missing, failed (items the last run could not build), corrupt (failing their "
    "checksum or holding another key) and stale (on disk, not in this plan).\n\n"
    f"Exit code: 0 when every planned shard is done and nothing is failed, corrupt or stale; else the sum of "
    f"{_STATUS_CODES_HELP} (e.g. 20: missing and corrupt shards), so that a script or CI can gate on it. "
    "2: a bad config or data dir; 1: an unexpected error."))
def status(config: ConfigOption, set_: SetOption = None) -> None:
    pipeline = _load(config, set_)
    store = _store(writable=False)
    try:
        rows = pipeline_status(pipeline, store)
    except PlanError as error:
        _fail(str(error))
    table = Table(title=escape(f"{pipeline.pipeline.name} in {store.root}"))
    for column in ("stage", "done", "missing", "failed", "corrupt", "stale"):
        table.add_column(column, justify="left" if column == "stage" else "right")
    for row in rows:
        table.add_row(row.stage, str(row.done), str(row.missing), str(row.failed), str(row.corrupt), str(row.stale))
    Console().print(table)
    code = status_exit_code(rows)
    if code:
        found = ", ".join(f"{sum(getattr(row, kind) for row in rows)} {kind}"
                          for kind in STATUS_EXIT_CODES if any(getattr(row, kind) for row in rows))
        _say(f"{pipeline.pipeline.name}: not complete: {found} (exit {code})", style="yellow")
        raise typer.Exit(code)


def _call_with_store(function: Callable[..., Any], **kwargs: Any) -> None:
    """Call a picture or export function on the data dir's store; print what it returns."""
    store = _store(writable=False)
    try:
        result = function(store=store, **kwargs)
    except (KeyError, ValueError, FileNotFoundError) as error:
        # str() of a KeyError is the repr of its message, quotes included
        _fail(str(error.args[0]) if isinstance(error, KeyError) and error.args else str(error))
    if result is not None:
        _say(str(result))


OutOption = Annotated[Path, typer.Option("--out", "-o", help="PNG file to write.")]
ModelArgument = Annotated[
    str, typer.Argument(help="A model's id, or its name as notes and summaries show it (osgd/hammer_001, user/drill).")
]


TaxonomyOption = Annotated[
    Path | None,
    typer.Option("--taxonomy", help="The pipeline's taxonomy file ([pipeline] taxonomy), for the names and colours of "
                 "its own parts and tasks; default: Table I's."),
]


def _shown_taxonomy(path: Path | None) -> Taxonomy:
    """The taxonomy a picture names parts and tasks by; one line and exit 2 on a bad file."""
    if path is None:
        return TABLE1
    try:
        return read_taxonomy(path)
    except (FileNotFoundError, TaxonomyError) as error:
        _fail(str(error))


@show_app.command("model")
def show_model(model_id: ModelArgument, out: OutOption, taxonomy: TaxonomyOption = None) -> None:
    """A model's mesh coloured by part, with its principal axis and how its parts were found."""
    from osgd.models.pictures import show_model as draw  # noqa: PLC0415 (keeps --help fast)

    _call_with_store(draw, model_id=model_id, out=out, taxonomy=_shown_taxonomy(taxonomy))


@show_app.command("models")
def show_models(out: OutOption, taxonomy: TaxonomyOption = None) -> None:
    """A contact sheet of every model in the data dir."""
    from osgd.models.pictures import show_models as draw  # noqa: PLC0415 (keeps --help fast)

    _call_with_store(draw, out=out, taxonomy=_shown_taxonomy(taxonomy))


@show_app.command("grasps")
def show_grasps(
    model_id: ModelArgument,
    out: OutOption,
    color_by: Annotated[str, typer.Option(help="task, or stability (needs the checks table).")] = "task",
    taxonomy: TaxonomyOption = None,
) -> None:
    """A model with its grasps drawn as gripper outlines."""
    from osgd.grasps.pictures import show_grasps as draw  # noqa: PLC0415 (keeps --help fast)

    _call_with_store(draw, model_id=model_id, out=out, color_by=color_by, taxonomy=_shown_taxonomy(taxonomy))


@show_app.command("scene")
def show_scene(scene_id: str, out: OutOption) -> None:
    """A picture of a stacked scene."""
    from osgd.scenes.pictures import show_scene as draw  # noqa: PLC0415 (keeps --help fast)

    _call_with_store(draw, scene_id=scene_id, out=out)


@show_app.command("sample")
def show_sample(sample_id: str, out: OutOption) -> None:
    """Depth with boxes and grasp rectangles coloured by task (paper figures 2 and 7)."""
    from osgd.samples.pictures import show_sample as draw  # noqa: PLC0415 (keeps --help fast)

    _call_with_store(draw, sample_id=sample_id, out=out)


@app.command("export")
def export(
    out_dir: Annotated[Path, typer.Argument(help="Folder to write into.")],
    format_: Annotated[str, typer.Option(
        "--format", help="osgd, cornell, coco, or hf (a Hugging Face dataset folder: Parquet per split, Image "
        "features, a dataset card; datasets.load_dataset(OUT) opens it).")] = "osgd",
    pipeline: Annotated[str | None, typer.Option(
        help="Whose samples (that pipeline's manifest); default: the data dir's only pipeline with samples.")] = None,
) -> None:
    """Write the samples in a format peers' tools read."""
    from osgd.samples.export import export as write  # noqa: PLC0415 (keeps --help fast)

    _call_with_store(write, out_dir=out_dir, format=format_, pipeline=pipeline)


def _seed_worker_hashes() -> None:
    """Give the processes this one starts ``PYTHONHASHSEED=0``, unless the user chose a seed.

    The interpreter reads ``PYTHONHASHSEED`` once, when it starts: setting it
    here reaches only child processes (the process pool's workers, a local Ray
    instance through :func:`osgd.executor.ray_runtime_env`), never this
    process's own ``str`` hashes. Whether the two differ is kept for
    :func:`_warn_if_built_with_other_hashes`.
    """
    own = os.environ.get("PYTHONHASHSEED")
    os.environ.setdefault("PYTHONHASHSEED", "0")
    _Global.hash_seed_differs = own != os.environ["PYTHONHASHSEED"]


def _warn_if_built_with_other_hashes(executor: Executor) -> None:
    """Warn when shards are built in this process while its ``str`` hashes are not the workers'."""
    if isinstance(executor, SerialExecutor) and _Global.hash_seed_differs:
        log.warning("the shards are built in this process (one worker), whose string hashes are random: "
                    "PYTHONHASHSEED was not set when it started, and worker processes run with 0; "
                    "set PYTHONHASHSEED=0 to build them with the workers' hashes")


def run() -> NoReturn:
    """Console-script entry point: an unexpected error is one line, its traceback only with ``--debug``.

    The process ends through :func:`osgd.contract.process_exit.run_then_exit`, without
    the native libraries' teardown.
    """
    run_then_exit(_run_app)


def _run_app() -> None:
    """The CLI, its end a :class:`SystemExit` (Click's standalone mode), an unexpected error one line."""
    _seed_worker_hashes()
    try:
        app()
    except KeyboardInterrupt:
        _say("interrupted; finished shards are kept, rerun to resume")
        sys.exit(130)
    except Exception as error:
        if _Global.debug or "--debug" in sys.argv:
            raise
        file, cause = describe(error)
        _say(f"error: {file + ': ' if file else ''}{cause} (--debug shows the traceback)", style="red")
        sys.exit(1)
