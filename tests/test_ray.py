"""The Ray backend on a real local Ray cluster: a head and two worker nodes.

Tests that need Ray skip where it is not installed (``pip install -e
'.[ray]'``); the others check that osgd needs no Ray unless asked. The
cluster's nodes are started without the kernel pins in their environment,
as a ``ray start`` on another machine would be, so the workers get them
from the runtime environment the executor sets (:func:`osgd.executor.ray_runtime_env`).
"""

from __future__ import annotations

import functools
import importlib.util
import json
import logging
import os
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import ray_tasks
from toy_stage import ToyParams, ToyStage
from typer.testing import CliRunner

from osgd.cli import app
from osgd.executor import (
    ExecutorError,
    RayExecutor,
    SerialExecutor,
    TaskFailure,
    call_checked,
    code_fingerprint,
    make_executor,
    ray_runtime_env,
)
from osgd.kernels import portable_settings
from osgd.pipeline import load_pipeline, run_stages, stages
from osgd.stage import run_stage
from osgd.store import ShardStore

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"
GOLDEN = ROOT / "pipelines" / "golden.toml"
HAVE_RAY = importlib.util.find_spec("ray") is not None
needs_ray = pytest.mark.skipif(
    not HAVE_RAY, reason="Ray is not installed; `pip install -e '.[ray]'` runs the Ray backend's tests"
)
runner = CliRunner()


# -- without Ray --------------------------------------------------------------------


def test_osgd_imports_without_ray() -> None:
    code = "import sys, osgd.cli, osgd.executor, osgd.pipeline; assert 'ray' not in sys.modules"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr


def test_a_missing_ray_is_one_line_saying_what_to_install(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    with pytest.raises(ExecutorError, match=r"pip install 'osgd\[ray\]'"):
        RayExecutor().connect()
    result = runner.invoke(app, ["--data-dir", str(tmp_path), "--executor", "ray", "run", str(GOLDEN)])
    assert result.exit_code == 2
    assert result.output.strip().splitlines() == [
        "error: the Ray executor needs Ray, which is not installed: pip install 'osgd[ray]' "
        "(or pip install 'ray[default]')"
    ]


def test_the_executor_comes_from_the_options_or_the_config(tmp_path: Path) -> None:
    result = runner.invoke(app, ["--executor", "dask", "status", "--config", str(GOLDEN)])
    assert result.exit_code == 2 and "unknown executor 'dask'; use process or ray" in result.output
    result = runner.invoke(app, ["status", "--config", str(GOLDEN), "--set", "executor.backend=dask"])
    assert result.exit_code == 2
    assert "[executor] backend = 'dask'" in result.output and "'process' or 'ray'" in result.output
    config = load_pipeline(GOLDEN, ["executor.backend=ray", "executor.ray_address=auto"])
    assert (config.executor.backend, config.executor.ray_address) == ("ray", "auto")
    assert load_pipeline(GOLDEN).executor.backend == "process"
    # `osgd config` writes the section, and it reads back.
    result = runner.invoke(app, ["config", "--config", str(GOLDEN), "--set", "executor.backend=ray"])
    assert result.exit_code == 0 and '[executor]\n# where items run' in result.output
    saved = tmp_path / "golden.toml"
    saved.write_text(result.output)
    assert load_pipeline(saved).executor == config.executor.model_copy(update={"ray_address": ""})


def test_make_executor_picks_the_backend() -> None:
    assert isinstance(make_executor(1), SerialExecutor)
    ray_executor = make_executor(3, "ray", "auto")
    assert isinstance(ray_executor, RayExecutor) and (ray_executor.address, ray_executor.workers) == ("auto", 3)
    with pytest.raises(ValueError, match="unknown executor"):
        make_executor(2, "dask")


def test_the_runtime_environment_carries_what_workers_must_share(monkeypatch: pytest.MonkeyPatch) -> None:
    pinned = portable_settings()
    for name, value in pinned.items():
        monkeypatch.setenv(name, value)
    monkeypatch.delenv("PYTHONHASHSEED", raising=False)
    monkeypatch.setenv("OSGD_NATIVE_SIMD", "1")
    environment = ray_runtime_env({"env_vars": {"PYTHONPATH": "/x"}, "py_modules": []})
    # The pins themselves are set by each worker for its own processor; what the user chose travels.
    assert environment["env_vars"] == {"PYTHONHASHSEED": "0", "OSGD_NATIVE_SIMD": "1", "PYTHONPATH": "/x"}
    assert environment["worker_process_setup_hook"] == "osgd.kernels.pin_kernels"
    assert environment["py_modules"] == []
    monkeypatch.setenv("OPENBLAS_CORETYPE", "SkylakeX")
    assert ray_runtime_env()["env_vars"]["OPENBLAS_CORETYPE"] == "SkylakeX"


def test_a_worker_with_another_osgd_refuses_to_build() -> None:
    assert call_checked(code_fingerprint(), abs, -3) == 3
    refused = call_checked("0" * 64, abs, -3)
    assert isinstance(refused, TaskFailure)
    assert "runs another osgd than the driver" in refused.cause and "install the same osgd" in refused.cause


@needs_ray
def test_an_unreachable_cluster_is_one_line_at_once(tmp_path: Path) -> None:
    import ray  # noqa: PLC0415

    if ray.is_initialized():
        pytest.skip("this process is already connected to a Ray cluster")
    result = runner.invoke(app, ["--data-dir", str(tmp_path), "--executor", "ray", "--ray-address", "127.0.0.1:1",
                                 "run", str(GOLDEN)])
    assert result.exit_code == 2
    assert result.output.startswith("error: cannot reach the Ray cluster at 127.0.0.1:1: Connection refused;")
    assert len(result.output.strip().splitlines()) == 1


# -- a local Ray cluster ----------------------------------------------------------------


@pytest.fixture(scope="module")
def cluster() -> Iterator[Any]:
    """A head (no CPUs: it only schedules) and two worker nodes of one CPU each; this process is a driver."""
    import ray  # noqa: PLC0415
    from ray.cluster_utils import Cluster  # noqa: PLC0415

    with pytest.MonkeyPatch.context() as patch:
        for name in ray_tasks.PINNED:  # started as `ray start` on another machine would be
            patch.delenv(name, raising=False)
        cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 0, "include_dashboard": False})
        for _ in range(2):
            cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    ray.init(address=cluster.address, runtime_env=ray_runtime_env({"env_vars": {"PYTHONPATH": str(TESTS)}}),
             logging_level=logging.WARNING)
    yield cluster
    ray.shutdown()
    cluster.shutdown()


