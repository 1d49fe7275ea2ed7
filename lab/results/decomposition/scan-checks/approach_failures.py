"""Per pipeline and model: hulls, grasps tried, and the share of each outcome of the checks (run.sh beside it).

    python lab/results/decomposition/scan-checks/approach_failures.py DATA_DIR PIPELINE [PIPELINE ...]
"""

from __future__ import annotations

import collections
import json
import sys
from pathlib import Path

import pyarrow.parquet as pq


def shards(data: Path, pipeline: str, stage: str) -> list[Path]:
    """The Parquet files of one stage of a pipeline's manifest."""
    manifest = json.loads((data / "manifests" / f"{pipeline}.json").read_text())
    return [data / stage / f"{shard['key']}.parquet" for shard in manifest["stages"][stage]["shards"]]


def main(data: Path, pipelines: list[str]) -> None:
    """Print the table of the module text, a row per pipeline and model."""
    reasons = ("approach_collision", "empty_close", "slipped_on_lift", "dropped_on_shake")
    print("| pipeline | model | hulls | grasps | lift-stable | " + " | ".join(reasons) + " |")
    print("| --- | --- | ---: | ---: | ---: |" + " ---: |" * len(reasons))
    for pipeline in pipelines:
        names, hulls = {}, {}
        for path in shards(data, pipeline, "models"):
            table = pq.read_table(path, columns=["model_id", "name", "convex_parts"])
            for row in table.to_pylist():
                names[row["model_id"]], hulls[row["model_id"]] = row["name"], len(row["convex_parts"])
        outcomes: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
        for path in shards(data, pipeline, "checks"):
            for row in pq.read_table(path, columns=["model_id", "lift_stable", "fail_reason"]).to_pylist():
                counts = outcomes[names[row["model_id"]]]
                counts["grasps"] += 1
                counts["lift_stable"] += row["lift_stable"]
                counts[row["fail_reason"]] += 1
        by_name = {name: model_id for model_id, name in names.items()}
        for name in sorted(outcomes):
            counts = outcomes[name]
            shares = [f"{100 * counts[key] / counts['grasps']:.1f} %" for key in ("lift_stable", *reasons)]
            print(f"| {pipeline} | {name} | {hulls[by_name[name]]} | {counts['grasps']} | " + " | ".join(shares) + " |")


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2:])
