"""The checks stage: real pybullet grasp trials on the fixture tools."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pyarrow as pa
import pytest
import trimesh
from helpers import block_parts, fixture_models, hammer_parts, model_row, write_models
from scipy.spatial.transform import Rotation

from osgd.checks import trial as trial_module
from osgd.checks.params import ChecksStageParams
from osgd.checks.stage import ChecksStage, trial_seed
from osgd.checks.summary import acceptance_counts, format_acceptance
from osgd.checks.trial import run_trial
from osgd.contract.schemas import GRASPS, MODELS
from osgd.gripper import PANDA
from osgd.stage import PlannedShard, WorkItem, run_stage
from osgd.store import ShardStore

PARAMS = ChecksStageParams()


def top_down(closing_axis: list[float]) -> np.ndarray:
    """Gripper quaternion in the object frame: approach along object -z, closing along ``closing_axis``."""
    x = np.asarray(closing_axis, dtype=np.float64)
    z = np.array([0.0, 0.0, -1.0])
    return Rotation.from_matrix(np.column_stack([x, np.cross(z, x), z])).as_quat()


ACROSS_Y = top_down([0.0, 1.0, 0.0])  # closing across the tools' thickness
ALONG_X = top_down([1.0, 0.0, 0.0])  # closing along the tools' length


def trial(model: dict, position: list[float], quaternion: np.ndarray, width: float,
          params: ChecksStageParams = PARAMS, seed: int = 0):
    return run_trial(model, np.asarray(position, dtype=np.float64), quaternion, width, params, PANDA,
                     np.random.default_rng(seed))


@pytest.fixture(scope="module")
def models() -> dict[str, dict]:
    return {row["name"].split("/")[1]: row for row in fixture_models()}


# -- grasps that hold ------------------------------------------------------------

@pytest.mark.parametrize(("name", "position", "width"), [
    ("block", [0.0, 0.0, 0.0], 0.05),  # 4 cm block, through its middle
    ("block", [0.03, 0.0, 0.0], 0.05),
    ("hammer", [-0.02, 0.0, 0.0], 0.035),  # 2.5 cm handle near the centre of mass
    ("screwdriver", [-0.06, 0.0, 0.0], 0.04),  # 3 cm handle
])
def test_grasp_through_the_middle_of_a_compact_body_is_stable(models, name, position, width) -> None:
    result = trial(models[name], position, ACROSS_Y, width)
    assert result.stable, result
    assert result.fail_reason == ""
    assert result.slip_distance < PARAMS.max_slip_distance
    # The pads end on the object: the opening is its thickness, not zero.
    thickness = {"block": 0.04, "hammer": 0.025, "screwdriver": 0.03}[name]
    assert result.final_opening == pytest.approx(thickness, abs=0.004)
    assert result.sim_steps > 0


# -- grasps that cannot hold, and why ----------------------------------------------

def test_grasp_beside_the_object_closes_empty(models) -> None:
    result = trial(models["block"], [0.0, 0.07, 0.0], ACROSS_Y, 0.05)
    assert not result.stable
    assert result.fail_reason == "empty_close"
    assert result.final_opening < PARAMS.min_opening


def test_fingertips_closing_on_a_single_face_close_empty(models) -> None:
    # Grasp centre above the top face: the fingertips end 1 mm above it, both
    # pads on the same side of the object; they close onto each other.
    fingertip_below_centre = PANDA.finger_depth / 2
    result = trial(models["block"], [0.0, 0.0, 0.02 + fingertip_below_centre + 0.001], ACROSS_Y, 0.05)
    assert result.fail_reason == "empty_close"


def test_object_wider_than_the_hand_collides_on_approach(models) -> None:
    # Closing along the 12 cm block: it does not fit between 8 cm pads.
    result = trial(models["block"], [0.0, 0.0, 0.0], ALONG_X, PANDA.max_opening)
    assert result.fail_reason == "approach_collision"
    assert result.sim_steps == 0


def test_pre_grasp_opening_narrower_than_the_object_collides_on_approach(models) -> None:
    result = trial(models["block"], [0.0, 0.0, 0.0], ACROSS_Y, 0.03)
    assert result.fail_reason == "approach_collision"


# -- the approach on the hulls and on the mesh ---------------------------------------

MESH_APPROACH = ChecksStageParams(approach_geometry="mesh")
HULLS = ChecksStageParams(approach_geometry="hulls")


def prongs_row(filled: bool) -> dict:
    """Two 8 mm prongs along x, 32 mm apart, on a base: the tines of a fork with one gap.

    ``filled``: the collision shape is the convex hull of the whole tool, as
    a coarse decomposition makes it, which fills the gap.
    """
    box = trimesh.creation.box
    parts = [("handle", box([0.04, 0.048, 0.01], [[1, 0, 0, -0.04], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]))]
    parts += [("tines", box([0.08, 0.008, 0.01], [[1, 0, 0, 0.02], [0, 1, 0, y], [0, 0, 1, 0], [0, 0, 0, 1]]))
              for y in (-0.02, 0.02)]
    row = model_row("prongs", "fork", parts)
    if filled:
        hull = trimesh.util.concatenate([mesh for _, mesh in parts]).convex_hull
        row["convex_parts"] = [{"vertices": hull.vertices.tolist(), "faces": hull.faces.tolist()}]
        # The same mesh, another decomposition: the process must not reuse the exact parts' collision file.
        row["decomposition"] = json.dumps({"method": "convex_hull"})
    return row


def test_mesh_approach_passes_a_gap_that_the_hulls_fill() -> None:
    # One prong grasped across y: finger A goes down into the gap.
    prong = ([0.03, 0.02, 0.0], ACROSS_Y, 0.018)
    assert trial(prongs_row(filled=True), *prong).fail_reason == "approach_collision"
    assert trial(prongs_row(filled=False), *prong).stable
    for filled in (True, False):
        assert trial(prongs_row(filled), *prong, params=MESH_APPROACH).fail_reason != "approach_collision"
    # Both tests still see the prong itself: a pre-grasp opening narrower than it.
    narrow = ([0.03, 0.02, 0.0], ACROSS_Y, 0.004)
    assert trial(prongs_row(filled=False), *narrow, params=MESH_APPROACH).fail_reason == "approach_collision"


def roof_row() -> dict:
    """A 15 mm bar along x with a plate 6 cm above it, joined by a post 8 cm off the grasp."""
    box = trimesh.creation.box
    def at(x, z):
        return [[1, 0, 0, x], [0, 1, 0, 0], [0, 0, 1, z], [0, 0, 0, 1]]
    return model_row("roofed", "knife", [("handle", box([0.2, 0.015, 0.015], at(0.0, 0.0))),
                                         ("handle", box([0.01, 0.015, 0.07], at(0.08, 0.035))),
                                         ("handle", box([0.1, 0.1, 0.005], at(0.0, 0.0725)))])


@pytest.mark.parametrize("params", [PARAMS, MESH_APPROACH], ids=["hulls", "mesh"])
def test_approach_sweeps_the_path_not_only_the_grasp_pose(params) -> None:
    # At the grasp pose the palm ends below the plate; on the way in it crosses it.
    roofed = roof_row()
    assert trial(roofed, [0.0, 0.0, 0.0], ACROSS_Y, 0.025, params=params).fail_reason == "approach_collision"
    short = params.model_copy(update={"approach_distance": 0.0})
    assert trial(roofed, [0.0, 0.0, 0.0], ACROSS_Y, 0.025, params=short).fail_reason != "approach_collision"


def test_heavy_slippery_block_slips_on_lift() -> None:
    # 0.58 kg at friction 0.05: two pads at 40 N hold at most 4 N < 5.7 N of weight.
    block = model_row("slippery", "knife", block_parts(), density=3000.0, friction=(0.05, 0.01, 0.01))
    result = trial(block, [0.0, 0.0, 0.0], ACROSS_Y, 0.05)
    assert result.fail_reason == "slipped_on_lift"
    assert result.slip_distance > PARAMS.max_slip_distance


def test_heavy_head_held_at_the_handle_end_slips() -> None:
    hammer = model_row("heavy", "hammer", hammer_parts(), density=8000.0)
    end = trial(hammer, [-0.14, 0.0, 0.0], ACROSS_Y, 0.035)
    assert end.fail_reason == "slipped_on_lift"
    # The head's weight turns the hammer about the closing axis.
    assert end.slip_rotation > PARAMS.max_slip_rotation


def test_violent_shake_drops_what_the_lift_keeps() -> None:
    block = model_row("grippy", "knife", block_parts(), density=3000.0, friction=(0.2, 0.01, 0.01))
    gentle = trial(block, [0.0, 0.0, 0.0], ACROSS_Y, 0.05)
    assert gentle.stable, gentle
    # 8 cm in 0.25 s: a peak acceleration of about 5 g.
    violent = trial(block, [0.0, 0.0, 0.0], ACROSS_Y, 0.05,
                    ChecksStageParams(shake_distance=0.08, store_shake=True))
    assert violent.fail_reason == "dropped_on_shake"


def test_under_the_lift_criterion_the_shakes_run_only_where_asked_for(models) -> None:
    """They cannot change ``stable`` under ``lift``: skipped, the lift's outcome is the same and costs fewer steps."""
    block = model_row("grippy", "knife", block_parts(), density=3000.0, friction=(0.2, 0.01, 0.01))
    heavy = model_row("heavy", "hammer", hammer_parts(), density=8000.0)
    grasps = [(block, [0.0, 0.0, 0.0], 0.05), (models["hammer"], [-0.02, 0.0, 0.0], 0.035),
              (heavy, [-0.14, 0.0, 0.0], 0.035)]
    for model, position, width in grasps:
        skipped = trial(model, position, ACROSS_Y, width)
        shaken = trial(model, position, ACROSS_Y, width, ChecksStageParams(store_shake=True))
        assert (skipped.stable, skipped.lift_stable) == (shaken.stable, shaken.lift_stable)
        if shaken.lift_stable:
            assert skipped.shake_stable is None and skipped.fail_reason == ""
            assert skipped.sim_steps < shaken.sim_steps
        else:
            assert (skipped.shake_stable, skipped.fail_reason) == (False, shaken.fail_reason)
            assert skipped.sim_steps == shaken.sim_steps
    assert [trial(model, position, ACROSS_Y, width).lift_stable for model, position, width in grasps] == [
        True, True, False]


