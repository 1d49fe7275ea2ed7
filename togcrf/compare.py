"""Two models over training seeds: each metric's difference with its 95 % interval.

``togcrf compare --baseline A.json ... --candidate B.json ...`` reads evaluations of two models, one per
training seed (``eval.json`` of ``togcrf eval``, or ``eval-sets.json`` of ``togcrf eval --test-set``; all of
one kind), and prints for each test set (one, ``test``, for plain evaluations) and each metric the mean of
each model, the mean difference candidate minus baseline, and two 95 % intervals of that difference:

- **paired by seed**: Student's t on the per-seed differences (n - 1 degrees of freedom). A seed fixes the
  order of the training samples and their augmentation (:mod:`togcrf.data`), so two runs of one seed saw
  the same images in the same order; pairing removes that part of the spread. Used when every seed
  (:func:`togcrf.evaluate.evaluation_seed`) appears once in each group.
- **unpaired**: Welch's t interval (each group's own variance, Welch-Satterthwaite degrees of freedom).

The metrics are Table II's (mAP, mAP-G, Acc-T top-1/5/10) and Acc-T top-1 in each stratum the
evaluation holds (:mod:`togcrf.metrics`: by the share of the object's box that other objects cover, and
by the number of objects in the image), in percentage points, under one protocol (``--protocol``). A
difference whose interval excludes zero is marked ``*``; with two or three seeds an interval is wide, and
with one seed there is none.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from scipy import stats

from togcrf.evaluate import TABLE_COLUMNS, document_protocol, evaluation_seed, read_evaluation, row_name, write_json
from togcrf.metrics import COVER_STRATUM, PILE_STRATUM, PROTOCOLS

#: Table II's metrics compared: its columns but the speed.
HEADLINE_METRICS = TABLE_COLUMNS[:-1]

#: The strata of Acc-T that an evaluation may hold (:mod:`togcrf.metrics`), compared on their top-1.
STRATA = (COVER_STRATUM, PILE_STRATUM)

#: Confidence of the intervals.
CONFIDENCE = 0.95


def set_metrics(document: dict[str, Any], protocol: str, source: str = "the evaluation") -> dict[str, dict[str, Any]]:
    """Test set name -> the metrics of one protocol, for a plain or a test-set evaluation read from ``source``.

    Raises
    ------
    ValueError
        Naming ``source``, if a plain evaluation is of another protocol or a test set lacks the protocol.
    """
    if "test_sets" in document:
        missing = [name for name, entry in document["test_sets"].items() if protocol not in entry.get("metrics", {})]
        if missing:
            raise ValueError(f"{source}: test set(s) {missing} hold no metrics of protocol {protocol!r}")
        return {name: entry["metrics"][protocol] for name, entry in document["test_sets"].items()}
    if document_protocol(document) != protocol:
        raise ValueError(f"{source}: an evaluation of protocol {document_protocol(document)!r}, not {protocol!r}")
    if "metrics" not in document:
        raise ValueError(f"{source}: not an evaluation (no metrics)")
    return {"test": document["metrics"]}


def flat_metrics(metrics: dict[str, Any]) -> dict[str, float]:
    """The compared metrics of one test set: Table II's and each stratum's Acc-T top-1 (``STRATUM: BIN``)."""
    values = {name: float(metrics[name]) for name in HEADLINE_METRICS if metrics.get(name) is not None}
    for stratum in STRATA:
        for bin_name, cell in (metrics.get(stratum) or {}).items():
            if cell.get("Acc-T top1") is not None:
                values[f"{stratum}: {bin_name}"] = float(cell["Acc-T top1"])
    return values


def stratum_rois(metrics: dict[str, Any]) -> dict[str, int]:
    """The RoIs judged in each stratum of one test set (the same keys as :func:`flat_metrics`), and overall."""
    counts = {name: int(metrics.get("rois") or 0) for name in HEADLINE_METRICS if name.startswith("Acc-T")}
    for stratum in STRATA:
        for bin_name, cell in (metrics.get(stratum) or {}).items():
            counts[f"{stratum}: {bin_name}"] = int(cell.get("rois") or 0)
    return counts


def interval(values: Sequence[float]) -> tuple[float, float] | None:
    """The 95 % Student's t interval of the mean of ``values`` (None for fewer than two)."""
    if len(values) < 2:
        return None
    half = stats.t.ppf(0.5 + CONFIDENCE / 2, len(values) - 1) * np.std(values, ddof=1) / math.sqrt(len(values))
    mean = float(np.mean(values))
    return mean - half, mean + half


