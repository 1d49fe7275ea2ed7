"""The scenes stage: piles dropped until at rest, rejection, determinism, statistics."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np
import pybullet
import pytest
from helpers import block_parts, fixture_models, model_row, write_models
from pydantic import ValidationError
from scipy.spatial.transform import Rotation

from osgd.checks.calibration import _top_down_across_y
from osgd.checks.params import ChecksStageParams
from osgd.checks.trial import run_trial
from osgd.config import ConfigError, build_config
from osgd.contract.taxonomy import TABLE1
from osgd.gripper import PANDA
from osgd.physics import create_object_body, get_mesh_pose, physics_client, pybullet_module, worker_client
from osgd.pipeline import stage_params_classes
from osgd.scenes import drop as drop_module
from osgd.scenes.drop import (
    ModelPool,
    Release,
    attempt_seed,
    build_world,
    deepest_penetration,
    draw_releases,
    generate_scene,
    simulate_drop,
    stored_penetration,
)
from osgd.scenes.params import ScenesStageParams
from osgd.scenes.pictures import show_scene
from osgd.scenes.stage import ScenesStage
from osgd.scenes.statistics import count_contacts, scene_contacts, scene_statistics
from osgd.scenes.views import posed_meshes
from osgd.stage import PlannedShard, WorkItem, run_stage
from osgd.store import ShardStore

MODELS_KEY = "0" * 64


def _plan(params: ScenesStageParams, seed: int = 0) -> list[PlannedShard]:
    upstream = {"models": [PlannedShard(WorkItem("fixture", {}), MODELS_KEY)]}
    return ScenesStage().planned(params, seed, upstream)


def _store(root: Path) -> ShardStore:
    store = ShardStore(root)
    write_models(store, fixture_models(), MODELS_KEY)
    return store


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[ShardStore, list[dict]]:
    store = _store(tmp_path_factory.mktemp("scenes"))
    report = run_stage(ScenesStage(), _plan(ScenesStageParams(count=4, scenes_per_shard=2)), store)
    assert report.ok and report.built == 2
    rows = [row for record in report.records for row in store.read("scenes", record.key).to_pylist()]
    return store, rows


def test_plan_splits_scenes_into_shards_reading_every_models_shard() -> None:
    shards = _plan(ScenesStageParams(count=7, scenes_per_shard=3))
    assert [shard.item.item_id for shard in shards] == ["scenes_000", "scenes_001", "scenes_002"]
    assert [shard.item.payload["scene_count"] for shard in shards] == [3, 3, 1]
    assert all(shard.item.inputs == {"models": (MODELS_KEY,)} for shard in shards)
    assert len({shard.key for shard in shards}) == 3
    # Another seed is another dataset: every key changes.
    assert not {shard.key for shard in shards} & {shard.key for shard in _plan(ScenesStageParams(count=7,
                                                                                  scenes_per_shard=3), seed=1)}


def test_rows_follow_the_schema_and_scene_ids(built: tuple[ShardStore, list[dict]]) -> None:
    _, rows = built
    assert [row["scene_id"] for row in rows] == [f"scene_{index:06d}" for index in range(4)]
    for row in rows:
        assert 3 <= len(row["objects"]) <= 6
        assert row["settled"]
        assert row["sim_steps"] > 0
        assert row["sim_time"] == pytest.approx(row["sim_steps"] / 240.0)
        assert row["seed"] == attempt_seed(0, row["scene_index"], row["attempts"] - 1)
        assert sum(json.loads(row["rejections"]).values()) == row["attempts"] - 1
        categories = {model["model_id"]: model["category"] for model in fixture_models()}
        assert all(categories[obj["model_id"]] == obj["category"] for obj in row["objects"])


def test_objects_pile_up_inside_the_walls_above_the_floor(built: tuple[ShardStore, list[dict]]) -> None:
    _, rows = built
    models = {model["model_id"]: model for model in fixture_models()}
    lying_on = 0
    for row in rows:
        for mesh in posed_meshes(row, models):
            assert np.all(np.abs(mesh.vertices[:, :2]) < 0.5)
            # Resting contacts sink a fraction of a millimetre into the floor at most.
            assert mesh.vertices[:, 2].min() > -0.002
        statistics = scene_statistics(row, models)
        assert statistics.touching >= 2, row["scene_id"]
        lying_on += statistics.lying_on
    assert lying_on >= len(rows)


def test_settled_scenes_stay_at_rest_when_simulated_again(built: tuple[ShardStore, list[dict]]) -> None:
    _, rows = built
    models = {model["model_id"]: model for model in fixture_models()}
    params = ScenesStageParams()
    for row in rows:
        with physics_client() as client:
            build_world(client, params)
            bodies = [create_object_body(client, models[obj["model_id"]], np.asarray(obj["position"]),
                                         np.asarray(obj["quaternion"])) for obj in row["objects"]]
            for _ in range(240):
                pybullet.stepSimulation(physicsClientId=client)
            for body, obj in zip(bodies, row["objects"], strict=True):
                position, quaternion = get_mesh_pose(body)
                assert np.linalg.norm(position - obj["position"]) < 0.003, row["scene_id"]
                angle = (Rotation.from_quat(quaternion) * Rotation.from_quat(obj["quaternion"]).inv()).magnitude()
                assert angle < 0.03, row["scene_id"]


def test_same_seed_gives_byte_identical_shards_and_shard_size_changes_no_scene(
        built: tuple[ShardStore, list[dict]], tmp_path: Path) -> None:
    store, rows = built
    params = ScenesStageParams(count=4, scenes_per_shard=2)
    again = _store(tmp_path / "again")
    report = run_stage(ScenesStage(), _plan(params), again)
    for shard in _plan(params):
        assert again.shard_path("scenes", shard.key).read_bytes() == store.shard_path("scenes", shard.key).read_bytes()
    # Scene 3 built alone, in a shard of one, in this process.
    pool = ModelPool(fixture_models())
    alone = generate_scene(pool, ScenesStageParams(count=4, scenes_per_shard=1), 0, 3).row
    assert alone == rows[3]
    other = generate_scene(pool, params, 1, 3).row
    assert other["objects"] != rows[3]["objects"]
    assert report.ok


def test_the_stored_seed_rebuilds_the_accepted_attempt(built: tuple[ShardStore, list[dict]]) -> None:
    _, rows = built
    pool = ModelPool(fixture_models())
    params = ScenesStageParams()
    row = rows[1]
    releases = draw_releases(np.random.default_rng(row["seed"]), pool, params)
    outcome = simulate_drop(pool, releases, params)
    np.testing.assert_array_equal(outcome.positions, [obj["position"] for obj in row["objects"]])


@pytest.mark.parametrize("runaway_check_steps", [1, 8])
def test_a_blown_up_simulation_is_rejected_until_the_attempts_run_out(tmp_path: Path,
                                                                       runaway_check_steps: int) -> None:
    # Anything falling 30 cm lands at about 2 m/s: a 1 m/s limit calls every attempt blown up.
    params = ScenesStageParams(count=1, max_linear_speed=1.0, max_attempts=3, runaway_check_steps=runaway_check_steps)
    result = generate_scene(ModelPool(fixture_models()), params, 0, 0)
    assert result.row is None
    assert result.rejections == Counter({"blew_up": 3})
    store = _store(tmp_path)
    report = run_stage(ScenesStage(), _plan(params), store)
    assert report.ok and report.records[0].rows == 0
    assert "all 3 attempts rejected (blew_up 3)" in report.notes["scenes_000"][0]


@pytest.mark.parametrize("runaway_check_steps", [1, 8])
def test_a_coarse_time_step_lets_objects_fall_through_the_floor_and_is_rejected(runaway_check_steps: int) -> None:
    params = ScenesStageParams(timestep=0.05, max_attempts=2, runaway_check_steps=runaway_check_steps)
    result = generate_scene(ModelPool(fixture_models()), params, 0, 0)
    assert result.row is None
    assert result.rejections["fell_through_floor"] >= 1


def test_a_pile_cut_short_before_every_release_is_never_kept() -> None:
    # 3 objects released 0.2 s apart need 0.4 s; 0.25 s of simulation leaves the third in the air.
    params = ScenesStageParams(min_objects=3, max_objects=3, release_interval=0.2, max_sim_time=0.25,
                               reject_unsettled=False, max_attempts=2)
    result = generate_scene(ModelPool(fixture_models()), params, 0, 0)
    assert result.row is None
    assert result.rejections == Counter({"not_settled": 2})


def test_a_rejected_attempt_is_redrawn_with_the_next_seed() -> None:
    pool = ModelPool(fixture_models())
    params = ScenesStageParams()
    calls: list[int] = []

    def draw_once_outside(rng: np.random.Generator, pool: ModelPool, params: ScenesStageParams) -> list[Release]:
        releases = draw_releases(rng, pool, params)
        calls.append(len(releases))
        if len(calls) == 1:  # The first attempt drops its first object beyond the walls.
            first = releases[0]
            releases[0] = Release(first.model_index, first.quaternion, np.array([0.7, 0.0]))
        return releases

    result = generate_scene(pool, params, 5, 2, draw=draw_once_outside)
    assert result.rejections == Counter({"left_area": 1})
    assert result.row["attempts"] == 2
    assert result.row["seed"] == attempt_seed(5, 2, 1)
    assert json.loads(result.row["rejections"]) == {"left_area": 1}


def test_deepest_penetration_measures_overlap() -> None:
    block = fixture_models()[2]  # 12 x 4 x 4 cm
    with physics_client() as client:
        # Dynamic bodies: pybullet finds no contacts between two static ones.
        first = create_object_body(client, block, np.array([0.0, 0.0, 0.5]))
        second = create_object_body(client, block, np.array([0.0, 0.0, 0.53]))
        pybullet.performCollisionDetection(physicsClientId=client)
        depth, pair = deepest_penetration(client, [first.body_id, second.body_id])
    # 1 cm of overlap, plus up to a millimetre of pybullet's collision margin on each hull.
    assert 0.009 < depth < 0.013
    assert set(pair) == {first.body_id, second.body_id}


def test_stored_penetration_measures_overlap_of_the_stored_parts_and_with_the_floor() -> None:
    block = fixture_models()[2]  # 12 x 4 x 4 cm, centred on its mesh origin
    level = np.array([0.0, 0.0, 0.0, 1.0])
    stacked = [(np.array([0.0, 0.0, 0.5]), level), (np.array([0.0, 0.0, 0.53]), level)]
    depth, pair = stored_penetration([block, block], stacked, ScenesStageParams())
    assert 0.009 < depth < 0.013
    assert pair == (0, 1)
    sunk = [(np.array([0.0, 0.0, 0.015]), level), (np.array([0.3, 0.0, 0.02]), level)]
    depth, pair = stored_penetration([block, block], sunk, ScenesStageParams())
    assert 0.004 < depth < 0.007
    assert pair == (0, -1)


def test_stored_penetration_in_the_reused_world_equals_a_fresh_world() -> None:
    """Bodies kept from pile to pile (copies of one model included) overlap as bodies loaded anew, walls too."""
    models = fixture_models()
    rng = np.random.default_rng(3)
    answers = {"reused": [], "fresh": []}
    for area_size in (1.0, 0.3, 1.0):  # the walls move in and back out: the world follows
        params = ScenesStageParams(area_size=area_size)
        # The 12 cm block lying along x, its centre 2 cm inside the wall's inner face, clear of the floor: only
        # the wall of this area_size overlaps it, by 4 cm.
        piles = [([models[2]], [(np.array([area_size / 2 - 0.02, 0.0, 0.1]), np.array([0.0, 0.0, 0.0, 1.0]))])]
        for pile in range(5):
            chosen = [models[int(index)] for index in rng.integers(len(models), size=2 + pile % 3)]
            piles.append((chosen, [(np.array([*rng.uniform(-0.05, 0.05, 2), rng.uniform(0.0, 0.06)]),
                                    Rotation.random(random_state=rng).as_quat()) for _ in chosen]))
        for chosen, poses in piles:
            answers["reused"].append(stored_penetration(chosen, poses, params))
            answers["fresh"].append(_stored_penetration_in_a_new_world(chosen, poses, params))
    assert answers["reused"] == answers["fresh"]
    assert sum(depth > 0 for depth, _ in answers["fresh"]) >= 9  # overlapping piles are among them
    for depth, pair in answers["fresh"][::6]:  # the block in the wall
        assert pair == (0, -1) and 0.038 < depth < 0.043


def _stored_penetration_in_a_new_world(models: list, poses: list, params: ScenesStageParams) -> tuple:
    """:func:`stored_penetration` the direct way: the pile loaded anew in an empty world."""
    with physics_client() as client:
        walls = build_world(client, params)
        bodies = [create_object_body(client, model, position, quaternion, mass=0.0).body_id
                  for model, (position, quaternion) in zip(models, poses, strict=True)]
        deepest, pair = 0.0, (-1, -1)
        for index, body in enumerate(bodies):
            for other_index, other in [*((j, bodies[j]) for j in range(index + 1, len(bodies))),
                                       *((-1, wall) for wall in walls)]:
                for point in pybullet.getClosestPoints(body, other, 0.0, physicsClientId=client):
                    if -point[8] > deepest:
                        deepest, pair = -point[8], (index, other_index)
    return deepest, pair


def test_piles_dropped_with_reduced_hulls_are_judged_on_the_stored_parts() -> None:
    # Hulls of 5 corners stand in for the boxes and bars while dropping: they let them sink into each other,
    # and only the check on the stored boxes rejects that.
    pool = ModelPool(fixture_models())
    params = ScenesStageParams(max_hull_vertices=5, min_objects=4, max_objects=4, max_attempts=4)
    assert generate_scene(pool, params, 0, 0).rejections["interpenetration"] > 0
    # the same draws with the stored parts: those piles are not rejected for interpenetration
    assert generate_scene(pool, params.model_copy(update={"max_hull_vertices": 0}), 0, 0
                          ).rejections["interpenetration"] == 0


def test_piles_do_not_depend_on_what_the_process_dropped_before(monkeypatch: pytest.MonkeyPatch) -> None:
    # Every attempt empties this process's one pybullet client (resetSimulation) instead of connecting anew.
    pool = ModelPool(fixture_models())
    params = ScenesStageParams(max_attempts=3, max_hull_vertices=5, penetration_tolerance=0.05)
    forward = [generate_scene(pool, params, 0, index).row for index in range(4)]
    # A grasp trial in between uses the same client with other engine settings (100 solver iterations, ERP).
    run_trial(fixture_models()[2], np.zeros(3), _top_down_across_y(), 0.06, ChecksStageParams(), PANDA,
              np.random.default_rng(0))
    backward = [generate_scene(pool, params, 0, index).row for index in reversed(range(4))]
    assert forward == backward[::-1]
    with worker_client() as client:
        assert pybullet_module().getNumBodies(physicsClientId=client) == 0
        with pytest.raises(RuntimeError, match="already in use"), worker_client():
            pass
    monkeypatch.setattr(drop_module, "worker_client", physics_client)  # a new client per attempt, as before
    assert [generate_scene(pool, params, 0, index).row for index in range(4)] == forward


def test_a_sparser_runaway_test_keeps_the_piles_and_the_old_keys() -> None:
    # What the test catches mostly lasts, so testing every 8th step (and at every rest test) keeps these piles.
    pool = ModelPool(fixture_models())
    for scene_index in range(3):
        every_step = generate_scene(pool, ScenesStageParams(max_attempts=3), 0, scene_index).row
        sparse = generate_scene(pool, ScenesStageParams(max_attempts=3, runaway_check_steps=8), 0, scene_index).row
        assert sparse == every_step
    assert "runaway_check_steps" not in ScenesStageParams().key_dict()
    assert ScenesStageParams(runaway_check_steps=8).key_dict()["runaway_check_steps"] == 8


def test_the_hull_option_keeps_old_scene_keys_until_it_is_set() -> None:
    assert "max_hull_vertices" not in ScenesStageParams().key_dict()
    assert ScenesStageParams(max_hull_vertices=32).key_dict()["max_hull_vertices"] == 32
    plain = {shard.key for shard in _plan(ScenesStageParams(count=50))}
    reduced = {shard.key for shard in _plan(ScenesStageParams(count=50, max_hull_vertices=32))}
    assert plain == {shard.key for shard in _plan(ScenesStageParams(count=50, max_hull_vertices=0))}
    assert not plain & reduced


def test_piles_in_maximal_coordinates_settle_the_same_way_twice_under_their_own_keys() -> None:
    pool = ModelPool(fixture_models())
    params = ScenesStageParams(max_attempts=3, maximal_coordinates=True)
    rows = [generate_scene(pool, params, 0, index).row for index in range(3)]
    assert all(row is not None and row["settled"] for row in rows)
    assert [generate_scene(pool, params, 0, index).row for index in range(3)] == rows
    # The option reaches the physics: the same draws settle elsewhere as multibodies.
    multibody = [generate_scene(pool, params.model_copy(update={"maximal_coordinates": False}), 0, index).row
                 for index in range(3)]
    assert [row["objects"] for row in multibody] != [row["objects"] for row in rows]
    assert "maximal_coordinates" not in ScenesStageParams().key_dict()
    plain = {shard.key for shard in _plan(ScenesStageParams(count=50))}
    assert not plain & {shard.key for shard in _plan(ScenesStageParams(count=50, maximal_coordinates=True))}


def test_category_weights_steer_the_draw() -> None:
    pool = ModelPool(fixture_models())
    params = ScenesStageParams(category_weights={"hammer": 0.0, "knife": 0.0})
    rng = np.random.default_rng(0)
    drawn = {pool.rows[release.model_index]["category"]
             for _ in range(20) for release in draw_releases(rng, pool, params)}
    assert drawn == {"screwdriver"}
    model_balance = ScenesStageParams(balance="model", min_objects=6)
    counts = Counter(pool.rows[release.model_index]["category"] for _ in range(20)
                     for release in draw_releases(rng, pool, model_balance))
    assert set(counts) == {"hammer", "screwdriver", "knife"}


def test_bad_parameters_and_empty_models_are_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(ValidationError, match="below min_objects"):
        ScenesStageParams(min_objects=4, max_objects=3)
    assert ScenesStageParams(category_weights={"teapot": 1.0}).taxonomy_mistakes(TABLE1) == [
        f"category_weights names unknown categories ['teapot']; known: {list(TABLE1.category_names)}"]
    with pytest.raises(ConfigError, match=r"\[scenes\] category_weights names unknown categories \['teapot'\]"):
        build_config({"scenes": {"category_weights": {"teapot": 1.0}}}, stage_params_classes())
    store = ShardStore(tmp_path)
    write_models(store, [], MODELS_KEY)
    shard = _plan(ScenesStageParams(count=1))[0]
    with pytest.raises(ValueError, match="has no rows"):
        ScenesStage().build(shard.item, store)


def test_statistics_of_a_hand_made_stack() -> None:
    block = model_row("block", "knife", block_parts())  # 12 x 4 x 4 cm, centred on its mesh origin
    upright = [0.0, 0.0, 0.0, 1.0]
    crossed = Rotation.from_euler("z", np.pi / 2).as_quat().tolist()
    scene = {"objects": [
        {"model_id": "block", "category": "knife", "position": [0.0, 0.0, 0.02], "quaternion": upright},
        {"model_id": "block", "category": "knife", "position": [0.0, 0.0, 0.06], "quaternion": crossed},
        {"model_id": "block", "category": "knife", "position": [0.3, 0.3, 0.02], "quaternion": upright},
    ]}
    statistics = scene_statistics(scene, {"block": block})
    assert statistics.objects == 3
    assert statistics.touching == 2
    assert statistics.lying_on == 1
    assert statistics.off_floor == 1
    assert statistics.overlapping == 2
    # The crossing block hides a 4 x 4 cm square of the lower block's 12 x 4 cm: a third.
    assert statistics.occlusion[0] == pytest.approx(1 / 3, abs=0.05)
    assert statistics.occlusion[1] == pytest.approx(0.0, abs=0.01)
    assert statistics.occlusion[2] == pytest.approx(0.0, abs=0.01)


def test_contacts_in_the_reused_world_equal_a_fresh_world() -> None:
    """scene_contacts' bodies kept from scene to scene count what bodies loaded anew with a floor count."""
    models = {row["model_id"]: row for row in fixture_models()}
    ids = sorted(models)
    rng = np.random.default_rng(8)
    counts = {"reused": [], "fresh": []}
    for _ in range(8):
        chosen = [ids[int(index)] for index in rng.integers(len(ids), size=int(rng.integers(2, 5)))]
        scene = {"objects": [{"model_id": model_id, "category": "knife",
                              "position": [*rng.uniform(-0.06, 0.06, 2).tolist(), float(rng.uniform(0.0, 0.08))],
                              "quaternion": Rotation.random(random_state=rng).as_quat().tolist()}
                             for model_id in chosen]}
        counts["reused"].append(scene_contacts(scene, models))
        counts["fresh"].append(_contacts_in_a_new_world(scene, models))
    assert counts["reused"] == counts["fresh"]
    assert any(touching for touching, _, _ in counts["fresh"]) and any(off for _, _, off in counts["fresh"])


