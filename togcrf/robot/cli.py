"""``togcrf robot-eval`` and ``togcrf robot-table``: the paper's Table III in simulation.

Writes into the run folder ``--out``: ``trials.parquet`` (the trial log,
:mod:`togcrf.robot.report`), ``table3.md`` (Table III with the paper's
rows), ``table3.json`` (the rates, failure reasons, timings and the
command) and ``failures/POLICY/TASK_NN.png`` (one picture per failure).
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Annotated, Any

import typer

from togcrf.checkpoint import checkpoint_path, read_checkpoint
from togcrf.evaluate import command_line, write_json
from togcrf.robot.protocol import check_fresh, protocol_trials, untried_tasks
from togcrf.robot.report import format_table3, policy_tables, read_logs, reason_counts, timing_summary, write_log
from togcrf.tta import check_view_count

log = logging.getLogger(__name__)


def _policies(checkpoints: list[Path], baselines: str) -> tuple[str, ...]:
    names = [name.strip() for name in baselines.split(",") if name.strip()]
    unknown = [name for name in names if name not in ("oracle", "random")]
    if unknown:
        raise ValueError(f"--baselines: unknown {unknown}; choose among oracle, random")
    for checkpoint in checkpoints:
        if not Path(checkpoint).exists():
            raise FileNotFoundError(f"{checkpoint}: no checkpoint")
    policies = (*names, *(str(path) for path in checkpoints))
    if not policies:
        raise ValueError("nothing to evaluate: give a CHECKPOINT or --baselines")
    return policies


def novel_tools(checkpoints: list[Path], tools: set[str]) -> dict[str, int | None]:
    """Per checkpoint, how many of ``tools`` (model ids) its training samples never showed (None: not recorded)."""
    counts: dict[str, int | None] = {}
    for checkpoint in checkpoints:
        trained = (read_checkpoint(checkpoint_path(checkpoint)).get("data") or {}).get("models")
        counts[str(checkpoint)] = None if trained is None else len(tools - set(trained))
    return counts


def _tasks(text: str | None, known: tuple[str, ...]) -> tuple[str, ...]:
    """The tasks of ``--tasks`` among ``known`` (the pipeline's taxonomy's); all of them when not given."""
    if text is None:
        return known
    tasks = tuple(name.strip() for name in text.split(",") if name.strip())
    unknown = [task for task in tasks if task not in known]
    if unknown:
        raise ValueError(f"--tasks: unknown {unknown}; tasks are {list(known)}")
    return tasks


def print_progress(row: dict[str, Any]) -> None:
    """One line per trial row: policy, task, trial number, outcome (ok, S for GSR-S only, or the reason)."""
    outcome = "ok" if row["gsr_t"] else ("S" if row["gsr_s"] else row["reason"])
    typer.echo(f"  {row['policy']:<24} {row['task']:<10} {row['repeat']:>2} {outcome}")


def write_results(out: Path, rows: list[dict[str, Any]], extra: dict[str, Any]) -> str:
    """Write the trial log, ``table3.md`` and ``table3.json``; return Table III as text."""
    write_log(rows, out / "trials.parquet")
    tables = policy_tables(rows)
    text = format_table3(tables)
    (out / "table3.md").write_text(text + "\n")
    write_json(out / "table3.json", {**extra, "table3": tables, "reasons": reason_counts(rows),
                                     "timing": timing_summary(rows)})
    return text


def robot_eval_command(
    checkpoints: Annotated[list[Path] | None, typer.Argument(
        metavar="CHECKPOINT", help="checkpoint.pt files (or run folders) written by `togcrf train`.")] = None,
    *,
    config: Annotated[Path, typer.Option("--config", "-c", help="The pipeline config the piles follow.")],
    data: Annotated[Path, typer.Option("--data", help="Data dir where the pipeline is built.")] = Path("data"),
    out: Annotated[Path, typer.Option(help="Run folder for the log, Table III and the failure pictures.")] = Path(
        "runs/robot"),
    baselines: Annotated[str, typer.Option(help="Comma-separated: oracle, random ('' for none).")] = "oracle,random",
    tool_trials: Annotated[int, typer.Option(help="Trials per tool task (paper: 10).")] = 10,
    named_trials: Annotated[int, typer.Option(help="Trials for 'no task' and for 'hand over' (paper: 30).")] = 30,
    tasks: Annotated[str | None, typer.Option(help="Only these tasks, comma-separated (default: all).")] = None,
    workers: Annotated[int, typer.Option(help="Processes (the trials are split between them).")] = 1,
    min_score: Annotated[float, typer.Option(help="Checkpoints: keep detections with this score.")] = 0.5,
    min_stability: Annotated[float, typer.Option(help="Checkpoints: candidates this stable compete.")] = 0.5,
    views: Annotated[int, typer.Option(help="Checkpoints: average the grasp candidates over 1 (off), 2, 4 or 8 "
                                            "flipped and turned copies of each image (togcrf.tta).")] = 1,
    any_pile: Annotated[bool, typer.Option(
        "--any-pile", help="Keep each trial's first pile even when the task cannot be done in it.")] = False,
    pictures: Annotated[bool, typer.Option(help="Draw a picture of every failure.")] = True,
    set_values: Annotated[list[str] | None, typer.Option(
        "--set", "-s", help="Override a config value: section.key=value.")] = None,
) -> None:
    """Table III (GSR-S, GSR-T) in simulation: the paper's robot protocol on fresh piles, per checkpoint."""
    # The generator's simulation (osgd.simulation: trimesh and embreex on import, pybullet on first use) loads
    # for this command only, not with `togcrf --help`: togcrf.cli imports this module.
    from osgd.simulation import load_pipeline  # noqa: PLC0415 - optional dependency: simulation
    from togcrf.robot.run import RunSpec, run_protocol  # noqa: PLC0415 - optional dependency: simulation
    from togcrf.robot.world import load_world, stored_scene_seeds  # noqa: PLC0415 - optional dependency: simulation

    started = time.perf_counter()
    overrides = tuple(set_values or ())
    policies = _policies(list(checkpoints or []), baselines)
    check_view_count(views)
    pipeline = load_pipeline(config, overrides)
    chosen_tasks = _tasks(tasks, pipeline.taxonomy.tasks)
    check_fresh(pipeline.params["scenes"].count, (), ())
    world = load_world(data, pipeline)
    eligible = world.eligible_categories()
    untried = untried_tasks(chosen_tasks, eligible, world.afforded_tasks())
    for task, reason in untried.items():
        typer.echo(f"not tried: {task!r}: {reason} (Total is the mean of the tasks tried)")
    chosen_tasks = tuple(task for task in chosen_tasks if task not in untried)
    if not chosen_tasks:
        raise ValueError(f"{config}: none of the tasks asked for can be tried on the pipeline's models")
    trials = protocol_trials(world.seed, eligible, tool_trials, named_trials, chosen_tasks, pipeline.taxonomy)
    spec = RunSpec(config, overrides, data, policies, out, min_score=min_score, min_stability=min_stability,
                   views=views, pictures=pictures, require_clear=not any_pile)
    novel = novel_tools(list(checkpoints or []), set(world.models))
    typer.echo(f"{len(trials)} trials x {len(policies)} policies, {workers} process(es); writing to {out}")
    typer.echo(f"{len(world.models)} tools in the piles")
    for checkpoint, count in novel.items():
        typer.echo(f"  {checkpoint}: {'not recorded' if count is None else f'{count} never in its training'}")

    rows = run_protocol(spec, trials, workers, world if workers <= 1 else None, print_progress)
    check_fresh(pipeline.params["scenes"].count, (row["pile_seed"] for row in rows), stored_scene_seeds(data))
    text = write_results(out, rows, {"command": command_line(), "config": str(config), "overrides": list(overrides),
                                     "policies": list(policies), "views": views, "trials": len(trials),
                                     "tools": len(world.models), "novel_tools": novel, "untried_tasks": untried,
                                     "workers": workers,
                                     "seconds": time.perf_counter() - started})
    typer.echo(text)
    typer.echo(f"{len(rows)} trial rows in {time.perf_counter() - started:.0f} s; written to {out}")


def robot_table_command(
    logs: Annotated[list[Path], typer.Argument(metavar="TRIALS.parquet", help="Trial logs of robot-eval runs.")],
    out: Annotated[Path | None, typer.Option(help="Also write table3.md and table3.json into this folder.")] = None,
) -> None:
    """Table III from one or more trial logs, side by side with the paper's."""
    rows = read_logs(logs)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        text = write_results(out, rows, {"command": command_line(), "logs": [str(path) for path in logs]})
    else:
        text = format_table3(policy_tables(rows))
    typer.echo(text)


def register(app: typer.Typer) -> None:
    """Add ``robot-eval`` and ``robot-table`` to the ``togcrf`` command line."""
    app.command("robot-eval")(robot_eval_command)
    app.command("robot-table")(robot_table_command)
