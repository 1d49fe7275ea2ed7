"""The grasps stage on the paper authors' OSGD models (../shared/osgd-models).

Until the models stage's OSGD importer (osgd/models/osgd_import.py) has
landed, the ``models`` rows are built here: the OBJ is read with trimesh and
scaled to a real length (REFERENCE section 7), and the annotation points are
mapped from Blender's Z-up frame, (x, y, z) -> (x, z, -y) (REFERENCE
section 2). No part labels and no convex parts: the grasps of OSGD models
come from their hand-made pairs only.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
import trimesh
from helpers import write_models
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from osgd.contract.schemas import vectors_from_arrow
from osgd.contract.taxonomy import CATEGORIES, CATEGORY_TASK, TASKS, task_from_file_stem
from osgd.grasps.stage import GraspsStage, GraspsStageParams
from osgd.gripper import PANDA
from osgd.stage import PlannedShard, WorkItem, run_stage
from osgd.store import ShardStore

#: Middle of the real length range of each category, m (REFERENCE section 7).
REAL_LENGTH = {"knife": 0.19, "screwdriver": 0.24, "spoon": 0.21, "fork": 0.195, "wrench": 0.245,
               "hammer": 0.27, "pen": 0.135, "toothbrush": 0.18, "spatula": 0.28, "pliers": 0.23}


def osgd_row(folder: Path) -> dict:
    """A ``models`` row for one shared OSGD model (see the module text)."""
    category = folder.name.rsplit("_", 1)[0]
    mesh = trimesh.load(folder / "model" / "model_normalized.obj", force="mesh", process=False)
    scale = REAL_LENGTH[category] / float(max(mesh.extents))
    pairs = []
    for file in sorted((folder / "annotations").glob("*.npy")):
        points = np.load(file)
        points = points[: len(points) // 2 * 2]  # wrench_004/hand_over.npy has an unpaired last row
        mapped = np.stack([points[:, 0], points[:, 2], -points[:, 1]], axis=1) * scale
        pairs += [{"task": task_from_file_stem(file.stem), "contact_a": a.tolist(), "contact_b": b.tolist(),
                   "file": f"annotations/{file.name}"} for a, b in zip(mapped[0::2], mapped[1::2], strict=True)]
    return {
        "model_id": hashlib.sha256(folder.name.encode()).hexdigest()[:16], "name": folder.name,
        "category": category, "source": "osgd", "scale": scale, "length": REAL_LENGTH[category],
        "vertices": (np.asarray(mesh.vertices) * scale).tolist(),
        "faces": np.asarray(mesh.faces, dtype=np.int32).tolist(), "face_parts": [-1] * len(mesh.faces),
        "convex_parts": [], "decomposition": "{}", "density": 700.0, "mass": 0.1,
        "center_of_mass": [0.0, 0.0, 0.0], "inertia": [0.0] * 9, "friction": [0.8, 0.01, 0.01],
        "annotated_pairs": pairs, "provenance": "{}",
    }


@pytest.fixture(scope="module")
def osgd_run(tmp_path_factory):
    """One model of each category, one models shard each, through the grasps stage."""
    from helpers import OSGD_MODELS  # noqa: PLC0415

    if not OSGD_MODELS.is_dir():
        pytest.skip(f"the shared OSGD models are not at {OSGD_MODELS}")
    store = ShardStore(tmp_path_factory.mktemp("osgd_grasps"))
    rows, planned = [], []
    for category in CATEGORIES:
        folder = sorted(OSGD_MODELS.glob(f"{category}_*"))[0]
        row = osgd_row(folder)
        key = write_models(store, [row], key=hashlib.sha256(folder.name.encode()).hexdigest())
        rows.append(row)
        planned.append(PlannedShard(WorkItem(folder.name, {}), key))
    stage = GraspsStage()
    report = run_stage(stage, stage.planned(GraspsStageParams(), 0, {"models": planned}), store)
    assert report.ok, report.failures
    return store, rows, report


def test_every_category_and_task_of_the_osgd_models_is_represented(osgd_run):
    store, rows, report = osgd_run
    categories = {row["model_id"]: row["category"] for row in rows}
    seen: set[tuple[str, str]] = set()
    for record in report.records:
        grasps = store.read("grasps", record.key)
        seen |= {(categories[model_id], task) for model_id, task in
                 zip(grasps.column("model_id").to_pylist(), grasps.column("task").to_pylist(), strict=True)}
    for category in CATEGORIES:
        assert (category, CATEGORY_TASK[category]) in seen, f"no {CATEGORY_TASK[category]!r} grasp of a {category}"
        assert (category, "hand over") in seen, f"no hand over grasp of a {category}"
    # OSGD annotates the 11 tasks; "no task" comes from the sampler only.
    assert {task for _, task in seen} == set(TASKS) - {"no task"}
    summary = GraspsStage().summary(store, report.records)
    assert all(category in summary for category in CATEGORIES)


def test_osgd_pairs_become_grasps_along_the_pair(osgd_run):
    store, rows, report = osgd_run
    by_id = {row["model_id"]: row for row in rows}
    for record in report.records:
        grasps = store.read("grasps", record.key)
        assert grasps.num_rows > 0, record.item_id
        row = by_id[grasps.column("model_id")[0].as_py()]
        # Most pairs survive: the dropped ones are reported in the notes.
        kept = set(grasps.column("pair_index").to_pylist())
        assert len(kept) >= 0.6 * len(row["annotated_pairs"]), (record.item_id, report.notes.get(record.item_id))
        positions = vectors_from_arrow(grasps.column("position"))
        rotations = Rotation.from_quat(vectors_from_arrow(grasps.column("quaternion"), 4)).as_matrix()
        contact_a = vectors_from_arrow(grasps.column("contact_a"))
        contact_b = vectors_from_arrow(grasps.column("contact_b"))
        widths = grasps.column("width").to_numpy()
        assert np.all(widths <= PANDA.max_opening + 1e-12)
        axis = (contact_b - contact_a) / np.linalg.norm(contact_b - contact_a, axis=1, keepdims=True)
        np.testing.assert_allclose(rotations[:, :, 0], axis, atol=1e-9)
        np.testing.assert_allclose(positions, (contact_a + contact_b) / 2, atol=1e-12)
        for contacts, side in ((contact_a, -1), (contact_b, 1)):
            local = np.einsum("gji,gj->gi", rotations, contacts - positions)
            assert np.all(side * local[:, 0] < widths / 2)
            np.testing.assert_allclose(local[:, 1:], 0.0, atol=1e-9)


def test_wider_pairs_are_reported(osgd_run):
    _store, rows, report = osgd_run
    for row in rows:
        too_wide: dict[str, int] = {}
        for pair in row["annotated_pairs"]:
            width = np.linalg.norm(np.subtract(pair["contact_b"], pair["contact_a"])) + PANDA.clearance
            if width > PANDA.max_opening:
                too_wide[pair["file"]] = too_wide.get(pair["file"], 0) + 1
        notes = report.notes.get(row["name"], [])
        for file, count in too_wide.items():
            assert any(f"dropped {count} pair(s) of {file} wider" in note for note in notes), (row["name"], notes)
        assert sum("wider" in note for note in notes) == len(too_wide)


def test_no_kept_grasp_collides_with_its_osgd_model(osgd_run):
    """Independent dense surface samples (another seed, 4x the density) stay out of every gripper box."""
    store, rows, report = osgd_run
    shrink = GraspsStageParams().collision_margin + 0.0005
    for row in rows:
        if row["category"] not in ("knife", "hammer", "pliers"):
            continue
        mesh = trimesh.Trimesh(np.array(row["vertices"]), np.array(row["faces"]), process=False)
        count = int(4 * mesh.area / GraspsStageParams().surface_spacing**2)
        samples = np.concatenate([trimesh.sample.sample_surface(mesh, count, seed=12345)[0], mesh.vertices])
        tree = cKDTree(samples)
        record = next(record for record in report.records if record.item_id == row["name"])
        grasps = store.read("grasps", record.key)
        positions = vectors_from_arrow(grasps.column("position"))
        rotations = Rotation.from_quat(vectors_from_arrow(grasps.column("quaternion"), 4)).as_matrix()
        for position, rotation, width in zip(positions, rotations, grasps.column("width").to_numpy(), strict=True):
            local = (samples[tree.query_ball_point(position, 0.1)] - position) @ rotation
            for name, centre, half in PANDA.boxes(width):
                inside = np.all(np.abs(local - centre) < half - shrink, axis=1)
                assert not inside.any(), f"{row['name']}: {inside.sum()} surface samples inside {name}"
