"""The grasps stage on the part-labelled fixture tools (tests/helpers.py)."""

from __future__ import annotations

import hashlib

import manifold3d
import numpy as np
import pyarrow as pa
import pytest
import trimesh
from helpers import block_parts, fixture_models, hammer_parts, model_row, screwdriver_parts, write_models
from scipy.spatial.transform import Rotation

from osgd.config import ConfigError, build_config
from osgd.contract.schemas import CHECKS, GRASPS, vectors_from_arrow
from osgd.contract.taxonomy import CATEGORIES, CATEGORY_TASK, PART_INDEX, TASKS
from osgd.grasps.antipodal import ContactPairs, spread_order, thin_pairs
from osgd.grasps.geometry import closing_region
from osgd.grasps.labels import DEFAULT_RULES, LabelRule, holding_parts, label_grasp, tool_axis
from osgd.grasps.pictures import show_grasps
from osgd.grasps.stage import GraspsStage, GraspsStageParams
from osgd.gripper import PANDA
from osgd.stage import PlannedShard, WorkItem, run_stage
from osgd.store import ShardStore

STAGE = GraspsStage()


def run_grasps(store: ShardStore, rows: list[dict], params: GraspsStageParams | None = None, seed: int = 0,
               item_id: str = "fixture"):
    """Write ``rows`` as one models shard and run the grasps stage on it."""
    models_key = write_models(store, rows, key=hashlib.sha256(item_id.encode()).hexdigest())
    upstream = {"models": [PlannedShard(WorkItem(item_id, {}), models_key)]}
    shards = STAGE.planned(params or GraspsStageParams(), seed, upstream)
    report = run_stage(STAGE, shards, store)
    assert report.ok, report.failures
    return report


@pytest.fixture(scope="module")
def fixture_run(tmp_path_factory):
    store = ShardStore(tmp_path_factory.mktemp("grasps"))
    rows = fixture_models()
    report = run_grasps(store, rows)
    grasps = store.read("grasps", report.records[0].key)
    return store, rows, report, grasps


def grasps_of(grasps: pa.Table, model_id: str) -> pa.Table:
    return grasps.filter(pa.compute.equal(grasps.column("model_id"), model_id))


def poses(grasps: pa.Table) -> tuple[np.ndarray, np.ndarray]:
    """Positions (G, 3) and rotation matrices (G, 3, 3) of the gripper frames."""
    positions = vectors_from_arrow(grasps.column("position"))
    rotations = Rotation.from_quat(vectors_from_arrow(grasps.column("quaternion"), 4)).as_matrix()
    return positions, rotations


def box_manifold(centre: np.ndarray, half: np.ndarray, position: np.ndarray, rotation: np.ndarray):
    """A gripper-frame box placed in the object frame, as a manifold."""
    transform = np.zeros((3, 4))
    transform[:, :3] = rotation
    transform[:, 3] = position + rotation @ centre
    return manifold3d.Manifold.cube(tuple(2 * half), True).transform(transform)


def part_manifolds(parts: list[tuple[str, trimesh.Trimesh]]) -> list[tuple[str, manifold3d.Manifold]]:
    return [(name, manifold3d.Manifold.hull_points(np.asarray(mesh.vertices))) for name, mesh in parts]


# -- plan -----------------------------------------------------------------------------------------------------------
def test_plan_has_one_item_per_models_shard_with_the_same_id():
    upstream = {"models": [PlannedShard(WorkItem(name, {}), f"{index:064x}")
                           for index, name in enumerate(["hammer_001", "knife_003", "procedural/pen_02"])]}
    items = STAGE.plan(GraspsStageParams(), 7, upstream)
    assert [item.item_id for item in items] == ["hammer_001", "knife_003", "procedural/pen_02"]
    assert [item.inputs for item in items] == [{"models": (shard.key,)} for shard in upstream["models"]]
    changed = STAGE.planned(GraspsStageParams(approach_count=4), 7, upstream)
    assert {shard.key for shard in changed}.isdisjoint(shard.key for shard in STAGE.planned(GraspsStageParams(), 7,
                                                                                            upstream))