def _osgd(*arguments: str) -> subprocess.CompletedProcess:
    """``python -m osgd ARGUMENTS`` as `osgd` runs (the kernels it pins, hash seed 0)."""
    return subprocess.run([sys.executable, "-m", "osgd", *arguments], capture_output=True, text=True,
                          env={**os.environ, "PYTHONHASHSEED": "0"}, check=False)


@pytest.fixture(scope="module")
def reference(golden_data_dir: Path) -> Path:
    """The golden pipeline built by the process pool (two workers): its data dir."""
    return golden_data_dir


def _manifest(data_dir: Path) -> str:
    return (data_dir / "manifests" / "golden.json").read_text()


def _assert_no_corrupt_shard(data_dir: Path) -> None:
    """After the leftovers of killed workers are cleaned, every file is a whole shard of the manifest."""
    store = ShardStore(data_dir)
    store.clean_leftovers()
    manifest = json.loads(_manifest(data_dir))
    for entry in manifest["stages"].values():
        table, keys = entry["table"], {shard["key"] for shard in entry["shards"]}
        for key in keys:
            store.verify(table, key)
        files = {path.name for path in (data_dir / table).iterdir() if path.name != ".locks"}
        assert {name.split(".")[0] for name in files} == keys, files
        assert not list((data_dir / table / ".locks").iterdir())


