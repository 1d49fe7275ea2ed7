"""The taxonomy as data: the packaged Table I and the validation of a taxonomy file."""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path

import pytest
from typer.testing import CliRunner

from osgd.cli import app
from osgd.contract import taxonomy
from osgd.contract.taxonomy import TABLE1, TaxonomyError, parse_taxonomy, read_taxonomy
from osgd.grasps.labels import DEFAULT_RULES
from osgd.models.categories import CATEGORY_PROPERTIES


def table1_document() -> dict:
    """The packaged Table I, parsed afresh (a copy a test may change)."""
    return tomllib.loads(resources.files("osgd.contract").joinpath(taxonomy.TABLE1_FILE).read_text())


def test_the_packaged_taxonomy_is_table_one_in_its_order() -> None:
    """The paper's Table I: the detector's logits and classes are indexed by these orders."""
    assert taxonomy.TASKS == ("no task", "cut", "screw", "ladle", "fork", "wrench", "hammer", "write", "brush",
                              "shovel", "pinch", "hand over")
    assert taxonomy.CATEGORIES == ("knife", "screwdriver", "spoon", "fork", "wrench", "hammer", "pen", "toothbrush",
                                   "spatula", "pliers")
    assert [taxonomy.CATEGORY_TASK[category] for category in taxonomy.CATEGORIES] == list(taxonomy.TASKS[1:-1])
    assert taxonomy.TASK_REQUIREMENT["hand over"] == "leave the handle clear"
    assert taxonomy.TASK_REQUIREMENT["hammer"] == "away from the heavier end"


def test_the_label_rules_and_physical_properties_are_the_taxonomys() -> None:
    hammer = TABLE1.category("hammer")
    assert DEFAULT_RULES["hammer"].working == hammer.working == ("head",)
    assert DEFAULT_RULES["hammer"].task_clearance == hammer.task_clearance == 0.03
    assert DEFAULT_RULES["knife"].task_clearance == taxonomy.RULE_DEFAULTS["task_clearance"]  # left out: default
    assert CATEGORY_PROPERTIES["wrench"].density == 7850.0 and CATEGORY_PROPERTIES["pen"].mass_range == (0.004, 0.03)
    with pytest.raises(ValueError, match="unknown category 'mug'"):
        TABLE1.category("mug")


def test_a_taxonomy_file_reads_with_a_new_category_and_task(tmp_path: Path) -> None:
    text = resources.files("osgd.contract").joinpath(taxonomy.TABLE1_FILE).read_text()
    text = text.replace('parts = ["handle",', 'parts = ["body", "handle",').replace(
        '    { name = "hand over"', '    { name = "pour", requirement = "hold the body" },\n    { name = "hand over"')
    text += ('\n[[categories]]\nname = "mug"\ntask = "pour"\nhandle = ["body"]\nworking = ["handle"]\n'
             'length_range = [0.08, 0.12]\ndensity = 1200.0\nmass_range = [0.2, 0.5]\nlateral_friction = 0.5\n')
    path = tmp_path / "mugs.toml"
    path.write_text(text)
    read = read_taxonomy(path)
    assert read.tasks[-2:] == ("pour", "hand over") and read.category_names[-1] == "mug"
    mug = read.category("mug")
    assert mug.split == 0.5 and mug.hand_over_clearance == 0.01 and mug.mass_range == (0.2, 0.5)


def test_each_mistake_is_named_on_a_line_of_its_own() -> None:
    document = table1_document()
    document["categories"][0]["working"] = ["blade", "edge"]  # an unknown part in a rule
    document["tasks"].insert(5, {"name": "stir", "requirement": "hold the handle"})  # a task without a rule
    document["categories"].append(dict(document["categories"][1]))  # a duplicate name
    document["categories"][2]["density"] = -1.0
    document["categories"][3]["colour"] = "red"
    with pytest.raises(TaxonomyError) as raised:
        parse_taxonomy(document, "mine.toml")
    lines = str(raised.value).splitlines()
    assert all(line.startswith("mine.toml: ") for line in lines)
    expected = ["categories['knife'].working: unknown part 'edge'",
                "tasks: 'stir' has no rule",
                "categories: 'screwdriver' is named twice",
                "categories['spoon'].density: expected a finite number > 0, got -1.0",
                "categories['fork']: unknown key 'colour'"]
    for fragment in expected:
        assert sum(fragment in line for line in lines) == 1, (fragment, lines)
    assert len(lines) == len(expected)