def test_an_empty_models_shard_gives_an_empty_grasps_shard(tmp_path):
    store = ShardStore(tmp_path)
    report = run_grasps(store, [], item_id="rejected_model")
    assert report.records[0].item_id == "rejected_model"
    table = store.read("grasps", report.records[0].key)
    assert table.num_rows == 0
    assert table.schema.equals(GRASPS)


# -- labels ---------------------------------------------------------------------------------------------------------
def test_label_grasp_applies_the_rule_in_order():
    rule = DEFAULT_RULES["hammer"]
    handle, head = PART_INDEX["handle"], PART_INDEX["head"]
    assert label_grasp("hammer", rule, np.array([handle]), {handle: 0.0, head: 0.05}) == "hammer"
    # On the handle but too close to the heavy end: not a hammer grasp, and not a hand over either.
    assert label_grasp("hammer", rule, np.array([handle]), {handle: 0.0, head: 0.02}) == "no task"
    assert label_grasp("hammer", rule, np.array([head]), {head: 0.0, handle: 0.02}) == "hand over"
    assert label_grasp("hammer", rule, np.array([head]), {head: 0.0, handle: 0.005}) == "no task"
    assert label_grasp("hammer", rule, np.array([handle, head]), {handle: 0.0, head: 0.0}) == "no task"
    assert label_grasp("hammer", rule, np.array([-1]), {-1: 0.0}) == "no task"
    assert label_grasp("hammer", rule, np.array([], dtype=int), {}) == "no task"


def test_the_split_gives_hand_over_beyond_it_and_the_task_behind_it():
    rule = DEFAULT_RULES["hammer"]
    handle, head, neck = PART_INDEX["handle"], PART_INDEX["head"], PART_INDEX["neck"]
    far = {handle: 0.0, head: 0.05}
    assert label_grasp("hammer", rule, np.array([handle]), far, position=0.3) == "hammer"
    # The front of the handle, and a part the rule does not name (paper Fig. 1: "head or neck"): hand over.
    assert label_grasp("hammer", rule, np.array([handle]), far, position=0.6) == "hand over"
    assert label_grasp("hammer", rule, np.array([neck]), {neck: 0.0, head: 0.0}, position=0.8) == "hand over"
    assert label_grasp("hammer", rule, np.array([handle, -1]), far, position=0.6) == "no task"
    # Where the handle meets the head, both held at once: no task, on either side of the split.
    assert label_grasp("hammer", rule, np.array([handle, head]), {handle: 0.0, head: 0.0}, position=0.8) == "no task"
    # The working part is hand over wherever it is; the task keeps its clearance behind the split.
    assert label_grasp("hammer", rule, np.array([head]), {head: 0.0, handle: 0.02}, position=0.4) == "hand over"
    assert label_grasp("hammer", rule, np.array([handle]), {handle: 0.0, head: 0.02}, position=0.4) == "no task"
    # Without a split (or without an axis), the parts alone decide.
    by_parts = rule.model_copy(update={"split": 1.0})
    assert label_grasp("hammer", by_parts, np.array([handle]), far, position=0.6) == "hammer"
    assert label_grasp("hammer", rule, np.array([handle]), far, position=None) == "hammer"


def _tool(parts: list[tuple[str, trimesh.Trimesh]]) -> tuple[trimesh.Trimesh, np.ndarray]:
    mesh = trimesh.util.concatenate([part for _, part in parts])
    face_parts = np.concatenate([np.full(len(part.faces), PART_INDEX[name]) for name, part in parts])
    return mesh, face_parts


