"""The robot experiment in simulation: real piles, renders and pybullet grasps, no mocks.

The world is the committed golden pipeline (``data/golden``: one procedural
tool per category, their grasps and checks); the piles are fresh ones from
the robot's own scene indices, rendered with the exact CPU ray caster.
"""

from __future__ import annotations

import json
import re
import shutil
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from helpers import write_synthetic_samples
from typer.testing import CliRunner

from osgd.contract.samples import iter_samples
from osgd.contract.taxonomy import TASKS
from osgd.pipeline import load_pipeline
from osgd.samples.renderer import make_renderer
from osgd.store import ShardStore, canonical_json
from togcrf.checkpoint import read_checkpoint
from togcrf.cli import app
from togcrf.robot import report
from togcrf.robot.cli import novel_tools
from togcrf.robot.execute import REASONS, Execution, execute, judge
from togcrf.robot.lifting import RobotParams, lift_rectangle
from togcrf.robot.pile import clear_grasps, feasible_pile, task_grasps
from togcrf.robot.policies import OraclePolicy
from togcrf.robot.protocol import (
    NAMED_TASKS,
    PAPER_TABLE3,
    PAPER_TOTAL,
    ROBOT_SCENE_OFFSET,
    TABLE_TASKS,
    TOOL_TASKS,
    Trial,
    check_fresh,
    protocol_trials,
    untried_tasks,
)
from togcrf.robot.report import TRIAL_LOG, rates, read_logs, write_log
from togcrf.robot.run import RunSpec, make_policies, run_trials
from togcrf.robot.world import World, world_from_tables
from togcrf.train import TrainConfig, train

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = ROOT / "data" / "golden"
OVERRIDES = ['samples.renderer="embree"']

#: Tool tasks whose golden tools have stable grasps a top-down gripper reaches in a few piles.
BOUND_TASKS = ("cut", "ladle", "write", "fork", "shovel")


def golden_table(name: str) -> pa.Table:
    return pa.concat_tables([pq.read_table(path) for path in sorted((GOLDEN / name).glob("*.parquet"))])


@pytest.fixture(scope="module")
def world() -> World:
    config = load_pipeline(ROOT / "pipelines" / "golden.toml", OVERRIDES)
    return world_from_tables(config, golden_table("models"), golden_table("grasps"), golden_table("checks"))


@pytest.fixture(scope="module")
def bounds(world: World, tmp_path_factory: pytest.TempPathFactory) -> tuple[list[dict], Path]:
    """The oracle and the random policy on one pile per task of BOUND_TASKS, pictures on."""
    out = tmp_path_factory.mktemp("robot")
    trials = protocol_trials(world.seed, world.eligible_categories(), 1, 1, BOUND_TASKS)
    spec = RunSpec(None, (), None, ("oracle", "random"), out)
    return run_trials(world, trials, make_policies(spec, world), spec), out


def test_the_protocol_is_the_papers(world: World) -> None:
    trials = protocol_trials(world.seed, world.eligible_categories())
    assert len(trials) == 160
    for task in TOOL_TASKS:
        assert sum(trial.task == task for trial in trials) == 10
    for task in NAMED_TASKS:
        named = [trial for trial in trials if trial.task == task]
        assert len(named) == 30
        assert {trial.category for trial in named} <= set(world.eligible_categories()[task])
        assert len({trial.category for trial in named}) > 1, "the named category is drawn at random"
    assert all(trial.category is None for trial in trials if trial.task in TOOL_TASKS)
    assert protocol_trials(world.seed, world.eligible_categories()) == trials, "the same trials every time"


def test_robot_piles_are_never_training_scenes(world: World, bounds: tuple[list[dict], Path]) -> None:
    trials = protocol_trials(world.seed, world.eligible_categories())
    indices = [trial.scene_index + pile for trial in trials for pile in range(100)]
    assert min(indices) >= ROBOT_SCENE_OFFSET
    assert len(set(indices)) == len(indices), "no two trials share a pile"
    rows, _ = bounds
    stored = set(golden_table("scenes").column("seed").to_pylist())
    check_fresh(4, [row["pile_seed"] for row in rows], stored)
    with pytest.raises(ValueError, match="reaches the robot's scene indices"):
        check_fresh(ROBOT_SCENE_OFFSET + 1, [], [])
    with pytest.raises(ValueError, match="seeds of stored scenes"):
        check_fresh(4, [rows[0]["pile_seed"]], [rows[0]["pile_seed"]])