def welch_interval(baseline: Sequence[float], candidate: Sequence[float]) -> tuple[float, float] | None:
    """Welch's 95 % interval of mean(candidate) - mean(baseline) (None with fewer than two runs in a group)."""
    if len(baseline) < 2 or len(candidate) < 2:
        return None
    var_b, var_c = np.var(baseline, ddof=1) / len(baseline), np.var(candidate, ddof=1) / len(candidate)
    difference = float(np.mean(candidate) - np.mean(baseline))
    if var_b + var_c == 0:
        return difference, difference
    dof = (var_b + var_c) ** 2 / (var_b**2 / (len(baseline) - 1) + var_c**2 / (len(candidate) - 1))
    half = stats.t.ppf(0.5 + CONFIDENCE / 2, dof) * math.sqrt(var_b + var_c)
    return difference - half, difference + half


def paired_order(baseline_seeds: Sequence[int | None], candidate_seeds: Sequence[int | None]) -> list[int] | None:
    """For each baseline run, the index of the candidate run of its seed; None when the seeds do not pair
    (a seed unknown, repeated, or in one group only)."""
    known = None not in baseline_seeds and None not in candidate_seeds
    if not known or len(set(baseline_seeds)) != len(baseline_seeds) or set(baseline_seeds) != set(candidate_seeds):
        return None
    if len(set(candidate_seeds)) != len(candidate_seeds):
        return None
    return [list(candidate_seeds).index(seed) for seed in baseline_seeds]


def compare_metric(baseline: Sequence[float], candidate: Sequence[float], order: list[int] | None) -> dict[str, Any]:
    """One metric's comparison, in percentage points (see the module docstring)."""
    baseline = [100 * value for value in baseline]
    candidate = [100 * value for value in candidate]
    paired = None
    if order is not None:
        paired = interval([candidate[index] - value for index, value in zip(order, baseline, strict=True)])
    return {"baseline": float(np.mean(baseline)), "candidate": float(np.mean(candidate)),
            "difference": float(np.mean(candidate) - np.mean(baseline)), "paired": paired,
            "unpaired": welch_interval(baseline, candidate), "baseline_runs": baseline, "candidate_runs": candidate}


def compare(baseline: Sequence[tuple[Path, dict[str, Any]]], candidate: Sequence[tuple[Path, dict[str, Any]]],
            protocol: str = "ours") -> dict[str, Any]:
    """Compare two groups of evaluations (path, document), metric by metric and test set by test set.

    Returns
    -------
    dict
        ``protocol``, ``baseline`` and ``candidate`` (``model``, ``seeds``, ``sources``), ``paired`` (whether the
        seeds paired) and ``test_sets``: set -> metric -> :func:`compare_metric`, for the sets and metrics that
        every evaluation holds; Acc-T's also hold ``rois``, the RoIs judged, averaged over the runs.

    Raises
    ------
    ValueError
        If a group is empty, the protocol unknown, or the groups' evaluations of different kinds.
    """
    if protocol not in PROTOCOLS:
        raise ValueError(f"--protocol {protocol!r}: expected one of {', '.join(PROTOCOLS)}")
    if not baseline or not candidate:
        raise ValueError("give at least one evaluation in --baseline and one in --candidate")
    groups = {"baseline": baseline, "candidate": candidate}
    read = {name: [set_metrics(document, protocol, str(path)) for path, document in group]
            for name, group in groups.items()}
    values = {name: [{set_name: flat_metrics(metrics) for set_name, metrics in sets.items()} for sets in runs]
              for name, runs in read.items()}
    seeds = {name: [evaluation_seed(path, document) for path, document in group] for name, group in groups.items()}
    order = paired_order(seeds["baseline"], seeds["candidate"])
    common = _common_keys([*values["baseline"], *values["candidate"]])
    if not common:
        raise ValueError("the evaluations share no test set: compare eval.json files with eval.json files, and "
                         "eval-sets.json files of the same --test-set names")
    test_sets = {set_name: {metric: compare_metric([run[set_name][metric] for run in values["baseline"]],
                                                   [run[set_name][metric] for run in values["candidate"]], order)
                            for metric in metrics}
                 for set_name, metrics in common.items()}
    for set_name, metrics in test_sets.items():
        counts = [stratum_rois(sets[set_name]) for runs in read.values() for sets in runs]
        for metric, cell in metrics.items():
            if metric in counts[0]:
                cell["rois"] = float(np.mean([count.get(metric, 0) for count in counts]))
    return {"protocol": protocol, "paired": order is not None, "test_sets": test_sets,
            **{name: {"model": _group_model(group), "seeds": seeds[name], "sources": [str(path) for path, _ in group]}
               for name, group in groups.items()}}