def test_the_tool_axis_runs_from_the_handle_end_to_the_working_end_in_any_pose():
    mesh, face_parts = _tool(hammer_parts())  # x from -0.15 (handle end) to 0.12 (head)
    points = np.array([[-0.15, 0.0, 0.0], [-0.015, 0.0, 0.0], [0.12, 0.0, 0.0]])
    axis = tool_axis(mesh, face_parts, DEFAULT_RULES["hammer"])
    assert axis.length == pytest.approx(0.27, abs=1e-6)
    np.testing.assert_allclose(axis.position(points), [0.0, 0.5, 1.0], atol=1e-6)
    rotation = Rotation.from_rotvec([0.4, -1.1, 0.7])
    shift = np.array([0.2, -0.1, 0.05])
    turned = mesh.copy()
    transform = np.eye(4)
    transform[:3, :3], transform[:3, 3] = rotation.as_matrix(), shift
    turned.apply_transform(transform)
    turned_axis = tool_axis(turned, face_parts, DEFAULT_RULES["hammer"])
    np.testing.assert_allclose(turned_axis.position(rotation.apply(points) + shift), [0.0, 0.5, 1.0], atol=1e-6)
    # No working part, no end to tell: the parts alone decide.
    block, block_faces = _tool(block_parts())
    assert tool_axis(block, block_faces, DEFAULT_RULES["hammer"]) is None


def test_a_ring_end_behind_the_handle_is_held_like_the_handle():
    """Table I's wrench task keeps only "away from the jaws": the ring end opposite them is the task's."""
    box = trimesh.creation.box
    parts = [
        ("head", box([0.03, 0.03, 0.008], trimesh.transformations.translation_matrix([-0.085, 0, 0]))),
        ("handle", box([0.14, 0.015, 0.006])),
        ("jaws", box([0.04, 0.045, 0.008], trimesh.transformations.translation_matrix([0.09, 0, 0]))),
    ]
    mesh, face_parts = _tool(parts)
    rule = DEFAULT_RULES["wrench"]
    axis = tool_axis(mesh, face_parts, rule)
    points = mesh.triangles_center
    held = holding_parts(face_parts, points, axis, rule)
    np.testing.assert_array_equal(held[face_parts == PART_INDEX["head"]], PART_INDEX["handle"])
    np.testing.assert_array_equal(held[face_parts != PART_INDEX["head"]], face_parts[face_parts != PART_INDEX["head"]])
    by_parts = rule.model_copy(update={"split": 1.0})
    np.testing.assert_array_equal(holding_parts(face_parts, points, axis, by_parts), face_parts)


def test_the_axis_points_to_the_jaws_however_large_the_ring_end():
    """The paper authors' wrench_003: a ring end with more area than the open jaws is still the handle's side."""
    box = trimesh.creation.box
    parts = [
        ("head", box([0.06, 0.06, 0.01], trimesh.transformations.translation_matrix([-0.1, 0, 0]))),
        ("handle", box([0.14, 0.015, 0.006])),
        ("jaws", box([0.02, 0.03, 0.008], trimesh.transformations.translation_matrix([0.08, 0, 0]))),
    ]
    mesh, face_parts = _tool(parts)
    areas = mesh.area_faces
    assert areas[face_parts == PART_INDEX["head"]].sum() > 3 * areas[face_parts == PART_INDEX["jaws"]].sum()
    axis = tool_axis(mesh, face_parts, DEFAULT_RULES["wrench"])
    assert axis.direction @ [1.0, 0.0, 0.0] == pytest.approx(1.0)
    # a wrench with a ring end alone: the ring is its working end
    ring_only = [part for part in parts if part[0] != "jaws"]
    ring_mesh, ring_faces = _tool(ring_only)
    assert tool_axis(ring_mesh, ring_faces, DEFAULT_RULES["wrench"]).direction @ [1.0, 0.0, 0.0] == pytest.approx(-1.0)


def test_every_category_has_a_rule_naming_disjoint_parts():
    assert set(DEFAULT_RULES) == set(CATEGORIES)
    for rule in DEFAULT_RULES.values():
        assert rule.handle and rule.working
        assert not set(rule.handle) & set(rule.working)