def test_a_chosen_rectangle_is_executed_and_scored(world: World) -> None:
    params = RobotParams()
    trial = protocol_trials(world.seed, world.eligible_categories(), 1, 0, ["cut"])[0]
    observation, _ = feasible_pile(world, trial, make_renderer("embree"), params)
    choice = OraclePolicy(world, params).choose(trial, observation)
    grasp = lift_rectangle(choice.rectangle, observation, world.gripper, params)
    assert np.allclose(grasp.rotation[:, 2], [0.0, 0.0, -1.0]), "top-down along the table normal"
    assert grasp.position[2] - world.gripper.finger_depth / 2 >= params.tip_clearance - 1e-9
    execution = execute(world, observation.scene, grasp, params)
    assert execution.held and execution.rise >= params.min_rise
    assert observation.categories[execution.gripped] == "knife"
    assert execution.label == "cut"
    verdict = judge(world, trial, observation, execution)
    assert (verdict.gsr_s, verdict.gsr_t, verdict.reason, verdict.judged_by) == (True, True, "", "parts")
    # The same pile, the gripper sent to an empty corner of the table: nothing between the pads.
    corner = np.array([3.0, 3.0, choice.rectangle[2], choice.rectangle[3], 0.0])
    assert observation.object_at(3.0, 3.0) == -1
    missed = execute(world, observation.scene, lift_rectangle(corner, observation, world.gripper, params), params)
    assert missed.gripped == -1 and not missed.held
    assert judge(world, trial, observation, missed).reason == "empty_close"


def test_the_judge_tells_the_wrong_object_from_the_wrong_grasp(world: World) -> None:
    params = RobotParams()
    trial = protocol_trials(world.seed, world.eligible_categories(), 1, 0, ["cut"])[0]
    observation, _ = feasible_pile(world, trial, make_renderer("embree"), params)
    knife = observation.categories.index("knife")
    other = next(index for index, category in enumerate(observation.categories) if category != "knife")
    grasp = lift_rectangle(task_grasps(observation, trial)[0]["rectangle"], observation, world.gripper, params)
    held = Execution(grasp, gripped=knife, held=True, rise=0.15, label="hand over")
    assert judge(world, trial, observation, held).reason == "wrong_grasp"
    assert judge(world, trial, observation, held).gsr_s
    held.gripped = other
    assert judge(world, trial, observation, held).reason == "wrong_object"
    assert judge(world, trial, observation, None, "no_grasp").reason == "no_grasp"


def test_every_feasible_pile_has_a_clear_rectangle_of_its_task(world: World, bounds: tuple[list[dict], Path]) -> None:
    params = RobotParams()
    trial = protocol_trials(world.seed, world.eligible_categories(), 1, 0, ["ladle"])[0]
    observation, piles = feasible_pile(world, trial, make_renderer("embree"), params)
    assert piles >= 1
    assert any(clear_grasps(world, observation, task_grasps(observation, trial), params))
    spoon = observation.categories.index("spoon")
    assert any(grasp["object_index"] == spoon for grasp in task_grasps(observation, trial))


def test_the_oracle_scores_high_and_a_random_pixel_low(bounds: tuple[list[dict], Path]) -> None:
    rows, _ = bounds
    oracle = [row for row in rows if row["policy"] == "oracle"]
    random = [row for row in rows if row["policy"] == "random"]
    assert len(oracle) == len(random) == len(BOUND_TASKS)
    assert sum(row["gsr_t"] for row in oracle) >= len(BOUND_TASKS) - 1, [row["reason"] for row in oracle]
    assert sum(row["gsr_s"] for row in random) <= 1, [row["reason"] for row in random]
    for row in rows:
        assert row["reason"] in ("", *REASONS)
        assert row["gsr_t"] <= row["gsr_s"]
        assert (row["reason"] == "") == row["gsr_t"]


