"""The recipe's two seeds side by side: Table II per test set, the gap to the seen tools per metric and per
category, and Table III per set of piles with each Total's 95 % interval (over the trials).

Reads the seed-0 run (lab/results/recipe-novel/) and the seed-1 run (this folder); writes summary.txt here.
Run from the repository root: `.venv/bin/python lab/results/recipe-seed1/summary.py`.
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

import numpy as np

from togcrf.robot.report import summary_intervals

HERE = Path(__file__).parent
RUNS = {0: HERE.parent / "recipe-novel", 1: HERE}
METRICS = ("mAP", "mAP-G", "Acc-T top1", "Acc-T top5", "Acc-T top10")
SETS = ("seen", "novel", "authors")
SUMMARIES = ("Total", "All trials")


@cache
def _sets(seed: int) -> dict:
    document = json.loads((RUNS[seed] / "table2-sets.json").read_text())
    (run,) = document["runs"].values()
    return run["test_sets"]


def _row(cells: list) -> str:
    return "| " + " | ".join(str(cell) for cell in cells) + " |"


def table2(protocol: str = "ours") -> list[str]:
    lines = [f"Table II per test set, {protocol} protocol (percent)", "",
             _row(["test set", "seed", "images", "tools (novel)", *METRICS]), _row(["---"] * (4 + len(METRICS)))]
    for name in SETS:
        values = {seed: _sets(seed)[name] for seed in RUNS if name in _sets(seed)}
        for seed, entry in values.items():
            metrics = entry["metrics"][protocol]
            lines.append(_row([name, seed, entry["images"], f"{entry['tools']} ({entry['novel_tools']})",
                               *[f"{100 * metrics[key]:.1f}" for key in METRICS]]))
        if len(values) > 1:
            lines.append(_row([name, "mean", "", "", *[
                f"{100 * np.mean([entry['metrics'][protocol][key] for entry in values.values()]):.1f}"
                for key in METRICS]]))
    return lines


def gap(protocol: str = "ours") -> list[str]:
    lines = ["", f"Gap to the seen tools, {protocol} protocol (points; minus: lower than on seen tools)", "",
             _row(["test set", "seed", *METRICS]), _row(["---"] * (2 + len(METRICS)))]
    for name in SETS[1:]:
        differences = {}
        for seed in RUNS:
            sets = _sets(seed)
            if name in sets:
                differences[seed] = [100 * (sets[name]["metrics"][protocol][key]
                                            - sets["seen"]["metrics"][protocol][key]) for key in METRICS]
                lines.append(_row([name, seed, *[f"{value:+.1f}" for value in differences[seed]]]))
        if len(differences) > 1:
            lines.append(_row([name, "mean", *[f"{value:+.1f}" for value in np.mean(list(differences.values()), 0)]]))
    return lines


def categories(metric: str = "AP-G", protocol: str = "ours") -> list[str]:
    seen_names = list(_sets(0)["seen"]["metrics"][protocol][metric])
    lines = ["", f"{metric} per category, {protocol} protocol, mean of the seeds holding the set (percent)", "",
             _row(["category", *SETS, "novel minus seen", "authors minus seen"]), _row(["---"] * 6)]
    for category in seen_names:
        means = {}
        for name in SETS:
            values = [_sets(seed)[name]["metrics"][protocol][metric].get(category)
                      for seed in RUNS if name in _sets(seed)]
            values = [value for value in values if value is not None]
            means[name] = 100 * float(np.mean(values)) if values else None
        cells = [f"{means[name]:.1f}" if means[name] is not None else "-" for name in SETS]
        gaps = [f"{means[name] - means['seen']:+.1f}" if means[name] is not None else "-" for name in SETS[1:]]
        lines.append(_row([category, *cells, *gaps]))
    return lines


def _outcomes(table: dict, metric: str) -> list[np.ndarray]:
    """Each task's trials as 0 / 1 from its rate and count (the order of the trials does not matter)."""
    columns = []
    for task, entry in table.items():
        if task not in SUMMARIES:
            successes = round(entry[metric] * entry["trials"] / 100)
            columns.append(np.array([1.0] * successes + [0.0] * (entry["trials"] - successes)))
    return columns


def table3() -> list[str]:
    lines = ["", "Table III, Total row GSR-S / GSR-T (percent), 95 % interval over the trials in brackets", "",
             _row(["piles of", "seed", "trials", "oracle", "random", "TOG-CRFs"]), _row(["---"] * 6)]
    for name in (*SETS, "novel-480"):
        for seed, folder in RUNS.items():
            path = folder / f"robot-{name}.json"
            if not path.is_file():
                continue
            tables = json.loads(path.read_text())["table3"]
            cells = []
            for table in tables.values():
                bounds = [summary_intervals(_outcomes(table, metric))["Total"] for metric in ("gsr_s", "gsr_t")]
                cells.append(f"{table['Total']['gsr_s']:.1f} [{bounds[0][0]:.1f}, {bounds[0][1]:.1f}] / "
                             f"{table['Total']['gsr_t']:.1f} [{bounds[1][0]:.1f}, {bounds[1][1]:.1f}]")
            lines.append(_row([name, seed, next(iter(tables.values()))["Total"]["trials"], *cells]))
    return lines


def main() -> None:
    lines = [*table2(), *gap(), *gap("lab"), *categories(), *table3()]
    (HERE / "summary.txt").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
