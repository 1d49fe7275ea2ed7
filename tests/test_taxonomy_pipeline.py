"""A pipeline's own taxonomy: the kitchen example (pipelines/kitchen/), from its meshes' parts to the keys."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import trimesh

from osgd.config import ConfigError, build_config, load_config
from osgd.contract.samples import metadata_vocabulary
from osgd.contract.schemas import samples_schema
from osgd.contract.taxonomy import TABLE1, read_taxonomy, taxonomy_of_document
from osgd.grasps.labels import effective_rules, label_grasp
from osgd.models import parts, user
from osgd.pipeline import plan_pipeline, stage_params_classes
from osgd.stage import TAXONOMY_KEY
from osgd.store import table_to_parquet_bytes
from togcrf.robot.protocol import protocol_trials

ROOT = Path(__file__).resolve().parents[1]
KITCHEN = read_taxonomy(ROOT / "pipelines/kitchen/taxonomy.toml")


def make_tools():
    """pipelines/kitchen/make_tools.py as a module."""
    spec = importlib.util.spec_from_file_location("make_tools", ROOT / "pipelines/kitchen/make_tools.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_kitchen_taxonomy_extends_table_one() -> None:
    assert KITCHEN.extends_table1 and not TABLE1.parts == KITCHEN.parts
    assert KITCHEN.tasks[: len(TABLE1.tasks)] == TABLE1.tasks and KITCHEN.tasks[-2:] == ("pour", "stir")
    assert KITCHEN.category_names[-3:] == ("mug", "scissors", "whisk")
    assert KITCHEN.part_index["wires"] == len(TABLE1.parts) + 1
    assert taxonomy_of_document(KITCHEN.document()) == KITCHEN and KITCHEN.digest != TABLE1.digest
    rules = effective_rules({}, KITCHEN)
    wires = KITCHEN.part_index["wires"]
    assert label_grasp("whisk", rules["whisk"], np.array([KITCHEN.part_index["handle"]]), {wires: 0.05}) == "stir"
    assert label_grasp("whisk", rules["whisk"], np.array([wires]), {}, position=0.8) == "hand over"


def test_the_generic_rule_finds_the_parts_of_scissors_and_whisks_in_any_pose() -> None:
    tools = make_tools()
    rng = np.random.default_rng(3)
    turn = trimesh.transformations.random_rotation_matrix(rng.random(3))
    scissors = tools.scissors(rng)
    whisk, handle_length = tools.whisk(rng)
    centres = {"scissors": scissors.triangles_center[:, 0], "whisk": whisk.triangles_center[:, 0]}
    working_from = {"scissors": 0.0, "whisk": handle_length}
    for name, mesh in (("scissors", scissors), ("whisk", whisk)):
        turned = mesh.copy()
        turned.apply_transform(turn)
        found = parts.find_parts(turned, name, KITCHEN)
        assert found.found and found.confidence >= 0.9, found.note
        working = found.face_parts == KITCHEN.part_index[KITCHEN.category(name).working[0]]
        truth = centres[name] > working_from[name] + 0.01
        clear = np.abs(centres[name] - working_from[name]) > 0.02  # faces well away from the boundary
        assert np.mean(working[clear] == truth[clear]) > 0.95, name


def test_a_category_without_a_parts_rule_gets_no_parts_and_says_where_to_give_them() -> None:
    mug, _ = make_tools().mug(np.random.default_rng(0))
    found = parts.find_parts(mug, "mug", KITCHEN)
    assert not found.found and (found.face_parts == -1).all() and "[part_labels]" in found.note
    with pytest.raises(ValueError, match="unknown category 'mug'"):
        parts.find_parts(mug, "mug")  # Table I has none


def test_the_kitchen_sidecars_give_parts_by_label_file_and_by_region(tmp_path: Path) -> None:
    tools = make_tools()
    for category, write in tools.WRITERS.items():
        write(tmp_path, f"{category}_00", np.random.default_rng(1))
    for category, part_source in (("mug", "part_labels"), ("whisk", "parts")):
        sidecar_file = tmp_path / f"{category}_00.toml"
        sidecar = user.read_sidecar(sidecar_file, KITCHEN)
        assert getattr(sidecar, part_source)
        mesh, groups = user.load_user_mesh(tmp_path / f"{category}_00.ply")
        face_parts = user.face_parts_from_regions(mesh, sidecar, groups, str(sidecar_file), tmp_path, KITCHEN)
        rule = KITCHEN.category(category)
        assert set(np.unique(face_parts)) == {KITCHEN.part_index[rule.handle[0]], KITCHEN.part_index[rule.working[0]]}
    with pytest.raises(user.SidecarError, match="unknown category 'mug'"):
        user.read_sidecar(tmp_path / "mug_00.toml")  # read with Table I
    with pytest.raises(user.SidecarError, match="unknown part 'body'"):
        user.parse_sidecar('category = "mug"\nscale = 1.0\n[part_labels]\nfile = "x.npy"\nnames = ["body"]\n')


def _document(tmp_path: Path, taxonomy: str) -> dict:
    (tmp_path / "tools").mkdir(exist_ok=True)
    make_tools().WRITERS["scissors"](tmp_path / "tools", "scissors_00", np.random.default_rng(0))
    pipeline = {"name": "kitchen-test"} | ({"taxonomy": taxonomy} if taxonomy else {})
    return {"pipeline": pipeline, "models": {"sources": ["procedural", "user"], "procedural_per_category": 1,
                                             "user_dir": str(tmp_path / "tools")}, "scenes": {"count": 2}}


def test_a_pipelines_taxonomy_is_in_the_keys_of_what_it_labels_and_table_one_keys_stay(tmp_path: Path) -> None:
    kitchen = build_config(_document(tmp_path, str(ROOT / "pipelines/kitchen/taxonomy.toml")),
                           stage_params_classes())
    plain = build_config(_document(tmp_path, ""), stage_params_classes())
    assert kitchen.taxonomy == KITCHEN and plain.taxonomy == TABLE1
    ours, table1 = plan_pipeline(kitchen), plan_pipeline(plain)
    for stage in ("models", "grasps", "samples"):
        assert all(shard.item.payload[TAXONOMY_KEY] == KITCHEN.document() for shard in ours[stage])
        assert all(TAXONOMY_KEY not in shard.item.payload for shard in table1[stage])
    for stage in ours:  # every key differs: downstream stages read the labelled shards
        assert {shard.key for shard in ours[stage]}.isdisjoint(shard.key for shard in table1[stage])


def test_a_taxonomy_that_does_not_extend_table_one_or_is_missing_is_one_line(tmp_path: Path) -> None:
    standalone = tmp_path / "mine.toml"
    standalone.write_text('parts = ["handle", "body"]\ntasks = [{ name = "no task", requirement = "-" }, '
                          '{ name = "pour", requirement = "hold the handle" }, '
                          '{ name = "hand over", requirement = "leave the handle clear" }]\n[[categories]]\n'
                          'name = "mug"\ntask = "pour"\nhandle = ["handle"]\nworking = ["body"]\n'
                          'length_range = [0.09, 0.14]\ndensity = 2300.0\nmass_range = [0.1, 0.4]\n'
                          'lateral_friction = 0.6\n')
    assert read_taxonomy(standalone).category_names == ("mug",)  # a taxonomy the detector takes
    config = tmp_path / "p.toml"
    for taxonomy, message in (("mine.toml", "does not extend Table I"), ("none.toml", "no such taxonomy file")):
        config.write_text(f'[pipeline]\nname = "p"\ntaxonomy = "{taxonomy}"\n')
        with pytest.raises(ConfigError, match=message) as error:
            load_config(config, stage_params_classes())
        assert len(str(error.value).splitlines()) == 1
    config.write_text('[pipeline]\nname = "p"\ntaxonomy = "' + str(ROOT / "pipelines/kitchen/taxonomy.toml")
                      + '"\n[scenes]\ncategory_weights = { mug = 2.0, teapot = 1.0 }\n')
    with pytest.raises(ConfigError, match=r"unknown categories \['teapot'\]"):
        load_config(config, stage_params_classes())


def test_samples_shards_record_the_vocabulary_of_their_taxonomy() -> None:
    schema = samples_schema(KITCHEN.vocabulary)
    data = table_to_parquet_bytes(schema.empty_table(), "samples", "k" * 64)
    recorded = metadata_vocabulary(pq.read_schema(pa.BufferReader(data)).metadata, "test")
    assert recorded == {field: list(names) for field, names in KITCHEN.vocabulary.items()}


def test_a_config_written_out_names_the_same_taxonomy(tmp_path: Path) -> None:
    from osgd.config import config_to_toml  # noqa: PLC0415

    config = load_config(ROOT / "pipelines/kitchen.toml", stage_params_classes())
    saved = tmp_path / "kitchen.toml"
    saved.write_text(config_to_toml(config))
    assert load_config(saved, stage_params_classes()).taxonomy == KITCHEN == config.taxonomy


def test_pictures_name_and_colour_the_parts_of_a_pipelines_taxonomy() -> None:
    from osgd.models.pictures import legend_handles, part_colour  # noqa: PLC0415 (matplotlib)

    body = KITCHEN.part_index["body"]
    assert [handle.get_label() for handle in legend_handles({0, body}, KITCHEN.parts)] == ["handle", "body"]
    assert [handle.get_label() for handle in legend_handles({body})] == [f"part {body}"]  # Table I's names only
    colours = [tuple(part_colour(index)) for index in range(len(KITCHEN.parts))]
    assert len(set(colours)) == len(colours)  # the new parts do not take a Table I part's colour


def test_a_mesh_that_crashes_coacd_costs_one_decomposition_not_the_process() -> None:
    from osgd.models.decomposition import decompose  # noqa: PLC0415 (coacd)

    rng = np.random.default_rng([0, 2])  # make_tools.py's scissors_02, which coacd's cut without remesh crashed on
    mesh = [make_tools().scissors(rng) for _ in range(3)][-1]
    result = decompose(np.asarray(mesh.vertices), np.asarray(mesh.faces), "scan")
    assert result.description["method"] == "coacd" and len(result.parts) > 1
    if result.notes:  # where coacd crashes on it: the note, and the description says what ran instead
        assert result.notes == ["coacd's process died (preprocess_mode='off') on the repaired mesh; decomposed it "
                                "again with coacd's manifold remesh on"]
        assert result.description["parameters"]["preprocess_mode"] == "on"
        assert result.description["crashed"]["preprocess_mode"] == "off"


def test_the_robot_protocol_tries_a_taxonomys_own_tasks_and_keeps_table_ones_piles() -> None:
    eligible = {"no task": ["mug"], "hand over": ["whisk"]}
    table1 = protocol_trials(0, eligible, tool_trials=2, named_trials=2)
    kitchen = protocol_trials(0, eligible, tool_trials=2, named_trials=2, taxonomy=KITCHEN)
    assert [trial.task for trial in kitchen[len(table1):]] == ["pour", "pour", "stir", "stir"]
    assert kitchen[: len(table1)] == table1  # Table I's tasks meet the same piles and named categories
    assert len({trial.scene_index for trial in kitchen}) == len(kitchen)
    with pytest.raises(ValueError, match="unknown task 'pour'"):
        protocol_trials(0, eligible, tasks=["pour"])