def test_sampled_labels_follow_the_rules(fixture_run):
    """Task grasps hold only handle parts in the half at the handle end; hand over holds no handle part, or
    holds the tool in the half at its working end (exact volumes; the fixture tools lie along x, handle at -x)."""
    _store, rows, _report, grasps = fixture_run
    tools = {"hammer": hammer_parts(), "screwdriver": screwdriver_parts()}
    for row in rows:
        if row["category"] not in tools:
            continue
        model_grasps = grasps_of(grasps, row["model_id"])
        tasks = model_grasps.column("task").to_pylist()
        rule = DEFAULT_RULES[row["category"]]
        category_task = CATEGORY_TASK[row["category"]]
        assert {category_task, "hand over"} <= set(tasks), f"{row['name']}: {set(tasks)}"
        parts = part_manifolds(tools[row["category"]])
        low, high = np.array([mesh.bounds[:, 0] for _, mesh in tools[row["category"]]]).T
        middle = (low.min() + high.max()) / 2
        positions, rotations = poses(model_grasps)
        widths = model_grasps.column("width").to_numpy()
        held_by_the_handle = 0
        for task, position, rotation, width in zip(tasks, positions, rotations, widths, strict=True):
            region = box_manifold(np.zeros(3), closing_region(PANDA, width), position, rotation)
            touched = {name for name, part in parts if (region ^ part).volume() > 1e-12}
            if task == category_task:
                assert touched <= set(rule.handle), f"{row['name']}: a {task!r} grasp touches {touched}"
                assert position[0] < middle, f"{row['name']}: a {task!r} grasp at x = {position[0]:.3f}"
            if task == "hand over" and touched & set(rule.handle):
                assert position[0] >= middle, f"{row['name']}: a hand over grasp on the handle at {position[0]:.3f}"
                held_by_the_handle += 1
        # The hammer's handle reaches past its middle: hand over takes the front of it (paper Fig. 1).
        assert held_by_the_handle > 0 or row["category"] != "hammer"
        # The heavy end: every hammer grasp keeps its pads' region 3 cm from the head.
        if row["category"] == "hammer":
            head = dict(parts)["head"]
            for task, position, rotation, width in zip(tasks, positions, rotations, widths, strict=True):
                if task == "hammer":
                    grown = box_manifold(np.zeros(3), closing_region(PANDA, width, 0.029), position, rotation)
                    assert (grown ^ head).volume() < 1e-12


def test_a_block_with_only_a_handle_gets_only_the_category_task(fixture_run):
    _store, rows, _report, grasps = fixture_run
    block = next(row for row in rows if row["name"] == "test/block")
    tasks = set(grasps_of(grasps, block["model_id"]).column("task").to_pylist())
    assert tasks == {CATEGORY_TASK[block["category"]]}


def test_label_rules_can_be_replaced_from_the_config(tmp_path):
    document = {"pipeline": {"name": "t"},
                "grasps": {"label_rules": {"hammer": {"handle": ["head"], "working": ["handle"]}}}}
    config = build_config(document, {"grasps": GraspsStageParams})
    params = config.params["grasps"]
    assert params.label_rules["hammer"] == LabelRule(handle=("head",), working=("handle",))
    store = ShardStore(tmp_path)
    row = model_row("test/hammer", "hammer", hammer_parts())
    report = run_grasps(store, [row], params)
    grasps = store.read("grasps", report.records[0].key)
    positions, _ = poses(grasps)
    tasks = np.array(grasps.column("task").to_pylist())
    # The hammer's head is at x > 0.09: with the rule swapped, "hammer" grasps sit there.
    assert (tasks == "hammer").any()
    assert np.all(positions[tasks == "hammer", 0] > 0.07)
    with pytest.raises(ConfigError, match="unknown part"):
        build_config({"grasps": {"label_rules": {"hammer": {"handle": ["grip"], "working": ["head"]}}}},
                     {"grasps": GraspsStageParams})