def _common_keys(runs: Sequence[dict[str, dict[str, float]]]) -> dict[str, list[str]]:
    """The test sets, and in each the metrics, that every run holds, in the first run's order."""
    common = {}
    for set_name, metrics in runs[0].items():
        if all(set_name in run for run in runs):
            common[set_name] = [metric for metric in metrics if all(metric in run[set_name] for run in runs)]
    return common


def _group_model(group: Sequence[tuple[Path, dict[str, Any]]]) -> str:
    """The paper's names of a group's models, joined where they differ."""
    return " / ".join(dict.fromkeys(row_name(document) for _, document in group))


def _format_interval(bounds: tuple[float, float] | None) -> str:
    if bounds is None:
        return "-"
    mark = "*" if bounds[0] > 0 or bounds[1] < 0 else " "
    return f"[{bounds[0]:+.1f}, {bounds[1]:+.1f}]{mark}"


def format_comparison(result: dict[str, Any]) -> str:
    """:func:`compare`'s result as text: a block per test set, a line per metric."""
    baseline, candidate = result["baseline"], result["candidate"]
    header = (f"{'metric':<42}{'RoIs':>6}{baseline['model'][:10]:>11}{candidate['model'][:10]:>11}{'diff':>8}"
              f"{'paired 95 %':>18}{'Welch 95 %':>18}")
    lines = [f"{candidate['model']} minus {baseline['model']}, protocol {result['protocol']}, "
             f"{len(baseline['seeds'])} and {len(candidate['seeds'])} runs; "
             + ("paired by seed" if result["paired"] else "not paired (the seeds do not match one to one)")]
    for set_name, metrics in result["test_sets"].items():
        lines += ["", f"test set {set_name}", header, "-" * len(header)]
        for metric, cell in metrics.items():
            rois = f"{cell['rois']:.0f}" if "rois" in cell else ""
            lines.append(f"{metric[:41]:<42}{rois:>6}{cell['baseline']:>11.1f}{cell['candidate']:>11.1f}"
                         f"{cell['difference']:>+8.1f}{_format_interval(cell['paired']):>18}"
                         f"{_format_interval(cell['unpaired']):>18}")
    lines.append("")
    lines.append("percentage points; RoIs: judged for Acc-T, the mean over the runs; * : the interval excludes zero")
    return "\n".join(lines)


# --------------------------------------------------------------------------- CLI


def compare_command(
    baseline: Annotated[list[Path], typer.Option("--baseline", help="An evaluation of the baseline model, one "
                                                 "per seed (repeat): eval.json, eval-sets.json or a run dir.")],
    candidate: Annotated[list[Path], typer.Option("--candidate", help="An evaluation of the candidate model, one "
                                                  "per seed (repeat).")],
    protocol: Annotated[str, typer.Option(help="The mAP / mAP-G rules compared: 'ours' or 'lab'.")] = "ours",
    out: Annotated[Path | None, typer.Option(help="Also write the comparison as JSON here.")] = None,
) -> None:
    """Candidate minus baseline over training seeds, per metric and test set, with 95 % intervals (paired by seed
    and Welch's); Acc-T also by crowding and by pile size."""
    groups = [[(path, read_evaluation(path)) for path in paths] for paths in (baseline, candidate)]
    result = compare(*groups, protocol=protocol)
    typer.echo(format_comparison(result))
    if out is not None:
        write_json(out, result)
        typer.echo(f"written to {out}")


def register(app: typer.Typer) -> None:
    """Add ``compare`` to the ``togcrf`` command line."""
    app.command("compare")(compare_command)
