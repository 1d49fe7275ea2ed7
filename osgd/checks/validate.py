"""The grasp check's fidelity, both ways, on the paper authors' annotated grasps.

Every grasp the grasps stage makes from the hand-made pairs of the authors'
models (``[models] osgd_dir`` of ``--config``, ``pipelines/osgd.toml``) is
tried as annotated and made wrong in three ways, each under both criteria
(``lift`` and ``shake``):

- ``annotated``: as the grasps stage made it;
- ``off_centre``: the grasp centre moved ``OFF_CENTRE`` further along the
  approach axis (the hand reaches past the annotated contacts: its palm
  meets a thick object, its pads pass beyond a thin one);
- ``turned``: the gripper turned about the grasp centre by the smallest
  rotation that lays its closing axis on the tool's long axis (its smallest
  box's longest side); for most grasps a turn about the approach axis, for
  the end-on ones (a pen held by its tip, approached along its length) a
  turn of the approach too;
- ``narrow``: the pre-grasp opening set to half the object's width at the
  grasp: its extent along the closing axis through the pad patches,
  measured on the mesh by rays (the annotated contacts are not always on
  the surface).

A good check passes the first set and fails the other three under both
criteria (``shake`` implies ``lift``, so failing ``lift`` fails both); the
trials run their shakes (``store_shake``) whatever the criterion.
Prints, per category and per task, the share of the annotated grasps that
hold and of each wrong set that fails, as Markdown tables, and writes every
trial's outcome and the tables as JSON.

``--physics`` prints instead the textbook probes (:mod:`osgd.checks.calibration`)
for both pad models: the grip force at which a held box slips and at which a
bar held off its centre turns, against the closed-form answers.

Usage, from the repository root::

    python -m osgd.checks.validate [--workers 2] [--data-dir DIR] [--pad-contact soft|rigid]
        [--config pipelines/osgd.toml] [--set PARAM=VALUE ...] [--json OUT.json]
    python -m osgd.checks.validate --physics
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from osgd.checks.calibration import FRICTIONS, coulomb_probe, torsion_probe
from osgd.checks.params import ChecksStageParams
from osgd.checks.stage import trial_seed
from osgd.checks.trial import approach_surface, run_trial
from osgd.contract.taxonomy import PART_INDEX
from osgd.gripper import PANDA
from osgd.models.parts import principal_frame

VARIANTS = ("annotated", "off_centre", "turned", "narrow")
#: How far ``off_centre`` moves the grasp along the approach, m.
OFF_CENTRE = 0.03


def tool_of_mass(name: str, mesh: trimesh.Trimesh, mass: float, friction: float) -> dict[str, Any]:
    """A ``models`` row of one convex part (a knife's handle) of ``mesh``, weighing ``mass`` kg, with lateral
    pad ``friction`` (spinning and rolling friction 0.01): the object of the textbook probes."""
    density = mass / mesh.volume
    digest = hashlib.sha256(mesh.vertices.tobytes() + mesh.faces.tobytes() + b"knife")
    return {
        "model_id": digest.hexdigest()[:16], "name": name, "category": "knife", "source": "test", "scale": 1.0,
        "length": float(max(mesh.extents)), "vertices": mesh.vertices.tolist(),
        "faces": mesh.faces.astype(np.int32).tolist(),
        "face_parts": [PART_INDEX["handle"]] * len(mesh.faces),
        "convex_parts": [{"vertices": mesh.vertices.tolist(), "faces": mesh.faces.astype(np.int32).tolist()}],
        "decomposition": json.dumps({"method": "primitives"}), "density": density, "mass": float(mass),
        "center_of_mass": mesh.center_mass.tolist(), "inertia": (mesh.moment_inertia * density).reshape(-1).tolist(),
        "friction": [friction, 0.01, 0.01], "annotated_pairs": [], "provenance": json.dumps({"test": name}),
    }


def bar_mesh(section: str, length: float = 0.2, thickness: float = 0.015) -> trimesh.Trimesh:
    """A bar along x, centred on the origin: a ``"square"`` or ``"round"`` section ``thickness`` across."""
    if section == "round":
        mesh = trimesh.creation.cylinder(radius=thickness / 2, height=length, sections=16)
        mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
        return mesh
    return trimesh.creation.box(extents=[length, thickness, thickness])


def width_at_grasp(mesh: trimesh.Trimesh, position: np.ndarray, quaternion: np.ndarray) -> float:
    """The object's extent along the closing axis through the pad patches, m.

    Rays along the closing axis ``x`` through a 3 x 3 grid over the patch
    (``pad_radius`` in ``y`` and ``z``); the extent of every hit within the
    gripper's reach. 0 when no ray meets the object.
    """
    rotation = Rotation.from_quat(quaternion).as_matrix()
    offsets = np.array([[0.0, dy, dz] for dy in (-1, 0, 1) for dz in (-1, 0, 1)]) * PANDA.pad_radius
    reach = PANDA.max_opening
    origins = position + (offsets - [reach, 0.0, 0.0]) @ rotation.T
    directions = np.repeat(rotation[:, 0][None, :], len(origins), axis=0)
    locations, _, _ = mesh.ray.intersects_location(origins, directions, multiple_hits=True)
    along = (np.asarray(locations).reshape(-1, 3) - position) @ rotation[:, 0]
    along = along[np.abs(along) <= reach]
    return float(np.ptp(along)) if len(along) else 0.0


def wrong_grasp(variant: str, position: np.ndarray, quaternion: np.ndarray, width: float,
                object_width: float, long_axis: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """One grasp (object frame) made wrong as ``variant`` says (module docstring)."""
    rotation = Rotation.from_quat(quaternion)
    if variant == "off_centre":
        return position + OFF_CENTRE * rotation.apply([0.0, 0.0, 1.0]), quaternion, width
    if variant == "narrow":
        return position, quaternion, 0.5 * object_width
    if variant == "turned":
        closing = rotation.apply([1.0, 0.0, 0.0])
        target = long_axis if long_axis @ closing >= 0 else -long_axis
        turn, _ = Rotation.align_vectors([target], [closing])
        return position, (turn * rotation).as_quat(), width
    return position, quaternion, width


def _model_trials(job: dict[str, Any]) -> list[dict[str, Any]]:
    """Every variant of every grasp of one model; runs in a worker process."""
    model, grasps, params, seed = job["model"], job["grasps"], ChecksStageParams(**job["params"]), job["seed"]
    mesh = trimesh.Trimesh(np.asarray(model["vertices"]), np.asarray(model["faces"]), process=False)
    long_axis = principal_frame(mesh).axes[0]
    surface = approach_surface(model, params)
    rows = []
    for grasp in grasps:
        object_width = width_at_grasp(mesh, np.asarray(grasp["position"]), np.asarray(grasp["quaternion"]))
        for variant in VARIANTS:
            position, quaternion, width = wrong_grasp(
                variant, np.asarray(grasp["position"]), np.asarray(grasp["quaternion"]), grasp["width"],
                object_width, long_axis)
            result = run_trial(model, position, quaternion, width, params, PANDA,
                               trial_seed(seed, model["model_id"], grasp["grasp_id"]), surface=surface)
            rows.append({"model": model["name"], "category": model["category"], "task": grasp["task"],
                         "grasp_id": grasp["grasp_id"], "variant": variant, "lift": result.lift_stable,
                         "shake": result.shake_stable, "fail_reason": result.fail_reason,
                         "object_width": object_width, "opening": width})
    return rows


def load_grasps(config_path: Path, data_dir: Path, workers: int) -> list[dict[str, Any]]:
    """Models and grasps of the authors' models of the pipeline at ``config_path``, built (or reused) under
    ``data_dir``."""
    from osgd.executor import make_executor  # noqa: PLC0415
    from osgd.pipeline import load_pipeline, run_stages  # noqa: PLC0415
    from osgd.store import ShardStore  # noqa: PLC0415

    config = load_pipeline(config_path)
    models_dir = config.params["models"].osgd_dir
    if not models_dir or not Path(models_dir).is_dir():
        raise SystemExit(f"the authors' models are not at {models_dir} ([models] osgd_dir of {config_path}): "
                         "nothing to validate")
    store = ShardStore(data_dir)
    reports = {report.stage: report for report in run_stages(config, store, make_executor(workers),
                                                              ["models", "grasps"])}
    models = store.read_many("models", [record.key for record in reports["models"].records]).to_pylist()
    grasps = store.read_many("grasps", [record.key for record in reports["grasps"].records]).to_pylist()
    by_model: dict[str, list[dict]] = defaultdict(list)
    for grasp in grasps:
        if grasp["origin"] != "antipodal":
            by_model[grasp["model_id"]].append(grasp)
    return [{"model": model, "grasps": by_model[model["model_id"]], "seed": config.pipeline.seed}
            for model in models if by_model[model["model_id"]]]


def rates(rows: list[dict[str, Any]], key: str) -> dict[str, dict[str, dict[str, float]]]:
    """Share passing each criterion, by ``key`` value and variant (and over all rows under "all")."""
    counts: dict[str, dict[str, list[int]]] = defaultdict(lambda: defaultdict(lambda: [0, 0, 0]))
    for row in rows:
        for group in (row[key], "all"):
            count = counts[group][row["variant"]]
            count[0] += 1
            count[1] += int(row["lift"])
            count[2] += int(row["shake"])
    return {group: {variant: {"trials": n, "lift": lift / n, "shake": shake / n}
                    for variant, (n, lift, shake) in variants.items()}
            for group, variants in counts.items()}


def table(title: str, by_group: dict[str, dict[str, dict[str, float]]]) -> str:
    """Markdown: per group, trials and lift/shake pass rates of the annotated set and each wrong set's fail rate."""
    lines = [f"| {title} | grasps | annotated: lift | annotated: shake | "
             "off-centre: fail | turned: fail | narrow: fail |", "|---|---:|---:|---:|---:|---:|---:|"]
    groups = sorted((group for group in by_group if group != "all"),
                    key=lambda group: -by_group[group]["annotated"]["lift"])
    order = [*groups, "all"]
    for group in order:
        cells = by_group[group]
        wrong = [f"{100 * (1 - cells[variant]['lift']):.1f} %" for variant in VARIANTS[1:]]
        lines.append(f"| {group} | {cells['annotated']['trials']} | {100 * cells['annotated']['lift']:.1f} % | "
                     f"{100 * cells['annotated']['shake']:.1f} % | " + " | ".join(wrong) + " |")
    return "\n".join(lines)


def validate(arguments: argparse.Namespace) -> None:
    jobs = load_grasps(arguments.config, arguments.data_dir, arguments.workers)[::arguments.every]
    overrides = dict(override.split("=", 1) for override in arguments.set)
    params = ChecksStageParams(**{"pad_contact": arguments.pad_contact, "store_shake": True, **overrides}).key_dict()
    for job in jobs:
        job["params"] = params
    start = time.perf_counter()
    rows: list[dict[str, Any]] = []
    with ProcessPoolExecutor(arguments.workers) as pool:
        for done, model_rows in enumerate(pool.map(_model_trials, jobs), start=1):
            rows += model_rows
            print(f"\r{done}/{len(jobs)} models, {len(rows)} trials, {time.perf_counter() - start:.0f} s",
                  end="", file=sys.stderr, flush=True)
    elapsed = time.perf_counter() - start
    print(file=sys.stderr)
    by_category, by_task = rates(rows, "category"), rates(rows, "task")
    print(f"{len(rows)} trials ({len(rows) // len(VARIANTS)} grasps x {len(VARIANTS)} sets of {len(jobs)} models), "
          f"pads {arguments.pad_contact} {overrides or ''}, {elapsed:.0f} s with {arguments.workers} workers: "
          f"{len(rows) / elapsed / arguments.workers:.1f} trials/s per core\n")
    print(table("category", by_category) + "\n\n" + table("task", by_task))
    failures: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    for row in rows:
        failures[f"{row['variant']}/{row['category']}"][row["fail_reason"] or "held"] += 1
    if arguments.json:
        arguments.json.parent.mkdir(parents=True, exist_ok=True)
        arguments.json.write_text(json.dumps(
            {"command": " ".join(sys.argv), "pad_contact": arguments.pad_contact, "overrides": overrides,
             "seconds": elapsed, "workers": arguments.workers, "trials": len(rows), "by_category": by_category,
             "by_task": by_task, "outcomes": failures}, indent=1, sort_keys=True))
    if arguments.trials:
        arguments.trials.write_text(json.dumps(rows))


def physics() -> None:
    """The textbook probes for both pad models."""
    print("| probe | pads | mass kg | mu | expected N | measured N | error |\n|---|---|---:|---:|---:|---:|---:|")
    for pad_contact in ("soft", "rigid"):
        params = ChecksStageParams(pad_contact=pad_contact)
        for mass in (0.2, 1.0):
            for friction in FRICTIONS:
                box = tool_of_mass("probe/box", trimesh.creation.box(extents=[0.04] * 3), mass, friction)
                probe = coulomb_probe(box, friction, params, PANDA, 0.04)
                print(f"| Coulomb, 4 cm box | {pad_contact} | {mass} | {friction} | {probe.expected:.2f} | "
                      f"{probe.measured:.2f} | {100 * probe.error:+.1f} % |")
        for section, label in (("square", "square bar"), ("round", "round rod")):
            for mass in (0.3, 0.6):
                for friction in FRICTIONS:
                    bar = tool_of_mass("probe/bar", bar_mesh(section), mass, friction)
                    probe = torsion_probe(bar, friction, 0.04, params, PANDA, 0.015)
                    print(f"| torsion, 1.5 cm {label} held 4 cm off | {pad_contact} | {mass} | {friction} | "
                          f"{probe.expected:.2f} | {probe.measured:.2f} | {100 * probe.error:+.1f} % |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--workers", type=int, default=2, help="trial processes")
    parser.add_argument("--data-dir", type=Path, default=Path(tempfile.gettempdir()) / "osgd-validate-checks",
                        help="where the models and grasps shards are built or reused")
    parser.add_argument("--config", type=Path, default=Path("pipelines") / "osgd.toml",
                        help="the pipeline whose [models] osgd_dir holds the authors' models")
    parser.add_argument("--pad-contact", choices=("soft", "rigid"), default="soft", help="the pad model to validate")
    parser.add_argument("--every", type=int, default=1, help="validate every n-th model only (a quick look)")
    parser.add_argument("--set", action="append", default=[], metavar="PARAM=VALUE",
                        help="a checks parameter other than its default (repeatable)")
    parser.add_argument("--json", type=Path, help="write the tables and every trial's outcome here")
    parser.add_argument("--trials", type=Path, help="write every trial's outcome here (JSON, a few MB)")
    parser.add_argument("--physics", action="store_true", help="print the textbook probes instead")
    arguments = parser.parse_args()
    if arguments.physics:
        physics()
    else:
        validate(arguments)


if __name__ == "__main__":
    main()
