"""Benchmark of the checks stage: the trial of this tree against the trial of an earlier commit, in one run.

The earlier trial is the ``osgd`` package of ``--before`` (a git ref;
default: the last commit before the trials stopped early), extracted with
``git archive`` into a temporary folder; each side runs in its own process
with its own package first on ``sys.path``, one after the other, on one core.

1. Trials per second on one core: the fixture tools (tests/helpers.py) with
   grasps across their handles and bodies, both sides on the same grasps,
   under the defaults (approach against the hulls; this tree skips the
   shakes, which cannot change ``stable`` under the ``lift`` criterion),
   with the approach against the mesh (``approach_geometry = "mesh"``, as
   ``pipelines/osgd.toml``), and with this tree's shakes run
   (``store_shake``, as the earlier trial always did); the ratio of each,
   and whether the ``lift`` outcomes of the sides are the same.
2. Unless ``--quick``: the speed and the fidelity of the two on the shared
   OSGD set (``../shared/osgd-models``, skipped when absent), with the
   settings of ``pipelines/osgd.toml``. The models and grasps stages are run
   first (their shards are kept under ``--data-dir`` and reused, and not
   timed); then every grasp of every ``--every``-th model is tried as
   annotated and made wrong three ways (:mod:`osgd.checks.validate`) by the
   earlier trial and by this tree's, with its defaults and with its shakes
   run. Prints each run's trials per second and the ratios, the share of the
   annotated grasps that hold ``lift`` and ``shake``, the share of each kind
   of wrong grasp that fails, per category and over all, and the per-grasp
   agreement of ``stable``, ``lift_stable`` and ``shake_stable`` between the
   earlier trial and this tree's with its shakes run.

Usage::

    python benchmarks/bench_checks.py [--quick] [--before REF] [--trials 150] [--every 5] [--data-dir DIR]
"""

from __future__ import annotations

import argparse
import json
import pickle
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]

#: The last commit whose trial ran every phase to its full length.
BEFORE = "8c21d9ec30808d4786389c41d8e86de33105bd33"

#: The ``[checks]`` settings of ``pipelines/osgd.toml``.
OSGD_SETTINGS = {"max_mass_ratio": 10, "approach_geometry": "mesh"}

WRONG = ("off_centre", "turned", "narrow")


# -- one side, in its own process ----------------------------------------------

def side_fixture(count: int, settings: dict[str, Any]) -> dict[str, Any]:
    """Time ``count`` fixture trials on one core (the package first on sys.path)."""
    import numpy as np  # noqa: PLC0415
    from helpers import fixture_models  # noqa: PLC0415
    from scipy.spatial.transform import Rotation  # noqa: PLC0415

    from osgd.checks.params import ChecksStageParams  # noqa: PLC0415
    from osgd.checks.trial import approach_surface, run_trial  # noqa: PLC0415
    from osgd.gripper import PANDA  # noqa: PLC0415

    params = ChecksStageParams(**settings)
    models = fixture_models()
    # Closing across each tool's thickness, approach from above, centres along the tool.
    quaternion = Rotation.from_matrix(np.column_stack([[0, 1, 0], [1, 0, 0], [0, 0, -1]])).as_quat()
    run_trial(models[2], np.zeros(3), quaternion, 0.05, params, PANDA, np.random.default_rng(0))  # warm-up
    offsets = np.random.default_rng(0).uniform(-0.1, 0.1, count)
    outcomes: dict[str, int] = defaultdict(int)
    steps = 0
    start = time.perf_counter()
    # As the stage does: each model's surface sampled once for the mesh approach (timed).
    surfaces = [approach_surface(model, params) for model in models]
    for index in range(count):
        result = run_trial(models[index % len(models)], np.array([offsets[index], 0.0, 0.0]), quaternion, 0.05,
                           params, PANDA, np.random.default_rng(index), surface=surfaces[index % len(models)])
        # The lift's outcome, which both sides decide the same way with or without the shakes.
        outcomes["stable" if result.lift_stable else result.fail_reason] += 1
        steps += result.sim_steps
    return {"seconds": time.perf_counter() - start, "trials": count, "steps": steps, "outcomes": dict(outcomes)}