def _documented_columns(text: str) -> list[str]:
    """Column names of the first reST or Markdown table whose first cell is ``policy``."""
    names = re.findall(r"^(?:\|\s*)?``?([a-z_]+)``?(?:`?,\s*``?([a-z_]+)``?)?", text, flags=re.MULTILINE)
    flat = [name for pair in names for name in pair if name]
    start = flat.index("policy")
    return flat[start:start + len(TRIAL_LOG.names)]


def test_the_trial_log_has_the_documented_columns(bounds: tuple[list[dict], Path], tmp_path: Path) -> None:
    rows, _ = bounds
    path = write_log(rows, tmp_path / "trials.parquet")
    table = pq.read_table(path)
    assert table.schema.equals(TRIAL_LOG)
    assert table.num_rows == len(rows)
    assert read_logs([path])[0]["policy"] == "oracle"
    assert _documented_columns(report.__doc__) == TRIAL_LOG.names
    assert _documented_columns((ROOT / "docs" / "togcrf-robot.md").read_text()) == TRIAL_LOG.names
    with pytest.raises(ValueError, match="not a robot trial log"):
        read_logs([ROOT / "data" / "golden" / "scenes" / next(iter(
            path.name for path in sorted((GOLDEN / "scenes").glob("*.parquet"))))])


def test_a_picture_is_written_for_every_failure(bounds: tuple[list[dict], Path]) -> None:
    rows, out = bounds
    failed = [row for row in rows if row["reason"]]
    assert failed, "the random policy fails"
    for row in failed:
        image = cv2.imread(str(out / row["picture"]))
        assert image is not None and image.shape[1] > image.shape[0] > 300
        assert len(np.unique(image.reshape(-1, 3), axis=0)) > 50, "a drawing, not a blank page"
    assert all(row["picture"] == "" for row in rows if not row["reason"])


def test_table3_totals_are_the_mean_of_the_task_rates() -> None:
    rows = ([{"task": "cut", "gsr_s": True, "gsr_t": True}] * 10
            + [{"task": "hand over", "gsr_s": index < 15, "gsr_t": index < 6} for index in range(30)])
    table = rates(rows)
    assert table["cut"] == {"trials": 10, "gsr_s": 100.0, "gsr_t": 100.0}
    assert table["hand over"]["gsr_s"] == pytest.approx(50.0) and table["hand over"]["gsr_t"] == pytest.approx(20.0)
    assert table["Total"]["gsr_s"] == pytest.approx(75.0) and table["Total"]["gsr_t"] == pytest.approx(60.0)
    assert table["All trials"]["gsr_s"] == pytest.approx(62.5)
    for name, total in PAPER_TOTAL.items():
        for index in (0, 1):
            assert np.mean([value[index] for value in PAPER_TABLE3[name].values()]) == pytest.approx(total[index],
                                                                                                    abs=0.05)


def test_tasks_that_the_models_cannot_serve_are_named_not_tried() -> None:
    # the paper authors' models: stable "hand over" grasps, no "no task" grasp, no brush
    eligible = {"hand over": ["knife", "spoon"], "cut": ["knife"], "ladle": ["spoon"]}
    afforded = {"hand over", "cut", "ladle"}
    untried = untried_tasks(TABLE_TASKS, eligible, afforded)
    assert set(untried) == set(TABLE_TASKS) - afforded
    assert "stable 'no task' grasp" in untried["no task"] and "'brush'" in untried["brush"]
    assert untried_tasks(("cut", "hand over"), eligible, afforded) == {}
    tried = [task for task in TABLE_TASKS if task not in untried]
    trials = protocol_trials(0, eligible, 2, 3, tried)
    assert [trial.task for trial in trials] == ["cut"] * 2 + ["ladle"] * 2 + ["hand over"] * 3
    with pytest.raises(ValueError, match="no task"):
        protocol_trials(0, eligible, 2, 3, ["no task"])


