"""The trial log (Parquet), Table III and the timing summary.

Trial log columns (:data:`TRIAL_LOG`), one row per trial and policy:

======================  =====================================================
``policy``              policy name (``oracle``, ``random``, ``tog:RUN`` ...)
``checkpoint``          the checkpoint file ("" for oracle and random)
``task``, ``category``  the trial's task; the named category ("" for tool tasks)
``repeat``              trial number within the task
``scene_index``         the trial's first scene index (>= 10^9, never a training scene's)
``piles``               piles drawn until one annotates the task (the last is used: ``scene_index + piles - 1``)
``pile_seed``           the seed of the used pile's accepted attempt (the ``scenes`` table's ``seed``)
``pile_categories``     the pile's tools, in scene order
``rectangle``           the chosen ``[x, y, h, w, theta]`` (px, rad); null when none
``chosen_category``     what the policy believes it grasps ("" when no belief)
``task_probability``    P(task | stable) of the choice (NaN for oracle and random)
``stability``           P(stable) of the choice (NaN likewise)
``detections``          objects detected (-1: the policy does not detect)
``aimed_object``        scene index of the object seen under the rectangle's centre (-1 table)
``aimed_category``      its category ("" for the table)
``grasp_position``      the lifted grasp's centre, world, m (null without a grasp)
``grasp_quaternion``    its gripper frame, world, (x, y, z, w)
``opening``             pre-grasp opening, m
``approach_stopped``    the guarded approach stopped early
``stopped_by``          what it touched ("floor", a category, "")
``held_object``         scene index of the object held, or the last to leave the pads (-1: none)
``held_category``       its category
``held``                lifted and held after the hold
``rise``                rise of that object's centre of mass, m
``label``               the grasps stage's task label of the held pose
``nearest_task``        task of the nearest annotated grasp of the held object
``nearest_distance``    its distance, m (see ``World.nearest_grasp``)
``judged_by``           ``parts`` or ``nearest`` (models without part labels)
``gsr_s``, ``gsr_t``    the outcome
``reason``              "" or one of ``execute.REASONS``
``picture``             the failure picture, relative to the run folder ("" on success)
``seconds_pile``        dropping and rendering the piles (shared by the policies of a trial)
``seconds_policy``      the policy's choice (inference for a checkpoint)
``seconds_execute``     lifting, simulating and judging
======================  =====================================================
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from togcrf.robot.protocol import NAMED_TASKS, PAPER_TABLE3, PAPER_TOTAL, TABLE_TASKS

_FLOATS = pa.list_(pa.float64())

#: The trial log's schema (see the module text).
TRIAL_LOG = pa.schema([
    ("policy", pa.string()), ("checkpoint", pa.string()), ("task", pa.string()), ("category", pa.string()),
    ("repeat", pa.int32()), ("scene_index", pa.int64()), ("piles", pa.int32()), ("pile_seed", pa.int64()),
    ("pile_categories", pa.list_(pa.string())), ("rectangle", _FLOATS), ("chosen_category", pa.string()),
    ("task_probability", pa.float64()), ("stability", pa.float64()), ("detections", pa.int32()),
    ("aimed_object", pa.int32()), ("aimed_category", pa.string()), ("grasp_position", _FLOATS),
    ("grasp_quaternion", _FLOATS), ("opening", pa.float64()), ("approach_stopped", pa.bool_()),
    ("stopped_by", pa.string()), ("held_object", pa.int32()), ("held_category", pa.string()), ("held", pa.bool_()),
    ("rise", pa.float64()), ("label", pa.string()), ("nearest_task", pa.string()), ("nearest_distance", pa.float64()),
    ("judged_by", pa.string()), ("gsr_s", pa.bool_()), ("gsr_t", pa.bool_()), ("reason", pa.string()),
    ("picture", pa.string()), ("seconds_pile", pa.float64()),
    ("seconds_policy", pa.float64()), ("seconds_execute", pa.float64()),
])


def write_log(rows: Sequence[Mapping[str, Any]], path: Path) -> Path:
    """Write trial rows as a Parquet file with :data:`TRIAL_LOG`'s columns."""
    path.parent.mkdir(parents=True, exist_ok=True)
    table = pa.Table.from_pylist([dict(row) for row in rows], schema=TRIAL_LOG)
    pq.write_table(table, path)
    return path