def test_the_tasks_every_rule_relies_on_must_be_there() -> None:
    document = table1_document()
    document["tasks"] = document["tasks"][1:-1]  # neither "no task" nor "hand over"
    with pytest.raises(TaxonomyError) as raised:
        parse_taxonomy(document, "t.toml")
    assert "the first task must be 'no task'" in str(raised.value) and "'hand over' is missing" in str(raised.value)
    document = table1_document()
    document["categories"][0]["task"] = "hand over"
    document["categories"][1]["handle"] = ["handle", "shaft"]
    with pytest.raises(TaxonomyError) as raised:
        parse_taxonomy(document, "t.toml")
    message = str(raised.value)
    assert "categories['knife']: task 'hand over' is not a task" in message and "'cut' has no rule" in message
    assert "part 'shaft' is both a handle and a working part" in message


def test_values_of_the_wrong_kind_are_mistakes_not_tracebacks() -> None:
    document = table1_document()
    document["name"] = 3
    document["categories"].append("mug")
    document["categories"][0]["density"] = float("nan")
    document["categories"][1]["length_range"] = [True, True]
    document["categories"][2]["lateral_friction"] = float("inf")
    document["tasks"][1]["requirment"] = "avoid the blade"
    document["tasks"][2]["requirement"] = 3
    document["parts"].append({"name": "spout"})
    with pytest.raises(TaxonomyError) as raised:
        parse_taxonomy(document, "t.toml")
    lines = str(raised.value).splitlines()
    for fragment in ("name: expected a non-empty string, got 3", "categories[10]: expected a table, got 'mug'",
                     "categories['knife'].density: expected a finite number > 0, got nan",
                     "categories['screwdriver'].length_range: expected [low, high]",
                     "categories['spoon'].lateral_friction: expected a finite number > 0, got inf",
                     "tasks[1]: unknown key 'requirment'", "tasks[2].requirement: expected the task's grasp",
                     "parts[10]: expected a name"):
        assert sum(fragment in line for line in lines) == 1, (fragment, lines)
    assert len(lines) == 8


def test_a_missing_or_broken_file_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="no such taxonomy file"):
        read_taxonomy(tmp_path / "none.toml")
    (tmp_path / "bad.toml").write_text("parts = [")
    with pytest.raises(TaxonomyError, match=r"bad\.toml: not TOML"):
        read_taxonomy(tmp_path / "bad.toml")
    (tmp_path / "latin.toml").write_bytes('name = "caf\xe9"'.encode("latin-1"))
    with pytest.raises(TaxonomyError, match=r"latin\.toml: not UTF-8 text"):
        read_taxonomy(tmp_path / "latin.toml")


def test_osgd_taxonomy_checks_a_file_and_names_each_mistake(tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["taxonomy"])
    assert result.exit_code == 0 and "taxonomy table1: 10 categories, 12 tasks" in result.output
    text = resources.files("osgd.contract").joinpath(taxonomy.TABLE1_FILE).read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('working = ["head"]', 'working = ["hed"]').replace("density = 900.0", "density = 0"))
    result = CliRunner().invoke(app, ["taxonomy", str(bad)])
    lines = result.output.strip().splitlines()
    assert result.exit_code == 2 and len(lines) == 2, result.output
    assert "categories['hammer'].working: unknown part 'hed'" in lines[0]
    assert "categories['pen'].density: expected a finite number > 0, got 0" in lines[1]
