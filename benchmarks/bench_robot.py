"""Cost of one robot trial: pile, render, inference on the CPU, execution, on one core.

Runs ``togcrf robot-eval`` on a reduced protocol (one trial per tool task and
two per named task: 14 trials) with one worker process and no pictures, in a
child process, and prints the seconds per trial and the child's peak
resident memory. The goal is under 3 s per trial on one core, so that the
full protocol (160 trials) of a ResNet-18 model fits 10 minutes on 2 cores.

It needs a trained checkpoint and the data of its pipeline (by default
those of ``make table``: TOG trained on ``pipelines/recipe-pairs96.toml``);
without them it says so and exits 0 (so that ``make bench`` runs on a fresh
clone)::

    python benchmarks/bench_robot.py --checkpoint runs/table2/tog/checkpoint.pt \\
        --config pipelines/recipe-pairs96.toml --data data
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", type=Path, default=ROOT / "runs/table2/tog/checkpoint.pt")
    parser.add_argument("--config", type=Path, default=ROOT / "pipelines/recipe-pairs96.toml")
    parser.add_argument("--data", type=Path, default=ROOT / "data")
    arguments = parser.parse_args()
    manifest = arguments.data / "manifests" / f"{arguments.config.stem}.json"
    if not arguments.checkpoint.is_file() or not manifest.is_file():
        print(f"skipped: needs {arguments.checkpoint} and {manifest} (the CPU recipe's run and data: "
              "docs/togcrf-evaluation.md)")
        return 0
    with tempfile.TemporaryDirectory() as out:
        command = [sys.executable, "-m", "togcrf", "robot-eval", str(arguments.checkpoint), "--baselines", "",
                   "--config", str(arguments.config), "--data", str(arguments.data), "--out", out,
                   "--tool-trials", "1", "--named-trials", "2", "--workers", "1", "--no-pictures"]
        started = time.perf_counter()
        subprocess.run(command, check=True, cwd=ROOT, capture_output=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
        seconds = time.perf_counter() - started
        document = json.loads((Path(out) / "table3.json").read_text())
        trials = document["trials"]
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(f"robot trials: {trials} in {seconds:.1f} s on one core, {seconds / trials:.2f} s per trial "
          f"(goal < 3 s; start-up included); peak RSS {peak:.0f} MiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