# -- geometry -------------------------------------------------------------------------------------------------------
def test_no_kept_grasp_collides_with_its_object(fixture_run):
    """Exact box/part intersections (manifold3d), within the documented tolerance."""
    _store, rows, _report, grasps = fixture_run
    tools = {"test/hammer": hammer_parts(), "test/screwdriver": screwdriver_parts(), "test/block": block_parts()}
    # The test tolerates the collision margin plus 0.5 mm for sampling between vertices.
    shrink = GraspsStageParams().collision_margin + 0.0005
    for row in rows:
        parts = part_manifolds(tools[row["name"]])
        model_grasps = grasps_of(grasps, row["model_id"])
        assert model_grasps.num_rows > 0
        positions, rotations = poses(model_grasps)
        for position, rotation, width in zip(positions, rotations, model_grasps.column("width").to_numpy(),
                                             strict=True):
            for name, centre, half in PANDA.boxes(width):
                box = box_manifold(centre, half - shrink, position, rotation)
                for part_name, part in parts:
                    overlap = (box ^ part).volume()
                    assert overlap < 1e-12, f"{row['name']}: {name} overlaps the {part_name} by {overlap:.2e} m^3"


def test_sampled_grasps_are_antipodal_pairs_between_the_fingers(fixture_run):
    _store, rows, _report, grasps = fixture_run
    params = GraspsStageParams()
    for row in rows:
        mesh = trimesh.Trimesh(np.array(row["vertices"]), np.array(row["faces"]), process=False)
        model_grasps = grasps_of(grasps, row["model_id"])
        assert set(model_grasps.column("origin").to_pylist()) == {"antipodal"}
        quality = model_grasps.column("quality").to_numpy()
        assert np.all((quality >= 0) & (quality <= 1))
        contact_a = vectors_from_arrow(model_grasps.column("contact_a"))
        contact_b = vectors_from_arrow(model_grasps.column("contact_b"))
        axis = (contact_b - contact_a) / np.linalg.norm(contact_b - contact_a, axis=1, keepdims=True)
        # Both contacts on the surface, the closing line inside both friction cones.
        for contacts, sign in ((contact_a, 1.0), (contact_b, -1.0)):
            _, distance, triangles = trimesh.proximity.closest_point(mesh, contacts)
            assert np.all(distance < 1e-5)
            inward = -mesh.face_normals[triangles]
            angles = np.arccos(np.clip(np.einsum("ij,ij->i", sign * axis, inward), -1, 1))
            # Where a contact lies on an edge the nearest face may be the other one; allow a few.
            assert np.mean(angles <= np.arctan(params.friction) + 1e-6) > 0.9
        assert len(set(model_grasps.column("pair_index").to_pylist())) <= params.sampler_max_pairs
        assert np.all(model_grasps.column("width").to_numpy() <= PANDA.max_opening + 1e-12)


def test_thinning_drops_near_duplicates_keeping_the_best():
    contact_a = np.array([[0, 0, 0], [0.001, 0, 0], [0, 0, 0], [0.05, 0, 0]], dtype=float)
    contact_b = np.array([[0, 0.02, 0], [0.001, 0.02, 0], [0, 0, 0.02], [0.05, 0.02, 0]], dtype=float)
    pairs = ContactPairs(contact_a, contact_b, np.array([0.5, 0.9, 0.4, 0.1]))
    # Pair 0 duplicates the better pair 1; pair 2 shares the centre region but closes across it.
    assert thin_pairs(pairs, 0.008, 0.35).tolist() == [1, 2, 3]