# -- trials that stop once their outcome is known -----------------------------------

FULL_HOLD = ChecksStageParams(hold_still_duration=0.0)


@pytest.fixture
def full_length(monkeypatch):
    """The trial with every phase run to its end: no grip tests in the lift and hold, the whole hold."""
    def run(model: dict, position: list[float], quaternion: np.ndarray, width: float) -> object:
        with monkeypatch.context() as patch:
            patch.setattr(trial_module, "_HOLD_CHECK_INTERVAL", 10**9)
            return trial(model, position, quaternion, width, FULL_HOLD)
    return run


def test_an_object_lost_on_the_lift_ends_the_trial_there(full_length) -> None:
    block = model_row("slippery", "knife", block_parts(), density=3000.0, friction=(0.05, 0.01, 0.01))
    early = trial(block, [0.0, 0.0, 0.0], ACROSS_Y, 0.05)
    full = full_length(block, [0.0, 0.0, 0.0], ACROSS_Y, 0.05)
    assert early.fail_reason == full.fail_reason == "slipped_on_lift"
    assert early.sim_steps < full.sim_steps
    assert not early.lift_stable and not early.shake_stable


def test_a_still_object_ends_the_hold_early_with_the_outcome_of_the_full_hold(models, full_length) -> None:
    for name, position, width in (("block", [0.0, 0.0, 0.0], 0.05), ("hammer", [-0.02, 0.0, 0.0], 0.035)):
        early = trial(models[name], position, ACROSS_Y, width)
        full = full_length(models[name], position, ACROSS_Y, width)
        assert (early.stable, early.lift_stable, early.shake_stable, early.fail_reason) == (
            full.stable, full.lift_stable, full.shake_stable, full.fail_reason), name
        # The hold of 24 steps at 1/240 s ends after 8.
        assert full.sim_steps - early.sim_steps == 16, name


