"""The recipe trained on 400 distinct tools beside the recipe (100 tools), both seed 1 on the same machine type:
Table II per test set, the gap to each model's seen tools per metric and per category, and Table III per set
of piles with each Total's 95 % interval (over the trials). The recipe's seed 0 is listed for the spread
between two seeds of one model.

Reads lab/results/recipe-novel/ (recipe, seed 0), lab/results/recipe-seed1/ (recipe, seed 1) and this folder;
writes summary.txt here. Run from the repository root: `.venv/bin/python lab/results/recipe-tools400/summary.py`.
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

HERE = Path(__file__).parent
RUNS = {"recipe s0": HERE.parent / "recipe-novel", "recipe s1": HERE.parent / "recipe-seed1", "tools400 s1": HERE}
METRICS = ("mAP", "mAP-G", "Acc-T top1", "Acc-T top5", "Acc-T top10")
SETS = ("seen", "seen100", "novel", "authors")


@cache
def _sets(run: str) -> dict:
    document = json.loads((RUNS[run] / "table2-sets.json").read_text())
    (entry,) = document["runs"].values()
    return entry["test_sets"]


def _row(cells: list) -> str:
    return "| " + " | ".join(str(cell) for cell in cells) + " |"


def table2(protocol: str = "ours") -> list[str]:
    lines = [f"Table II per test set, {protocol} protocol (percent); seen: each model's own test piles, seen100: "
             "the recipe's test piles", "", _row(["test set", "run", "images", "tools (novel)", *METRICS]),
             _row(["---"] * (4 + len(METRICS)))]
    for name in SETS:
        for run in RUNS:
            entry = _sets(run).get(name)
            if entry is not None:
                metrics = entry["metrics"][protocol]
                lines.append(_row([name, run, entry["images"], f"{entry['tools']} ({entry['novel_tools']})",
                                   *[f"{100 * metrics[key]:.1f}" for key in METRICS]]))
    return lines


def _metric(run: str, name: str, key: str, protocol: str) -> float:
    return 100 * _sets(run)[name]["metrics"][protocol][key]


def gap(protocol: str = "ours") -> list[str]:
    lines = ["", f"Gap to the model's own seen tools, {protocol} protocol (points; minus: lower than on seen tools)",
             "", _row(["test set", "run", *METRICS]), _row(["---"] * (2 + len(METRICS)))]
    for name in ("novel", "authors"):
        for run in RUNS:
            if name in _sets(run):
                lines.append(_row([name, run, *[
                    f"{_metric(run, name, key, protocol) - _metric(run, 'seen', key, protocol):+.1f}"
                    for key in METRICS]]))
    return lines


def against_recipe(protocol: str = "ours") -> list[str]:
    lines = ["", f"400 tools minus the recipe, both seed 1, {protocol} protocol (points)", "",
             _row(["test set", *METRICS]), _row(["---"] * (1 + len(METRICS)))]
    for name, recipe_name in (("seen", "seen"), ("seen100", "seen"), ("novel", "novel"), ("authors", "authors")):
        if name in _sets("tools400 s1") and recipe_name in _sets("recipe s1"):
            label = name if name == recipe_name else f"{name} (recipe: its seen)"
            lines.append(_row([label, *[
                f"{_metric('tools400 s1', name, key, protocol) - _metric('recipe s1', recipe_name, key, protocol):+.1f}"
                for key in METRICS]]))
    return lines


def categories(metric: str = "AP-G", protocol: str = "ours") -> list[str]:
    names = list(_sets("recipe s1")["seen"]["metrics"][protocol][metric])
    columns = [(run, name) for run in ("recipe s1", "tools400 s1") for name in ("seen", "novel", "authors")]
    lines = ["", f"{metric} per category, {protocol} protocol (percent)", "",
             _row(["category", *[f"{run} {name}" for run, name in columns], "novel gap recipe", "novel gap tools400"]),
             _row(["---"] * (3 + len(columns)))]
    for category in names:
        values = {(run, name): _sets(run)[name]["metrics"][protocol][metric].get(category) for run, name in columns}
        cells = [f"{100 * value:.1f}" if value is not None else "-" for value in values.values()]
        gaps = [f"{100 * (values[(run, 'novel')] - values[(run, 'seen')]):+.1f}"
                for run in ("recipe s1", "tools400 s1")]
        lines.append(_row([category, *cells, *gaps]))
    return lines


def table3() -> list[str]:
    lines = ["", "Table III, Total row GSR-S / GSR-T (percent), 95 % interval over the trials in brackets", "",
             _row(["piles of", "run", "trials", "oracle", "random", "TOG-CRFs"]), _row(["---"] * 6)]
    for name in ("seen", "novel", "authors"):
        for run in ("recipe s1", "tools400 s1"):
            path = RUNS[run] / f"robot-{name}.json"
            if not path.is_file():
                continue
            tables = json.loads(path.read_text())["table3"]
            cells = []
            for table in tables.values():
                total = table["Total"]
                cells.append(" / ".join(
                    f"{total[key]:.1f} [{total[key + '_interval'][0]:.1f}, {total[key + '_interval'][1]:.1f}]"
                    for key in ("gsr_s", "gsr_t")))
            lines.append(_row([name, run, next(iter(tables.values()))["Total"]["trials"], *cells]))
    return lines


def main() -> None:
    lines = [*table2(), *gap(), *gap("lab"), *against_recipe(), *categories(), *table3()]
    (HERE / "summary.txt").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