def read_logs(paths: Sequence[Path]) -> list[dict[str, Any]]:
    """Rows of one or more trial logs.

    Raises
    ------
    FileNotFoundError, ValueError
        A missing file, or one without the trial log's columns.
    """
    rows: list[dict[str, Any]] = []
    for path in paths:
        if not Path(path).is_file():
            raise FileNotFoundError(f"{path}: no trial log")
        table = pq.read_table(path)
        missing = sorted(set(TRIAL_LOG.names) - set(table.column_names))
        if missing:
            raise ValueError(f"{path}: not a robot trial log (missing columns {missing})")
        rows.extend(table.to_pylist())
    return rows


def rates(rows: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """Table III of one policy: per task and in total.

    Returns
    -------
    dict
        Per task present (:func:`table_tasks` order): ``trials``, ``gsr_s``,
        ``gsr_t`` (percent); ``Total``: the mean of the task rates, as the
        paper's total; ``All trials``: pooled over every trial. The two
        summaries also hold ``gsr_s_interval`` and ``gsr_t_interval``, their
        95 % intervals (percent, :func:`summary_intervals`).
    """
    table: dict[str, dict[str, Any]] = {}
    outcomes: dict[str, np.ndarray] = {}
    for task in table_tasks(row["task"] for row in rows):
        chosen = [row for row in rows if row["task"] == task]
        if chosen:
            outcomes[task] = np.array([[row["gsr_s"], row["gsr_t"]] for row in chosen], dtype=float)
            gsr_s, gsr_t = 100.0 * outcomes[task].mean(axis=0)
            table[task] = {"trials": len(chosen), "gsr_s": float(gsr_s), "gsr_t": float(gsr_t)}
    if table:
        table["Total"] = {"trials": sum(entry["trials"] for entry in table.values()),
                          "gsr_s": float(np.mean([entry["gsr_s"] for entry in table.values()])),
                          "gsr_t": float(np.mean([entry["gsr_t"] for entry in table.values()]))}
        table["All trials"] = {"trials": len(rows), "gsr_s": 100.0 * np.mean([row["gsr_s"] for row in rows]),
                               "gsr_t": 100.0 * np.mean([row["gsr_t"] for row in rows])}
        for index, metric in enumerate(("gsr_s", "gsr_t")):
            intervals = summary_intervals([column[:, index] for column in outcomes.values()])
            for summary, interval in intervals.items():
                table[summary][f"{metric}_interval"] = interval
    return table


#: Draws of the bootstrap behind :func:`summary_intervals`, and its seed: one log always gives one interval.
INTERVAL_DRAWS = 20_000
INTERVAL_SEED = 0


def summary_intervals(outcomes: Sequence[np.ndarray]) -> dict[str, list[float]]:
    """95 % intervals (percent) of the Total and the All trials rate of one outcome (GSR-S or GSR-T).

    ``outcomes`` holds each task's trials as 0 / 1. The interval is the
    2.5 and 97.5 percentiles of a bootstrap that resamples each task's
    trials with replacement (so each task keeps its count, as the protocol
    fixes it): a resampled task's successes are binomial at its observed
    rate. It reflects the trials' chance, not the spread between seeds of a
    checkpoint; a task whose trials all agree adds no width.
    """
    rng = np.random.default_rng(INTERVAL_SEED)
    counts = np.array([len(column) for column in outcomes], dtype=float)
    successes = np.stack([rng.binomial(len(column), float(np.mean(column)), size=INTERVAL_DRAWS)
                          for column in outcomes])
    draws = {"Total": 100.0 * (successes / counts[:, None]).mean(axis=0),
             "All trials": 100.0 * successes.sum(axis=0) / counts.sum()}
    return {summary: [float(bound) for bound in np.percentile(values, [2.5, 97.5])]
            for summary, values in draws.items()}


def table_tasks(tasks: Iterable[str]) -> list[str]:
    """The tasks named, once each, as Table III orders them: the paper's, then those of a pipeline's own taxonomy
    in the order first named (the protocol's)."""
    present = dict.fromkeys(tasks)
    return [task for task in TABLE_TASKS if task in present] + [task for task in present if task not in TABLE_TASKS]


def policy_tables(rows: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, dict[str, Any]]]:
    """:func:`rates` of every policy in the rows, in the order they first appear."""
    names = list(dict.fromkeys(row["policy"] for row in rows))
    return {name: rates([row for row in rows if row["policy"] == name]) for name in names}