def _protocol_rows(success: int, *, tool_trials: int = 10, named_trials: int = 30) -> list[dict]:
    """Trials of the 12 tasks with ``success`` of every ten a success (GSR-S and GSR-T alike)."""
    return [{"task": task, "gsr_s": index % 10 < success, "gsr_t": index % 10 < success}
            for task in TABLE_TASKS
            for index in range(named_trials if task in NAMED_TASKS else tool_trials)]


def test_table3_summaries_have_95_percent_intervals_that_narrow_with_the_trials() -> None:
    table = rates(_protocol_rows(5))
    low, high = table["Total"]["gsr_t_interval"]
    # the mean of 10 rates over 10 trials and 2 over 30, each at 0.5: standard error 100 * sqrt(0.25 * (10 / 10
    # + 2 / 30)) / 12 = 4.3 points
    assert low == pytest.approx(50.0 - 1.96 * 4.3, abs=1.2) and high == pytest.approx(50.0 + 1.96 * 4.3, abs=1.2)
    assert table["Total"]["gsr_s_interval"] == [low, high], "GSR-S of the same outcomes, the same interval"
    pooled_low, pooled_high = table["All trials"]["gsr_t_interval"]
    assert pooled_low < 50.0 < pooled_high and pooled_high - pooled_low < high - low
    tripled = rates(_protocol_rows(5, tool_trials=30, named_trials=90))["Total"]["gsr_t_interval"]
    assert (tripled[1] - tripled[0]) == pytest.approx((high - low) / np.sqrt(3), rel=0.1)
    assert rates(_protocol_rows(5))["Total"]["gsr_t_interval"] == [low, high], "one log, one interval"
    assert rates(_protocol_rows(10))["Total"]["gsr_t_interval"] == [100.0, 100.0]
    markdown = report.format_table3({"tog": table}, paper=False)
    assert f"| Total, 95 % interval | {low:.1f}-{high:.1f} | {low:.1f}-{high:.1f} |  |" in markdown


def _golden_data_dir(root: Path) -> Path:
    """The committed golden models, grasps and checks as a built pipeline ``golden``: the shards
    copied byte for byte, their checksum files and the committed manifest's entries."""
    store = ShardStore(root)
    manifest = json.loads((ROOT / "data" / "manifests" / "golden.json").read_text())
    stages = {}
    for table in ("models", "grasps", "checks"):
        entries = manifest["stages"][table]["shards"]
        for entry in entries:
            store.shard_path(table, entry["key"]).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(GOLDEN / table / f"{entry['key']}.parquet", store.shard_path(table, entry["key"]))
            store.checksum_path(table, entry["key"]).write_text(canonical_json(entry) + "\n")
        stages[table] = {"shards": entries}
    store.write_manifest("golden", {"pipeline": "golden", "stages": stages})
    return root


def test_robot_eval_and_robot_table_on_the_command_line(tmp_path: Path) -> None:
    data = _golden_data_dir(tmp_path / "data")
    out = tmp_path / "run"
    config = str(ROOT / "pipelines" / "golden.toml")
    result = CliRunner().invoke(app, ["robot-eval", "--config", config, "--data", str(data), "--out", str(out),
                                      "--tasks", "shovel", "--tool-trials", "1", "--baselines", "oracle,random",
                                      "--set", OVERRIDES[0]])
    assert result.exit_code == 0, result.output
    assert "| shovel |" in result.output and "paper TOG-CRFs GSR-T" in result.output
    assert {path.name for path in out.iterdir()} >= {"trials.parquet", "table3.md", "table3.json", "failures"}
    table = CliRunner().invoke(app, ["robot-table", str(out / "trials.parquet")])
    assert table.exit_code == 0 and "| Total |" in table.output
    for arguments, message in (
        (["--baselines", "oracle,genius"], "--baselines: unknown ['genius']"),
        (["--tasks", "juggle"], "--tasks: unknown ['juggle']"),
        (["--data", str(tmp_path / "nowhere")], "no manifest"),
        (["--config", str(tmp_path / "missing.toml")], "no such pipeline config"),
    ):
        base = {"--config": config, "--data": str(data)}
        base.update(dict(zip(arguments[::2], arguments[1::2], strict=True)))
        failed = CliRunner().invoke(app, ["robot-eval", *[item for pair in base.items() for item in pair],
                                          "--out", str(out)])
        assert failed.exit_code == 1
        assert failed.output.strip().splitlines() == [f"error: {failed.output.split('error: ')[1].strip()}"]
        assert message in failed.output


