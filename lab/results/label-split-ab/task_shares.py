"""Share of each task among the ground-truth grasps of a pipeline's test samples, for each labelling of the A/B.

The most frequent task's share is what a detector that always says that task would score on Acc-T top-1 (roughly:
Acc-T judges the top grasp of each matched RoI against the task of its ground truth): the floor each arm's Acc-T is
read against. Run from the repository root after run.sh::

    python lab/results/label-split-ab/task_shares.py data/manifests/recipe.json \
        runs/label-ab/parts-data/manifests/recipe.json
"""

from __future__ import annotations

import collections
import json
import sys
from pathlib import Path

import pyarrow.parquet as pq


def task_shares(manifest: Path, samples: Path) -> tuple[int, dict[str, float]]:
    """(number of test grasps, percent per task, most frequent first)."""
    counts: collections.Counter[str] = collections.Counter()
    for shard in json.loads(manifest.read_text())["stages"]["samples"]["shards"]:
        table = pq.read_table(samples / f"{shard['key']}.parquet", columns=["split", "grasps"])
        for split, grasps in zip(table.column("split").to_pylist(), table.column("grasps").to_pylist(), strict=True):
            if split == "test":
                counts.update(grasp["task"] for grasp in grasps)
    total = sum(counts.values())
    return total, {task: 100.0 * count / total for task, count in counts.most_common()}


if __name__ == "__main__":
    for path in sys.argv[1:]:
        total, shares = task_shares(Path(path), Path("data/samples"))
        print(f"{path}: {total} test grasps; " + ", ".join(f"{task} {share:.1f} %" for task, share in shares.items()))
