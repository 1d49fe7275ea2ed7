import sys, time, collections
from pathlib import Path
from osgd.pipeline import load_pipeline, plan_pipeline, stage_by_name
from osgd.store import ShardStore
from osgd.checks import trial as T
from osgd.physics import pybullet_module
config = load_pipeline(sys.argv[2])
items = sys.argv[3].split(",")
arms = [eval(a) for a in sys.argv[4:]]
plan = {s.item.item_id: s.item for s in plan_pipeline(config)["checks"]}
stage = stage_by_name("checks"); store = ShardStore(Path(sys.argv[1]))
orig = T._setup_world
base = None
for extra in arms:
    def setup(client, params, extra=extra):
        orig(client, params)
        if extra: pybullet_module().setPhysicsEngineParameter(physicsClientId=client, **extra)
    T._setup_world = setup
    sec = 0; steps = 0; lift = []; shake = []; reasons = collections.Counter()
    for item_id in items:
        start = time.perf_counter(); table = stage.build(plan[item_id], store).table; sec += time.perf_counter() - start
        steps += sum(table.column("sim_steps").to_pylist())
        lift += table.column("lift_stable").to_pylist(); shake += table.column("shake_stable").to_pylist()
        reasons.update(table.column("fail_reason").to_pylist())
    if base is None: base = (lift, shake)
    dl = sum(a != b for a, b in zip(lift, base[0])); ds = sum(a != b for a, b in zip(shake, base[1]))
    print(f"{extra}: {sec:.1f}s {len(lift)} trials {steps} steps {1e6*sec/steps:.0f} us/step lift {sum(lift)} shake {sum(shake)} differ lift {dl} shake {ds}", dict(reasons), flush=True)