def test_spread_order_starts_best_and_goes_far_first():
    centres = np.array([[0.0, 0, 0], [0.01, 0, 0], [0.2, 0, 0], [0.1, 0, 0]])
    pairs = ContactPairs(centres, centres + np.array([0, 0.02, 0]), np.array([0.2, 0.9, 0.5, 0.5]))
    order = spread_order(pairs)
    assert order[0] == 1
    assert order[1] == 2  # farthest from pair 1
    assert order[2] == 3
    assert sorted(order.tolist()) == [0, 1, 2, 3]


# -- annotated pairs ------------------------------------------------------------------------------------------------
def test_annotated_pairs_convert_with_contacts_between_the_fingers(tmp_path):
    """Hand-made pairs on the 4 x 4 x 12 cm block: midpoint, axis along the pair, opening, dropped pairs."""
    pairs = [
        {"task": "cut", "contact_a": [0.0, -0.021, 0.0], "contact_b": [0.0, 0.021, 0.0], "file": "annotations/cut.npy"},
        {"task": "hand over", "contact_a": [0.03, 0.0, 0.022], "contact_b": [0.035, 0.0, -0.022],
         "file": "annotations/hand_over.npy"},
        # 0.12 m long: wider than the gripper, reported and dropped.
        {"task": "cut", "contact_a": [-0.061, 0, 0], "contact_b": [0.061, 0, 0], "file": "annotations/cut.npy"},
    ]
    row = model_row("test/annotated_block", "knife", block_parts(), annotated_pairs=pairs)
    store = ShardStore(tmp_path)
    params = GraspsStageParams(approach_count=4)
    report = run_grasps(store, [row], params)
    grasps = store.read("grasps", report.records[0].key)
    notes = report.notes["fixture"]
    assert any("dropped 1 pair(s) of annotations/cut.npy wider" in note for note in notes), notes
    assert set(grasps.column("pair_index").to_pylist()) == {0, 1}
    assert grasps.column("grasp_id").to_pylist() == list(range(grasps.num_rows))
    assert np.all(np.isnan(grasps.column("quality").to_numpy()))
    positions, rotations = poses(grasps)
    contact_a = vectors_from_arrow(grasps.column("contact_a"))
    contact_b = vectors_from_arrow(grasps.column("contact_b"))
    widths = grasps.column("width").to_numpy()
    for index, pair_index in enumerate(grasps.column("pair_index").to_pylist()):
        pair = pairs[pair_index]
        assert grasps.column("task")[index].as_py() == pair["task"]
        assert grasps.column("origin")[index].as_py() == pair["file"]
        np.testing.assert_allclose(contact_a[index], pair["contact_a"])
        np.testing.assert_allclose(positions[index], (np.array(pair["contact_a"]) + pair["contact_b"]) / 2)
        distance = np.linalg.norm(np.subtract(pair["contact_b"], pair["contact_a"]))
        assert widths[index] == pytest.approx(distance + PANDA.clearance)
        rotation = rotations[index]
        np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-9)
        assert np.linalg.det(rotation) == pytest.approx(1.0)
        # Closing axis (gripper x) along the pair, finger A towards contact b.
        np.testing.assert_allclose(rotation[:, 0], (np.array(pair["contact_b"]) - pair["contact_a"]) / distance,
                                   atol=1e-9)
        for contact, side in ((contact_a[index], -1), (contact_b[index], 1)):
            local = rotation.T @ (contact - positions[index])
            assert side * local[0] < widths[index] / 2  # between the pads
            np.testing.assert_allclose(local[1:], 0.0, atol=1e-9)
    for pair_index in (0, 1):
        approaches = rotations[grasps.column("pair_index").to_numpy() == pair_index][:, :, 2]
        assert 1 <= len(approaches) <= 4
        # Distinct approaches, each perpendicular to the closing axis.
        assert len(np.unique(np.round(approaches, 6), axis=0)) == len(approaches)
    # Pair 0 closes along y across the 12 cm long block: of the 4 approaches around y (along +-x and +-z),
    # those along the block's length put the palm into it; the two along +-z are free.
    approaches_0 = rotations[grasps.column("pair_index").to_numpy() == 0][:, :, 2]
    np.testing.assert_allclose(np.sort(approaches_0[:, 2]), [-1.0, 1.0], atol=1e-9)