def test_a_checkpoint_policy_takes_test_time_views(tmp_path: Path) -> None:
    """`robot-eval --views`: the policy of a checkpoint averages its candidates over the views; boxes stay."""
    write_synthetic_samples(ShardStore(tmp_path / "data"), 4)
    train(TrainConfig(data=str(tmp_path / "data"), out=str(tmp_path / "run" / "tog"), pipeline="synthetic",
                      model="tog", backbone="resnet18", epochs=1, batch_size=2, max_samples=2, augment=False,
                      warmup_steps=1, device="cpu", amp=False, model_options={"box_head.detections_per_image": 5}))
    spec = RunSpec(None, (), None, (str(tmp_path / "run" / "tog" / "checkpoint.pt"),), tmp_path, min_score=0.0,
                   min_stability=0.0, views=8)
    (viewed,) = make_policies(spec, None)
    plain = replace(viewed, views=1)
    assert viewed.views == 8 and viewed.name == "tog:run [8 views]"
    observation = SimpleNamespace(depth=next(iter_samples(tmp_path / "data", pipeline="synthetic")).depth)
    trial = Trial("hand over", TASKS.index("hand over"), 0, "hammer", 0)
    plain.choose(trial, observation)
    viewed.choose(trial, observation)
    assert len(plain.last_detections.scores) > 0
    np.testing.assert_array_equal(plain.last_detections.boxes, viewed.last_detections.boxes)
    assert not np.allclose(plain.last_detections.grasp_stability, viewed.last_detections.grasp_stability)
    with pytest.raises(ValueError, match="1, 2, 4, 8"):
        make_policies(replace(spec, views=3), None)


def test_robot_eval_counts_the_pile_tools_a_checkpoint_never_trained_on(tmp_path: Path) -> None:
    """Piles of another pipeline's tools: each checkpoint says how many of them its training never showed."""
    write_synthetic_samples(ShardStore(tmp_path / "data"), 4)
    run = tmp_path / "run"
    train(TrainConfig(data=str(tmp_path / "data"), out=str(run), pipeline="synthetic", model="tog",
                      backbone="resnet18", epochs=1, batch_size=2, max_samples=2, augment=False, warmup_steps=1,
                      device="cpu", amp=False, model_options={"box_head.detections_per_image": 5}))
    trained = set(read_checkpoint(run / "checkpoint.pt")["data"]["models"])
    assert trained and trained <= {"synthetic0", "synthetic1", "synthetic2"}
    tools = {*trained, "procedural/hammer_00", "osgd/hammer_001"}
    assert novel_tools([run], tools) == {str(run): 2}  # a run dir or its checkpoint.pt
    assert novel_tools([run / "checkpoint.pt"], trained) == {str(run / "checkpoint.pt"): 0}
    # a run started from those weights has seen their tools too
    write_synthetic_samples(ShardStore(tmp_path / "data"), 4, seed=1, pipeline="other")
    again = tmp_path / "again"
    train(TrainConfig(data=str(tmp_path / "data"), out=str(again), pipeline="other", model="tog",
                      backbone="resnet18", epochs=1, batch_size=2, max_samples=2, augment=False, warmup_steps=1,
                      device="cpu", amp=False, init=str(run / "checkpoint.pt"),
                      model_options={"box_head.detections_per_image": 5}))
    both = set(read_checkpoint(again / "checkpoint.pt")["data"]["models"])
    assert trained < both and any(model.startswith("other") for model in both)