def reason_counts(rows: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, int]]:
    """Per policy, how many trials ended for each reason ("" = success)."""
    counts: dict[str, dict[str, int]] = {}
    for row in rows:
        entry = counts.setdefault(row["policy"], {})
        entry[row["reason"]] = entry.get(row["reason"], 0) + 1
    return counts


def _cell(value: float | None) -> str:
    return "" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.1f}"


def format_table3(tables: Mapping[str, Mapping[str, Mapping[str, Any]]], paper: bool = True) -> str:
    """Table III as Markdown: a GSR-S and a GSR-T column per policy, the paper's beside them.

    The trial counts are in a column per policy when they differ from the paper's
    (10 per tool task, 30 for "no task" and "hand over").
    """
    names = list(tables)
    paper_names = list(PAPER_TABLE3) if paper else []
    header = ["Task", *[f"{name} GSR-S" for name in names], *[f"paper {name} GSR-S" for name in paper_names],
              *[f"{name} GSR-T" for name in names], *[f"paper {name} GSR-T" for name in paper_names], "trials"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    summaries = ("Total", "All trials")
    tasks = table_tasks(task for table in tables.values() for task in table if task not in summaries)
    for task in (*tasks, *summaries):
        if not any(task in table for table in tables.values()):
            continue
        trials = sorted({table[task]["trials"] for table in tables.values() if task in table})
        cells = [task]
        for metric, index in (("gsr_s", 0), ("gsr_t", 1)):
            cells += [_cell(tables[name].get(task, {}).get(metric)) for name in names]
            cells += [_cell(_paper_value(name, task, index)) for name in paper_names]
        cells.append("/".join(str(count) for count in trials))
        lines.append("| " + " | ".join(cells) + " |")
        if task in summaries and any("gsr_t_interval" in table.get(task, {}) for table in tables.values()):
            lines.append(_interval_line(tables, task, len(paper_names)))
    return "\n".join(lines)


def _interval_line(tables: Mapping[str, Mapping[str, Mapping[str, Any]]], task: str, paper_columns: int) -> str:
    """The 95 % intervals of a summary row, a cell per policy and metric (blank where a table has none)."""
    cells = [f"{task}, 95 % interval"]
    for metric in ("gsr_s", "gsr_t"):
        for table in tables.values():
            bounds = table.get(task, {}).get(f"{metric}_interval")
            cells.append("" if bounds is None else f"{bounds[0]:.1f}-{bounds[1]:.1f}")
        cells += [""] * paper_columns
    cells.append("")
    return "| " + " | ".join(cells) + " |"


def _paper_value(name: str, task: str, index: int) -> float | None:
    if task == "Total":
        return PAPER_TOTAL[name][index]
    if task == "All trials":
        values = PAPER_TABLE3[name]
        weights = {task: 30 if task in NAMED_TASKS else 10 for task in values}
        return sum(values[task][index] * weights[task] for task in values) / sum(weights.values())
    return PAPER_TABLE3[name].get(task, (None, None))[index]


def timing_summary(rows: Sequence[dict[str, Any]]) -> dict[str, float]:
    """Mean seconds per trial of each phase, and of a whole single-policy trial per policy."""
    summary = {f"mean_{phase}": float(np.mean([row[f"seconds_{phase}"] for row in rows]))
               for phase in ("pile", "policy", "execute")}
    summary["mean_piles"] = float(np.mean([row["piles"] for row in rows]))
    for name in dict.fromkeys(row["policy"] for row in rows):
        chosen = [row for row in rows if row["policy"] == name]
        summary[f"trial_{name}"] = float(np.mean([
            row["seconds_pile"] + row["seconds_policy"] + row["seconds_execute"]
            for row in chosen]))
    return summary