def test_a_grasp_that_hits_the_mesh_on_the_approach_builds_no_world(models, monkeypatch) -> None:
    def no_world(*_args, **_kwargs):
        raise AssertionError("a world was set up for a grasp that the geometry rejects")

    monkeypatch.setattr(trial_module, "_setup_world", no_world)
    result = trial(models["block"], [0.0, 0.0, 0.0], ACROSS_Y, 0.03, MESH_APPROACH)
    assert result.fail_reason == "approach_collision"
    assert result.sim_steps == 0
    assert result.final_opening == PANDA.max_opening


def test_same_seed_same_result_regardless_of_earlier_trials(models) -> None:
    hammer = models["hammer"]
    first = trial(hammer, [-0.08, 0.0, 0.0], ACROSS_Y, 0.035, seed=5)
    trial(models["block"], [0.0, 0.0, 0.0], ACROSS_Y, 0.05)  # other work in the same client
    again = trial(hammer, [-0.08, 0.0, 0.0], ACROSS_Y, 0.035, seed=5)
    assert dataclasses.asdict(first) == dataclasses.asdict(again)


# -- the stage ---------------------------------------------------------------------

def grasp_rows(model: dict, grasps: list[tuple[list[float], np.ndarray, float, str]]) -> list[dict]:
    rows = []
    for grasp_id, (position, quaternion, width, task) in enumerate(grasps):
        closing = Rotation.from_quat(quaternion).apply([1.0, 0.0, 0.0])
        rows.append({
            "model_id": model["model_id"], "grasp_id": grasp_id, "task": task,
            "position": list(position), "quaternion": quaternion.tolist(), "width": width,
            "contact_a": (np.asarray(position) - closing * width / 2).tolist(),
            "contact_b": (np.asarray(position) + closing * width / 2).tolist(),
            "origin": "test", "pair_index": grasp_id, "quality": float("nan"),
        })
    return rows