def side_osgd(jobs_path: Path, settings: dict[str, Any]) -> dict[str, Any]:
    """Every variant of every grasp of the pickled jobs, serially (the package first on sys.path)."""
    from osgd.checks import validate  # noqa: PLC0415
    from osgd.checks.params import ChecksStageParams  # noqa: PLC0415

    jobs = pickle.loads(jobs_path.read_bytes())
    params = ChecksStageParams(**settings).key_dict()
    rows: list[dict[str, Any]] = []
    start = time.perf_counter()
    for done, job in enumerate(jobs, start=1):
        rows += validate._model_trials({**job, "params": params})
        print(f"\r{done}/{len(jobs)} models, {len(rows)} trials, {time.perf_counter() - start:.0f} s",
              end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    return {"seconds": time.perf_counter() - start, "rows": rows}


def run_side(code: Path, task: str, argument: str, settings: dict[str, Any]) -> dict[str, Any]:
    """Run one side's ``task`` in a fresh process whose ``osgd`` is the package under ``code``."""
    with tempfile.NamedTemporaryFile(suffix=".json") as out:
        subprocess.run([sys.executable, __file__, "--side", str(code), task, argument, json.dumps(settings),
                        out.name], check=True)
        return json.loads(Path(out.name).read_text())


# -- the comparison -----------------------------------------------------------

#: This tree's setting that runs the shakes under the ``lift`` criterion, as the earlier trial always did.
SHAKES = {"store_shake": True}

#: The fixture runs: label, settings of both sides, settings of this tree's side only.
FIXTURE_RUNS = (
    ("defaults (approach against the hulls)", {}, {}),
    ("approach against the mesh", {"approach_geometry": "mesh"}, {}),
    ("defaults, this tree's shakes run (store_shake)", {}, SHAKES),
)


def bench_fixture(before: Path, count: int) -> None:
    print("| fixture tools, one core | before trials/s | after trials/s | ratio | steps/trial before, after |")
    print("|---|---:|---:|---:|---|")
    for label, settings, after_only in FIXTURE_RUNS:
        old = run_side(before, "fixture", str(count), settings)
        new = run_side(ROOT, "fixture", str(count), {**settings, **after_only})
        old_rate, new_rate = old["trials"] / old["seconds"], new["trials"] / new["seconds"]
        print(f"| {label} | {old_rate:.1f} | {new_rate:.1f} | **{new_rate / old_rate:.2f}x** | "
              f"{old['steps'] / old['trials']:.0f}, {new['steps'] / new['trials']:.0f} |", flush=True)
        if old["outcomes"] != new["outcomes"]:
            print(f"  lift outcomes before {old['outcomes']}, after {new['outcomes']}")


def fidelity_table(old_rows: list[dict], new_rows: list[dict]) -> str:
    """Markdown: per category, both sides' annotated pass rates and wrong fail rates, and the agreement."""
    old_by = {(row["model"], row["grasp_id"], row["variant"]): row for row in old_rows}
    groups: dict[str, list[tuple[dict, dict]]] = defaultdict(list)
    for row in new_rows:
        pair = (old_by[(row["model"], row["grasp_id"], row["variant"])], row)
        groups[row["category"]].append(pair)
        groups["all"].append(pair)

    def share(pairs: list[tuple[dict, dict]], side: int, variant: str, key: str, value: bool) -> str:
        chosen = [pair[side][key] == value for pair in pairs if pair[side]["variant"] == variant]
        return f"{100 * sum(chosen) / max(len(chosen), 1):.1f}"

    lines = ["| category | grasps | annotated lift, before / after | annotated shake | "
             + " | ".join(f"{variant}: fail" for variant in WRONG)
             + " | agreement stable / lift / shake, annotated | agreement, all trials |",
             "|---|---:|---:|---:|" + "---:|" * len(WRONG) + "---:|---:|"]
    for group in [*sorted(group for group in groups if group != "all"), "all"]:
        pairs = groups[group]
        annotated = [pair for pair in pairs if pair[0]["variant"] == "annotated"]
        cells = [f"{share(pairs, 0, 'annotated', key, True)} / {share(pairs, 1, 'annotated', key, True)} %"
                 for key in ("lift", "shake")]
        cells += [f"{share(pairs, 0, variant, 'lift', False)} / {share(pairs, 1, variant, 'lift', False)} %"
                  for variant in WRONG]

        def agree(chosen: list[tuple[dict, dict]], key: str) -> str:
            return f"{100 * sum(old[key] == new[key] for old, new in chosen) / max(len(chosen), 1):.1f}"

        # stable is lift_stable under the default criterion, which both sides run.
        cells.append(" / ".join(agree(annotated, key) for key in ("lift", "lift", "shake")) + " %")
        cells.append(" / ".join(agree(pairs, key) for key in ("lift", "shake")) + " %")
        name = f"**{group}**" if group == "all" else group
        lines.append(f"| {name} | {len(annotated)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def bench_osgd(before: Path, data_dir: Path, every: int) -> None:
    sys.path.insert(0, str(ROOT))
    from osgd.checks.validate import load_grasps  # noqa: PLC0415

    jobs = load_grasps(ROOT / "pipelines" / "osgd.toml", data_dir, 1)[::every]
    with tempfile.NamedTemporaryFile(suffix=".pickle") as jobs_file:
        Path(jobs_file.name).write_bytes(pickle.dumps(jobs))
        old = run_side(before, "osgd", jobs_file.name, OSGD_SETTINGS)
        fast = run_side(ROOT, "osgd", jobs_file.name, OSGD_SETTINGS)
        shaken = run_side(ROOT, "osgd", jobs_file.name, {**OSGD_SETTINGS, **SHAKES})
    trials = len(shaken["rows"])
    grasps = sum(len(job["grasps"]) for job in jobs)
    old_rate = trials / old["seconds"]
    print(f"\nOSGD set, every {every}. model ({len(jobs)} models, {grasps} grasps x 4 sets = {trials} trials), "
          f"settings of pipelines/osgd.toml, one core each run: before {old_rate:.1f} trials/s "
          f"({old['seconds']:.0f} s)")
    for label, run in (("after, defaults", fast), ("after, shakes run (store_shake)", shaken)):
        rate = trials / run["seconds"]
        print(f"- {label}: {rate:.1f} trials/s ({run['seconds']:.0f} s): **{rate / old_rate:.2f}x**")
    same = sum(a["lift"] == b["lift"] and a["fail_reason"] in (b["fail_reason"], "dropped_on_shake")
               for a, b in zip(shaken["rows"], fast["rows"], strict=True))
    print(f"- lift outcomes of the defaults equal to those with the shakes run: {same} of {trials}\n")
    print(fidelity_table(old["rows"], shaken["rows"]))


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--side":
        code, task, argument, settings, out = sys.argv[2:7]
        sys.path[:0] = [code, str(ROOT / "tests")]
        import osgd  # noqa: PLC0415

        if not Path(osgd.__file__).is_relative_to(code):
            raise SystemExit(f"side {code}: imported osgd from {osgd.__file__}")
        result = (side_fixture(int(argument), json.loads(settings)) if task == "fixture"
                  else side_osgd(Path(argument), json.loads(settings)))
        Path(out).write_text(json.dumps(result))
        return
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--before", default=BEFORE, help="git ref of the trial to compare with")
    parser.add_argument("--trials", type=int, default=150, help="fixture trials timed on one core, each side")
    parser.add_argument("--every", type=int, default=5, help="compare every n-th of the authors' models")
    parser.add_argument("--data-dir", type=Path, default=Path(tempfile.gettempdir()) / "osgd-bench-checks")
    parser.add_argument("--quick", action="store_true", help="fixture trials only")
    arguments = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="osgd-checks-before-") as before:
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", arguments.before, "osgd"], check=False,
                                 capture_output=True)
        if archive.returncode != 0:
            raise SystemExit(f"--before {arguments.before}: not a commit of this repository's history "
                             f"({archive.stderr.decode().strip() or 'git archive failed'}); fetch it or name another")
        subprocess.run(["tar", "-x", "-C", before], input=archive.stdout, check=True)
        print(f"before: osgd of {arguments.before}; after: osgd of this tree\n")
        bench_fixture(Path(before), arguments.trials)
        osgd_models = ROOT.parent / "shared" / "osgd-models"
        if arguments.quick:
            pass
        elif osgd_models.is_dir():
            bench_osgd(Path(before), arguments.data_dir, arguments.every)
        else:
            print(f"OSGD set: skipped, the shared models are not at {osgd_models}")


if __name__ == "__main__":
    main()
