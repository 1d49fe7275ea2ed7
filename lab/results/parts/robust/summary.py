"""Per category and draw: the figures of issue #70's goal from bench_parts.py JSON files (every case).

    python lab/results/parts/robust/summary.py

Columns: the authors' held-out half as it is (pairs, pooled); the authors' stress cases of the tuned and of the
held-out half (pairs, pooled); the procedural stress cases (face area, mean over cases) with the lowest case;
the cases whose parts were not found. A category meets the goal where every figure is at least 95 % and no
case is unfound. "Before" is the rules of 35dc572: its seed-0 and seed-1 runs were made with the holes case of
that commit, so their holes cases are replaced by the runs of the holes case of today (before/holes-seed*.json).
"After" is the rules of 8cc0d46. "Least width" is the rules that compare a capped pen's ends by their least
width: only the pen's cases change, so at seeds 0-3 the pen's cases of the "after" runs are replaced by runs of
the pens alone (least-width/pen-seed*.json, `--stress-categories pen`); seed 4 is a full run of each.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import NamedTuple

HERE = Path(__file__).resolve().parent
PARTS = HERE.parent
CATEGORIES = ("knife", "screwdriver", "spoon", "fork", "wrench", "hammer", "pen", "toothbrush", "spatula", "pliers")
class Run(NamedTuple):
    """One draw's cases: a bench_parts JSON, with its holes cases or its pens' cases taken from another."""

    path: Path
    holes: Path | None = None
    pens: Path | None = None


RUNS = {
    "before, seed 0": Run(PARTS / "pen-steps/bench_parts-full.json", holes=HERE / "before/before-holes-seed0.json"),
    "before, seed 1": Run(PARTS / "seed1/bench_parts-full.json", holes=HERE / "before/before-holes-seed1.json"),
    "before, seed 2": Run(HERE / "before/before-seed2.json"),
    "before, seed 3": Run(HERE / "before/before-seed3.json"),
    **{f"after, seed {seed}": Run(HERE / f"seed{seed}.json") for seed in range(4)},
    "after, seed 4": Run(HERE / "after-seed4.json"),
    **{f"least width, seed {seed}": Run(HERE / f"seed{seed}.json", pens=HERE / f"least-width/pen-seed{seed}.json")
       for seed in range(4)},
    "least width, seed 4": Run(HERE / "least-width/seed4.json"),
}


def cases(run: Run) -> list[dict]:
    records = json.loads(run.path.read_text())["cases"]
    if run.holes is not None:
        records = [r for r in records if r["variant"] != "holes"] + json.loads(run.holes.read_text())["cases"]
    if run.pens is not None:
        records = ([r for r in records if r["category"] != "pen"]
                   + [r for r in json.loads(run.pens.read_text())["cases"] if r["category"] == "pen"])
    return records


def pooled(records: list[dict]) -> float:
    total = sum(r["total"] for r in records)
    return 100 * sum(r["agree"] for r in records) / total if total else float("nan")


def row(records: list[dict], category: str) -> tuple[list[str], bool]:
    mine = [r for r in records if r["category"] == category]
    authors = [r for r in mine if r["kind"] == "authors"]
    held = pooled([r for r in authors if r["variant"] == "as is" and r["half"] == "held-out"])
    stress = {half: pooled([r for r in authors if r["variant"] != "as is" and r["half"] == half])
              for half in ("tuned", "held-out")}
    procedural = [r for r in mine if r["kind"] == "procedural"]
    mean = 100 * sum(r["score"] for r in procedural) / len(procedural)
    lowest = min(procedural, key=lambda r: r["score"])
    missed = sorted({f"{r['name']} *{r['variant']}*" for r in mine if not r["found"]})
    meets = min(held, *stress.values(), mean) >= 95 and not missed
    cells = [f"{held:.1f}%", f"{stress['tuned']:.1f}%", f"{stress['held-out']:.1f}%", f"{mean:.1f}%",
             f"{100 * lowest['score']:.0f}% ({lowest['name'].split('/')[-1]} *{lowest['variant']}*)",
             "; ".join(missed) or "-"]
    return cells, meets


def main() -> None:
    for label, run in RUNS.items():
        if not all(part.exists() for part in run if part is not None):
            print(f"{label}: a file is missing\n")
            continue
        records = cases(run)
        print(f"**{label}**\n")
        print("| category | authors held-out | stress tuned | stress held-out | procedural stress | lowest procedural "
              "| not found | goal |")
        print("| --- | ---: | ---: | ---: | ---: | --- | --- | --- |")
        failed = []
        for category in CATEGORIES:
            cells, meets = row(records, category)
            failed += [] if meets else [category]
            print(f"| {category} | " + " | ".join(cells) + f" | {'met' if meets else '**not met**'} |")
        print(f"\ngoal met in {len(CATEGORIES) - len(failed)} of {len(CATEGORIES)} categories"
              + (f" (not: {', '.join(failed)})" if failed else "") + "\n")


if __name__ == "__main__":
    main()
