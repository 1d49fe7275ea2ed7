"""Solver settings against the checks stage as it is, on whole checks items of a built pipeline (issue #22).

Each arm rebuilds the items with one change and compares every grasp's lift and shake outcome with the
first arm's. Arms: "base"; "residual=X" (pybullet's solverResidualThreshold X for the whole trial);
"iterations=N" (numSolverIterations N from the lift on, after the fingers have closed).

    python lab/results/checks-speed/ab_solver.py DATA pipelines/osgd.toml osgd/fork_007,osgd/hammer_003 \
        base residual=1e-6 residual=1e-5 residual=1e-4 base
    python lab/results/checks-speed/ab_solver.py DATA pipelines/osgd.toml \
        osgd/fork_007,osgd/hammer_003,osgd/pen_003 base iterations=50 iterations=30
"""
import collections
import sys
import time
from pathlib import Path

from osgd.checks import trial
from osgd.physics import pybullet_module
from osgd.pipeline import load_pipeline, plan_pipeline, stage_by_name
from osgd.store import ShardStore

data_dir, config_path, item_ids, *arms = sys.argv[1:]
plan = {shard.item.item_id: shard.item for shard in plan_pipeline(load_pipeline(config_path))["checks"]}
stage, store = stage_by_name("checks"), ShardStore(Path(data_dir))
setup_world, lift = trial._setup_world, trial._lift


def with_arm(arm: str) -> None:
    trial._setup_world, trial._lift = setup_world, lift
    name, _, value = arm.partition("=")
    if name == "residual":
        def setup(client, params):
            setup_world(client, params)
            pybullet_module().setPhysicsEngineParameter(solverResidualThreshold=float(value), physicsClientId=client)
        trial._setup_world = setup
    elif name == "iterations":
        def lift_with(running):
            pybullet_module().setPhysicsEngineParameter(numSolverIterations=int(value), physicsClientId=running.client)
            return lift(running)
        trial._lift = lift_with


base = None
for arm in arms:
    with_arm(arm)
    seconds, steps, lifts, shakes, reasons = 0.0, 0, [], [], collections.Counter()
    for item_id in item_ids.split(","):
        start = time.perf_counter()
        table = stage.build(plan[item_id], store).table
        seconds += time.perf_counter() - start
        steps += sum(table.column("sim_steps").to_pylist())
        lifts += table.column("lift_stable").to_pylist()
        shakes += table.column("shake_stable").to_pylist()
        reasons.update(table.column("fail_reason").to_pylist())
    base = base or (lifts, shakes)
    changed_lift = sum(a != b for a, b in zip(lifts, base[0], strict=True))
    changed_shake = sum(a != b for a, b in zip(shakes, base[1], strict=True))
    print(f"{arm}: {seconds:.1f} s, {len(lifts)} trials, {steps} steps, {1e6 * seconds / steps:.0f} us/step; "
          f"lift {sum(lifts)}, shake {sum(shakes)}; changed against the first arm: lift {changed_lift}, "
          f"shake {changed_shake}; {dict(reasons)}", flush=True)