@needs_ray
def test_tasks_run_on_the_worker_nodes_with_the_kernels_pinned(cluster: Any) -> None:
    executor = RayExecutor()
    outcomes = dict(executor.map_unordered(ray_tasks.worker_facts, list(range(12))))
    assert sorted(outcomes) == list(range(12))
    # A worker process serves many tasks: what a stage keeps per process is kept.
    assert len({facts["pid"] for facts in outcomes.values()}) < 12
    head = cluster.head_node.node_id
    assert all(facts["node"] != head for facts in outcomes.values())
    expected = {"PYTHONHASHSEED": "0", **portable_settings()}
    for facts in outcomes.values():
        assert {name: value for name, value in facts["environment"].items() if value is not None} == expected


@needs_ray
def test_a_raising_task_comes_back_as_a_failure_and_the_others_finish(cluster: Any) -> None:
    outcomes = dict(RayExecutor(workers=2).map_unordered(ray_tasks.fail_on_odd, list(range(6))))
    assert [outcomes[index] for index in (0, 2, 4)] == [0, 4, 16]
    for index in (1, 3, 5):
        assert outcomes[index].cause == f"ValueError: task {index} is odd"
        assert "fail_on_odd" in outcomes[index].traceback


@needs_ray
def test_the_toy_stage_on_ray_reports_like_the_process_pool(cluster: Any, tmp_path: Path) -> None:
    stage, params = ToyStage(), ToyParams(items=6, fail_item=2)
    shards = stage.planned(params, 0, {})
    seen: list[tuple[str, str]] = []
    on_ray = run_stage(stage, shards, ShardStore(tmp_path / "ray"), RayExecutor(),
                       on_item=lambda item, status: seen.append((item, status)))
    serial = run_stage(stage, shards, ShardStore(tmp_path / "serial"), SerialExecutor())
    assert sorted(seen) == sorted([(f"toy_{index:03d}", "failed" if index == 2 else "built") for index in range(6)])
    assert (on_ray.built, on_ray.reused, [failure.item_id for failure in on_ray.failures]) == (5, 0, ["toy_002"])
    assert on_ray.failures[0].cause == "RuntimeError: item 2 is set to fail"
    assert on_ray.records == serial.records  # the same keys, rows and bytes


@needs_ray
def test_broken_models_fail_alone_on_ray_with_the_same_failure_table(cluster: Any, tmp_path: Path) -> None:
    """tests/test_item_failures.py's broken models, annotated through Ray by the command line."""
    from test_item_failures import _counts, _setup  # noqa: PLC0415

    config = _setup(tmp_path)
    result = runner.invoke(app, ["--data-dir", str(tmp_path / "data"), "--executor", "ray", "annotate",
                                 "--config", str(config)])
    assert result.exit_code == 1, result.output
    table = result.output[result.output.index("2 item(s) failed"):]
    broken_obj = f"{tmp_path}/osgd/knife_003/model/model_normalized.obj"
    assert re.search(rf"models +osgd/knife_003 +{re.escape(broken_obj)} +trimesh cannot read it \(IndexError", table)
    assert re.search(r"models +user/drill +\S+drill.toml +category = 'screwdrivr': unknown category", table)
    assert _counts(result.output) == {"models": (3, 0, 2), "grasps": (3, 0, 0)}
    assert re.search(r"^models: 5/5 items \(3 built, 2 failed\), done in \d+s$", result.output, re.MULTILINE)


@needs_ray
def test_the_golden_pipeline_on_ray_gives_the_process_pools_manifest(
    cluster: Any, reference: Path, tmp_path: Path
) -> None:
    result = _osgd("--data-dir", str(tmp_path), "--executor", "ray", "--ray-address", cluster.address,
                   "run", str(GOLDEN))
    assert result.returncode == 0, result.stdout + result.stderr
    assert "samples: 2/2 items (2 built), done in" in result.stderr  # the same progress lines
    assert _manifest(tmp_path) == _manifest(reference)
    _assert_no_corrupt_shard(tmp_path)


def _starts(trace: Path, module: str | None = None) -> list[tuple[str, str]]:
    """(node id, shard key) of every build started so far, in order; only ``module``'s where given."""
    lines = trace.read_text().splitlines() if trace.exists() else []
    starts = (line.split() for line in lines)
    return [(node, key) for node, key, stage in starts if module is None or stage == module]


#: The module of the stage whose build a test kills a node in the middle of.
CHECKS = "osgd.checks.stage"