HAND_MADE = {
    "block": [([0.0, 0.0, 0.0], ACROSS_Y, 0.05, "cut"), ([0.0, 0.07, 0.0], ACROSS_Y, 0.05, "hand over"),
              ([0.0, 0.0, 0.0], ALONG_X, 0.08, "cut")],
    "hammer": [([-0.02, 0.0, 0.0], ACROSS_Y, 0.035, "hammer"), ([0.05, 0.0, 0.0], ACROSS_Y, 0.035, "hand over")],
    "screwdriver": [([-0.06, 0.0, 0.0], ACROSS_Y, 0.04, "screw")],
}


def planned_upstream(store: ShardStore, models: dict[str, dict]) -> dict[str, list[PlannedShard]]:
    """One models shard and one grasps shard per fixture model, paired by item id."""
    upstream: dict[str, list[PlannedShard]] = {"models": [], "grasps": []}
    for number, (name, model) in enumerate(sorted(models.items())):
        models_key = write_models(store, [model], key=f"{number:064x}")
        grasps_key = f"{number + 100:064x}"
        store.write("grasps", grasps_key, name, pa.Table.from_pylist(grasp_rows(model, HAND_MADE[name]), schema=GRASPS))
        upstream["models"].append(PlannedShard(WorkItem(name, {}), models_key))
        upstream["grasps"].append(PlannedShard(WorkItem(name, {}, {"models": (models_key,)}), grasps_key))
    # An empty models shard (a rejected model) and its empty grasps shard.
    empty_models = store.write("models", "e" * 64, "rejected", MODELS.empty_table())
    empty_grasps = store.write("grasps", "f" * 64, "rejected", GRASPS.empty_table())
    upstream["models"].append(PlannedShard(WorkItem("rejected", {}), empty_models.key))
    upstream["grasps"].append(PlannedShard(WorkItem("rejected", {}), empty_grasps.key))
    return upstream


def test_stage_checks_every_grasp_resumes_and_summarises(tmp_path, models) -> None:
    models = {**models, "block": {**models["block"], "source": "user"}}  # a user's mesh, for the summary's note
    store = ShardStore(tmp_path)
    upstream = planned_upstream(store, models)
    stage = ChecksStage()
    shards = stage.planned(HULLS, 7, upstream)
    assert [shard.item.item_id for shard in shards] == ["block", "hammer", "screwdriver", "rejected"]
    for shard, models_shard, grasps_shard in zip(shards, upstream["models"], upstream["grasps"], strict=True):
        assert shard.item.inputs == {"models": (models_shard.key,), "grasps": (grasps_shard.key,)}

    report = run_stage(stage, shards, store)
    assert report.ok and report.built == 4
    rows = {shard.item.item_id: store.read("checks", shard.key).to_pylist() for shard in shards}
    assert rows["rejected"] == []
    assert [row["grasp_id"] for row in rows["block"]] == [0, 1, 2]
    assert [row["fail_reason"] for row in rows["block"]] == ["", "empty_close", "approach_collision"]
    assert [row["stable"] for row in rows["hammer"]] == [True, True]
    assert rows["screwdriver"][0]["stable"]

    # Interrupted run: one shard lost. Only that one is rebuilt, byte-identical.
    lost = shards[1]
    sha_before = store.verify("checks", lost.key).sha256
    store.shard_path("checks", lost.key).unlink()
    again = run_stage(stage, shards, store)
    assert (again.reused, again.built) == (3, 1)
    assert store.verify("checks", lost.key).sha256 == sha_before

    counts = acceptance_counts(store, again.records)
    assert counts.rate(category="knife") == (1, 3)  # the block is filed as a knife
    assert counts.rate(task="hand over") == (1, 2)
    assert counts.rate(category="hammer", task="hammer") == (1, 1)
    assert counts.fail_reasons == {"empty_close": 1, "approach_collision": 1}
    assert (counts.user_trials, counts.user_approach_collisions) == (3, 1)  # the block's trials
    text = stage.summary(store, again.records)
    assert "4 of 6 grasps stable" in text  # block 1 of 3, hammer 2 of 2, screwdriver 1 of 1
    assert "hand over" in text and "knife" in text
    # the approach swept against a user's hulls: the summary says how to sweep it against the mesh
    assert "the 3 trials on users' meshes was swept against their convex parts (1 failed it)" in text
    for geometry in ("mesh", "auto"):
        assert 'checks.approach_geometry = "mesh"' not in format_acceptance(counts, geometry)