# -- determinism ----------------------------------------------------------------------------------------------------
def test_the_same_seed_gives_the_same_grasps(tmp_path):
    rows = [model_row("test/hammer", "hammer", hammer_parts())]
    params = GraspsStageParams(sampler_points=800)
    shas = []
    for folder, seed in (("a", 3), ("b", 3), ("c", 4)):
        store = ShardStore(tmp_path / folder)
        report = run_grasps(store, rows, params, seed=seed)
        shas.append((report.records[0].sha256, store.read("grasps", report.records[0].key)))
    assert shas[0][0] == shas[1][0]
    assert shas[0][1].equals(shas[1][1])
    assert not shas[0][1].equals(shas[2][1])


# -- summary and pictures -------------------------------------------------------------------------------------------
def test_summary_counts_grasps_per_category_and_task(fixture_run):
    store, rows, report, grasps = fixture_run
    text = STAGE.summary(store, report.records)
    categories = {row["model_id"]: row["category"] for row in rows}
    hammer_tasks = [task for model_id, task in zip(grasps.column("model_id").to_pylist(),
                                                   grasps.column("task").to_pylist(), strict=True)
                    if categories[model_id] == "hammer"]
    lines = text.splitlines()
    header = lines[1].split()
    hammer_line = next(line for line in lines if line.startswith("hammer"))
    cells = hammer_line.split()
    assert cells[-1] == str(len(hammer_tasks))
    assert "hand" in header  # "hand over" splits in two on whitespace
    assert lines[-1].split()[-1] == str(grasps.num_rows)
    assert set(TASKS) >= {task for task in hammer_tasks}


def test_show_grasps_by_task_and_by_stability(fixture_run, tmp_path):
    store, rows, _report, grasps = fixture_run
    hammer = next(row for row in rows if row["category"] == "hammer")
    out = tmp_path / "hammer.png"
    message = show_grasps(store, hammer["model_id"], out)
    assert out.stat().st_size > 10_000 and "grasps" in message
    show_grasps(store, "test/hammer", tmp_path / "by_name.png")
    with pytest.raises(KeyError, match="no model"):
        show_grasps(store, "nonexistent", tmp_path / "x.png")
    with pytest.raises(ValueError, match="color_by"):
        show_grasps(store, "test/hammer", tmp_path / "x.png", color_by="colour")
    checks_store = ShardStore(tmp_path / "with_checks")
    for table_name in ("models", "grasps"):
        for key in store.keys_on_disk(table_name):
            checks_store.write(table_name, key, "fixture", store.read(table_name, key))
    with pytest.raises(FileNotFoundError, match="no checks table"):
        show_grasps(checks_store, "test/hammer", tmp_path / "x.png", color_by="stability")
    hammer_grasps = grasps_of(grasps, hammer["model_id"])
    count = hammer_grasps.num_rows // 2
    checks = pa.table({
        "model_id": [hammer["model_id"]] * count,
        "grasp_id": hammer_grasps.column("grasp_id").to_pylist()[:count],
        "stable": [index % 2 == 0 for index in range(count)],
        "lift_stable": [index % 2 == 0 for index in range(count)],
        "shake_stable": [index % 2 == 0 for index in range(count)],
        "fail_reason": ["" if index % 2 == 0 else "slipped_on_lift" for index in range(count)],
        "slip_distance": [0.0] * count, "slip_rotation": [0.0] * count, "final_opening": [0.02] * count,
        "sim_steps": [100] * count,
    }, schema=CHECKS)
    checks_store.write("checks", "c" * 64, "fixture", checks)
    out = tmp_path / "stability.png"
    show_grasps(checks_store, "test/hammer", out, color_by="stability")
    assert out.stat().st_size > 10_000