def _kill_when_building_there(cluster: Any, node: Any, trace: Path, killed: list[str]) -> Any:
    """An ``on_item`` that kills ``node`` once it has started a checks build.

    Called when the first checks item is done: it waits for a checks build
    on ``node`` to start (:class:`_Traced` holds such a build there until the
    node dies, so the node is surely in the middle of it), kills the node's
    processes and notes the item's key.
    """

    def on_item(name: str, item: str, status: str) -> None:
        if name != "checks" or killed:
            return
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            there = [key for node_id, key in _starts(trace, CHECKS) if node_id == node.node_id]
            if there:
                cluster.remove_node(node, allow_graceful=False)
                killed.append(there[0])
                return
            time.sleep(0.02)

    return on_item


class _Traced:
    """An executor that notes where each build starts (:func:`ray_tasks.traced`) and holds the
    checks builds on the node ``hold_on`` (a node id) until that node is killed."""

    def __init__(self, inner: RayExecutor, trace: Path, hold_on: str) -> None:
        self.inner, self.trace, self.hold = inner, trace, (hold_on, CHECKS)

    def map_unordered(self, function: Any, tasks: Any) -> Iterator[tuple[int, Any]]:
        traced = functools.partial(ray_tasks.traced, str(self.trace), function, hold=self.hold)
        return self.inner.map_unordered(traced, tasks)


def _run_golden(store: ShardStore, executor: Any, on_item: Any = None) -> list:
    names = tuple(stage.name for stage in stages())
    return run_stages(load_pipeline(GOLDEN), store, executor, names, on_item=on_item)


def _run_golden_killing_a_node(cluster: Any, tmp_path: Path, executor: Any) -> tuple[ShardStore, Path, list, list]:
    """The golden pipeline into ``tmp_path/data`` on a cluster whose added third node is killed
    while it builds a checks shard; returns the store, the trace, the killed build's key(s) and the reports."""
    doomed = cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    trace, killed = tmp_path / "trace.txt", []
    store = ShardStore(tmp_path / "data")
    reports = _run_golden(store, _Traced(executor, trace, doomed.node_id),
                          _kill_when_building_there(cluster, doomed, trace, killed))
    return store, trace, killed, reports


@needs_ray
@pytest.mark.slow
def test_a_worker_node_killed_mid_stage_leaves_no_corrupt_shard(
    cluster: Any, reference: Path, tmp_path: Path
) -> None:
    """A third node dies while it builds a checks shard: Ray runs the task again elsewhere."""
    store, trace, killed, reports = _run_golden_killing_a_node(cluster, tmp_path, RayExecutor())
    assert killed, "the node was never seen building a checks shard"
    # Ray ran the killed build again on another node.
    assert [node for node, key in _starts(trace) if key == killed[0]][1:], "the killed build was not run again"
    assert all(report.ok for report in reports), [report.failures for report in reports]
    assert _manifest(tmp_path / "data") == _manifest(reference)
    _assert_no_corrupt_shard(tmp_path / "data")
    # A rerun builds nothing and writes the same manifest.
    again = _run_golden(store, RayExecutor())
    assert sum(report.built for report in again) == 0
    assert _manifest(tmp_path / "data") == _manifest(reference)


@needs_ray
@pytest.mark.slow
def test_without_retries_a_killed_node_fails_its_items_and_a_rerun_completes(
    cluster: Any, reference: Path, tmp_path: Path
) -> None:
    store, _, killed, reports = _run_golden_killing_a_node(cluster, tmp_path, RayExecutor(max_retries=0))
    failures = [failure for report in reports for failure in report.failures]
    assert killed and failures, "the killed node's build should have failed"
    # One line each, e.g. "NodeDiedError: Task failed because the node it was running on is dead ...".
    assert all(failure.cause.startswith(("NodeDiedError: ", "WorkerCrashedError: ")) for failure in failures), failures
    _assert_no_corrupt_shard(tmp_path / "data")
    again = _run_golden(store, RayExecutor())
    assert all(report.ok for report in again)
    assert _manifest(tmp_path / "data") == _manifest(reference)