def test_plan_leaves_out_a_models_shard_without_grasps(tmp_path, models) -> None:
    """A model whose grasps failed (left out of the grasps plan) is not checked; the others are."""
    store = ShardStore(tmp_path)
    upstream = planned_upstream(store, models)
    left_out = upstream["grasps"][0].item.item_id
    upstream["grasps"] = upstream["grasps"][1:]
    items = ChecksStage().plan(PARAMS, 0, upstream)
    assert [item.item_id for item in items] == [shard.item.item_id for shard in upstream["grasps"]]
    assert left_out not in {item.item_id for item in items}
    for item, grasps in zip(items, upstream["grasps"], strict=True):
        assert item.inputs["grasps"] == (grasps.key,)


def test_keys_follow_parameters_and_seed(tmp_path, models) -> None:
    store = ShardStore(tmp_path)
    upstream = planned_upstream(store, models)
    stage = ChecksStage()
    base = [shard.key for shard in stage.planned(PARAMS, 0, upstream)]
    assert base == [shard.key for shard in stage.planned(ChecksStageParams(), 0, upstream)]
    assert base[0] != stage.planned(PARAMS, 1, upstream)[0].key
    assert base[0] != stage.planned(ChecksStageParams(lift_height=0.2), 0, upstream)[0].key
    # Options off by default keep the keys of pipelines that leave them out.
    assert base == [shard.key for shard in stage.planned(ChecksStageParams(approach_geometry="hulls"), 0, upstream)]
    assert base[0] != stage.planned(MESH_APPROACH, 0, upstream)[0].key


def test_auto_sweeps_the_approach_of_users_meshes_against_the_mesh(tmp_path, models) -> None:
    store = ShardStore(tmp_path)
    upstream = planned_upstream(store, models)
    as_users = {**upstream, "models": [PlannedShard(WorkItem(shard.item.item_id, {"source": "user"}), shard.key)
                                       for shard in upstream["models"]]}
    stage = ChecksStage()

    def keys(params: ChecksStageParams, planned_upstream: dict) -> list[str]:
        return [shard.key for shard in stage.planned(params, 0, planned_upstream)]

    assert PARAMS.approach_geometry == "auto"
    assert [shard.item.payload["params"]["approach_geometry"] for shard in stage.planned(PARAMS, 0, as_users)] == [
        "mesh"] * len(upstream["models"])
    assert keys(PARAMS, as_users) == keys(MESH_APPROACH, as_users) != keys(PARAMS, upstream)
    # set to the hulls, users' meshes get the keys (and the trials) of every other model under auto
    assert keys(HULLS, as_users) == keys(PARAMS, upstream) == keys(HULLS, upstream)
    assert all("approach_geometry" not in shard.item.payload["params"] for shard in stage.planned(HULLS, 0, as_users))


def test_trial_seeds_depend_on_the_grasp_not_on_its_neighbours() -> None:
    first = trial_seed(3, "abc", 4).random(4)
    np.testing.assert_array_equal(first, trial_seed(3, "abc", 4).random(4))
    assert not np.array_equal(first, trial_seed(3, "abc", 5).random(4))
    assert not np.array_equal(first, trial_seed(4, "abc", 4).random(4))
