# ruff: noqa
# The harness as it ran (paths under /tmp/c73, the data of bench_checks.py --data-dir), kept verbatim.
"""Run annotated (+ wrong) grasps of a subset of OSGD models under a config; dump per-trial rows."""
import argparse
import json
import sys
import time
from pathlib import Path

ap = argparse.ArgumentParser()
ap.add_argument("--code", default="/work/main")
ap.add_argument("--every-model", type=int, default=5)
ap.add_argument("--every-grasp", type=int, default=4)
ap.add_argument("--variants", default="annotated")
ap.add_argument("--set", action="append", default=[])
ap.add_argument("--engine", default="{}")
ap.add_argument("--out")
ap.add_argument("--objkw", default="{}")
ap.add_argument("--objdyn", default="{}")
ap.add_argument("--jitter", type=float, default=0.0)
a = ap.parse_args()
sys.path.insert(0, a.code)
import numpy as np
import trimesh

import osgd.checks.trial as T
import osgd.checks.validate as V

assert T.__file__.startswith(a.code), T.__file__
from osgd.checks.params import ChecksStageParams
from osgd.checks.stage import trial_seed
from osgd.gripper import PANDA
from osgd.models.parts import principal_frame

engine = json.loads(a.engine)
if engine:
    from osgd.physics import pybullet_module
    pb = pybullet_module(); orig = T._setup_world
    def setup(client, params):
        orig(client, params); pb.setPhysicsEngineParameter(physicsClientId=client, **engine)
    T._setup_world = setup
objkw = json.loads(a.objkw); objdyn = json.loads(a.objdyn)
if objkw or objdyn:
    from osgd.physics import pybullet_module
    _pb = pybullet_module(); _orig_create = T.create_object_body
    def _create(client, model, *args, **kw):
        body = _orig_create(client, model, *args, **{**kw, **objkw})
        if objdyn: _pb.changeDynamics(body.body_id, -1, physicsClientId=client, **objdyn)
        return body
    T.create_object_body = _create
import logging; logging.disable(logging.WARNING)
jobs = V.load_grasps(Path("/work/main/pipelines/osgd.toml"), Path("/tmp/c73/data"), 1)[::a.every_model]
overrides = dict(s.split("=", 1) for s in a.set)
params = ChecksStageParams(max_mass_ratio=10, approach_geometry="mesh", **overrides)
variants = a.variants.split(",")
rows = []; t0 = time.perf_counter(); steps = 0
for job in jobs:
    model = job["model"]
    mesh = trimesh.Trimesh(np.asarray(model["vertices"]), np.asarray(model["faces"]), process=False)
    long_axis = principal_frame(mesh).axes[0]
    surface = T.approach_surface(model, params)
    for grasp in job["grasps"][::a.every_grasp]:
        ow = V.width_at_grasp(mesh, np.asarray(grasp["position"]), np.asarray(grasp["quaternion"])) if variants != ["annotated"] else 0
        for variant in variants:
            p, q, w = V.wrong_grasp(variant, np.asarray(grasp["position"]), np.asarray(grasp["quaternion"]), grasp["width"], ow, long_axis)
            p = p + a.jitter
            r = T.run_trial(model, p, q, w, params, PANDA, trial_seed(0, model["model_id"], grasp["grasp_id"]), surface=surface)
            steps += r.sim_steps
            rows.append({"key": f"{model['name']}/{grasp['grasp_id']}/{variant}", "cat": model["category"], "variant": variant,
                         "lift": r.lift_stable, "shake": r.shake_stable, "fail": r.fail_reason, "steps": r.sim_steps})
el = time.perf_counter() - t0
print(f"{a.set} {a.engine} code={a.code}: {len(rows)} trials {el:.0f} s {len(rows)/el:.2f} trials/s {steps/len(rows):.0f} steps/trial {1e6*el/steps:.0f} us/step"
      f" lift {np.mean([r['lift'] for r in rows]):.3f} shake {np.mean([r['shake'] for r in rows]):.3f}", flush=True)
if a.out: Path(a.out).write_text(json.dumps({"elapsed": el, "rows": rows}))