def _contacts_in_a_new_world(scene: dict, models: dict) -> tuple[int, int, int]:
    """:func:`scene_contacts` the direct way: the scene loaded anew with a floor, in a new client."""
    with physics_client() as client:
        floor = pybullet.createMultiBody(0, pybullet.createCollisionShape(pybullet.GEOM_PLANE, physicsClientId=client),
                                         physicsClientId=client)
        bodies = [create_object_body(client, models[obj["model_id"]], np.asarray(obj["position"]),
                                     np.asarray(obj["quaternion"]), mass=0.0).body_id for obj in scene["objects"]]
        return count_contacts(client, floor, bodies)


def test_summary_and_picture(built: tuple[ShardStore, list[dict]], tmp_path: Path) -> None:
    store, rows = built
    records = [store.verify("scenes", key) for key in store.keys_on_disk("scenes")]
    text = ScenesStage().summary(store, records)
    assert "scenes: 4 (4 settled)" in text
    assert "overlapping another" in text
    out = tmp_path / "scene.png"
    message = show_scene(store, rows[0]["scene_id"], out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert str(out) in message
    with pytest.raises(KeyError, match="no scene"):
        show_scene(store, "scene_999999", out)



def test_a_model_whose_content_changes_leaves_the_other_draws_alone():
    """The pool is ordered by name: a new content hash for one model moves no other model's draws."""
    rows = [{"model_id": f"{index:016x}", "name": f"procedural/tool_{index:02d}", "category": category}
            for index, category in enumerate(["hammer", "knife", "fork", "pen"] * 3)]
    changed = [dict(row) for row in rows]
    changed[5]["model_id"] = "ffffffffffffffff"  # tool_05 rebuilt with other bytes
    params = ScenesStageParams()
    for scene in range(20):
        before = draw_releases(np.random.default_rng(scene), ModelPool(rows), params)
        after = draw_releases(np.random.default_rng(scene), ModelPool(changed), params)
        names_before = [ModelPool(rows).rows[release.model_index]["name"] for release in before]
        names_after = [ModelPool(changed).rows[release.model_index]["name"] for release in after]
        assert names_before == names_after
