"""The stage framework on the real store: keys, atomic writes, resume,
corruption, executors, failures, configs, manifests."""

from __future__ import annotations

import fcntl
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from toy_stage import ToyParams, ToyStage

from osgd.config import ConfigError, build_config
from osgd.contract.shards import ShardError, file_sha256
from osgd.executor import WORKER_DIED, ProcessPoolExecutor, SerialExecutor, TaskFailure
from osgd.stage import run_stage
from osgd.store import ShardStore, shard_key

TESTS = Path(__file__).resolve().parent

# -- keys ----------------------------------------------------------------------

json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=8),
    lambda children: st.lists(children, max_size=3) | st.dictionaries(st.text(max_size=5), children, max_size=3),
    max_leaves=8,
)


@settings(max_examples=150, deadline=None)
@given(
    payload=st.dictionaries(st.text(max_size=6), json_values, max_size=4),
    other=st.dictionaries(st.text(max_size=6), json_values, max_size=4),
    inputs=st.lists(st.text(alphabet="0123456789abcdef", min_size=4, max_size=8), max_size=4),
)
def test_key_changes_exactly_when_payload_changes(payload: dict, other: dict, inputs: list) -> None:
    key = shard_key("stage", 1, "item", payload, inputs)
    assert (shard_key("stage", 1, "item", other, inputs) == key) == (other == payload)


@settings(max_examples=100, deadline=None)
@given(inputs=st.lists(st.text(alphabet="0123456789abcdef", min_size=4, max_size=8), min_size=1, max_size=5,
                       unique=True))
def test_key_ignores_input_order_but_not_input_set(inputs: list) -> None:
    key = shard_key("stage", 1, "item", {"a": 1}, inputs)
    assert shard_key("stage", 1, "item", {"a": 1}, list(reversed(inputs))) == key
    assert shard_key("stage", 1, "item", {"a": 1}, inputs[1:]) != key
    assert shard_key("stage", 1, "item", {"a": 1}, [*inputs, "ffff0000"]) != key


def test_key_covers_stage_name_version_and_item() -> None:
    base = shard_key("stage", 1, "item", {"seed": 0}, ["k"])
    assert shard_key("stage", 2, "item", {"seed": 0}, ["k"]) != base
    assert shard_key("other", 1, "item", {"seed": 0}, ["k"]) != base
    assert shard_key("stage", 1, "item2", {"seed": 0}, ["k"]) != base
    assert shard_key("stage", 1, "item", {"seed": 1}, ["k"]) != base
    assert shard_key("stage", 1, "item", {"seed": 0}, ["k"]) == base


def test_planned_keys_follow_every_parameter_and_the_seed() -> None:
    stage = ToyStage()
    base = [shard.key for shard in stage.planned(ToyParams(), 0, {})]
    assert len(set(base)) == len(base)
    for change in ({"rows": 51}, {"scale": 2.0}, {"fail_item": 3}):
        changed = [shard.key for shard in stage.planned(ToyParams(**change), 0, {})]
        assert not set(changed) & set(base), change
    assert not {shard.key for shard in stage.planned(ToyParams(), 1, {})} & set(base)
    # More items keep the keys of the existing ones? No: `items` is a
    # parameter every item's payload carries, so all keys change; the
    # location field `workdir` is not part of any key.
    moved = [shard.key for shard in stage.planned(ToyParams(workdir="/elsewhere"), 0, {})]
    assert moved == base


# -- writing, resuming, corruption ----------------------------------------------


def _files(root: Path) -> dict[str, bytes]:
    return {path.name: path.read_bytes() for path in sorted((root / "checks").glob("*.parquet"))}


def _run(root: Path, executor=None, **params) -> tuple:
    stage = ToyStage()
    shards = stage.planned(ToyParams(**params), 7, {})
    return run_stage(stage, shards, ShardStore(root), executor or SerialExecutor()), shards


def test_rerun_reuses_everything_and_changes_nothing(tmp_path: Path) -> None:
    first, shards = _run(tmp_path)
    assert (first.built, first.reused) == (len(shards), 0)
    before = {path: path.stat().st_mtime_ns for path in (tmp_path / "checks").iterdir()}
    second, _ = _run(tmp_path)
    assert (second.built, second.reused) == (0, len(shards))
    assert {path: path.stat().st_mtime_ns for path in (tmp_path / "checks").iterdir()} == before
    assert second.notes == {"toy_000": ["built toy_000"]}  # notes survive the resume


def test_truncated_and_altered_shards_are_detected_and_rebuilt(tmp_path: Path) -> None:
    _, shards = _run(tmp_path)
    reference = _files(tmp_path)
    store = ShardStore(tmp_path)
    truncated = store.shard_path("checks", shards[1].key)
    truncated.write_bytes(truncated.read_bytes()[:100])
    altered = store.shard_path("checks", shards[3].key)
    data = bytearray(altered.read_bytes())
    data[len(data) // 2] ^= 0xFF
    altered.write_bytes(bytes(data))
    assert not store.is_done("checks", shards[1].key)
    assert not store.is_done("checks", shards[3].key)

    report, _ = _run(tmp_path)
    assert report.built == 2
    assert len(report.rebuilt) == 2
    assert all("checksum" in problem for problem in report.rebuilt)
    assert _files(tmp_path) == reference


def test_a_checksum_disagreeing_with_the_manifest_is_rebuilt(tmp_path: Path) -> None:
    _, shards = _run(tmp_path)
    stage = ToyStage()
    manifest = {shards[0].key: "0" * 64}
    report = run_stage(stage, shards, ShardStore(tmp_path), manifest_shards=manifest)
    assert report.built == 1
    assert "manifest" in report.rebuilt[0]


def test_a_shard_without_its_checksum_counts_as_missing(tmp_path: Path) -> None:
    _, shards = _run(tmp_path)
    store = ShardStore(tmp_path)
    store.checksum_path("checks", shards[2].key).unlink()
    report, _ = _run(tmp_path)
    assert report.built == 1


def test_process_pool_gives_byte_identical_shards(tmp_path: Path) -> None:
    _run(tmp_path / "serial")
    report, shards = _run(tmp_path / "pool", ProcessPoolExecutor(2))
    assert report.ok and report.built == len(shards)
    assert _files(tmp_path / "pool") == _files(tmp_path / "serial")


def test_a_failing_item_is_reported_and_the_others_survive(tmp_path: Path) -> None:
    report, shards = _run(tmp_path, ProcessPoolExecutor(2), fail_item=2)
    assert not report.ok
    assert [failure.item_id for failure in report.failures] == ["toy_002"]
    assert "item 2 is set to fail" in report.failures[0].traceback
    assert "RuntimeError" in report.failures[0].error
    store = ShardStore(tmp_path)
    done = [shard.item.item_id for shard in shards if store.is_done("checks", shard.key)]
    assert done == [shard.item.item_id for shard in shards if shard.item.item_id != "toy_002"]


def _square_or_crash(task: int) -> int:
    """A task of the pool: task 3 kills its worker as a segfault in native code would."""
    if task == 3:
        os.kill(os.getpid(), signal.SIGSEGV)
    return task * task


def test_a_task_that_kills_its_worker_fails_alone_and_the_others_finish() -> None:
    results = dict(ProcessPoolExecutor(2).map_unordered(_square_or_crash, list(range(7))))
    assert sorted(results) == list(range(7))
    assert isinstance(results[3], TaskFailure) and results[3].error == WORKER_DIED
    assert {index: result for index, result in results.items() if index != 3} == {
        index: index * index for index in range(7) if index != 3}


def _toy_command(root: Path, workers: int, items: int) -> list[str]:
    return [sys.executable, str(TESTS / "run_toy.py"), str(root), str(workers), str(items)]


def _environment(delay: float, trace: Path | None = None) -> dict[str, str]:
    environment = {**os.environ, "OSGD_TOY_DELAY": str(delay)}
    if trace is not None:
        environment["OSGD_TOY_TRACE"] = str(trace)
    return environment


@pytest.mark.parametrize("workers", [1, 2])
def test_sigkill_halfway_then_resume_gives_identical_files(tmp_path: Path, workers: int) -> None:
    items = 8
    subprocess.run(_toy_command(tmp_path / "clean", 1, items), check=True, capture_output=True)
    reference = _files(tmp_path / "clean")
    assert len(reference) == items

    trace = tmp_path / "trace"
    trace.mkdir()
    interrupted = tmp_path / "interrupted"
    process = subprocess.Popen(
        _toy_command(interrupted, workers, items), env=_environment(0.4, trace), start_new_session=True,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 60
    while len(list((interrupted / "checks").glob("*.sha256"))) < 3 and time.monotonic() < deadline:
        time.sleep(0.05)
    os.killpg(process.pid, signal.SIGKILL)  # the whole group: parent and pool workers
    process.wait()
    finished = len(list((interrupted / "checks").glob("*.sha256")))
    assert 3 <= finished < items, "the run was not interrupted halfway"
    (trace / "builds.log").unlink()

    result = subprocess.run(_toy_command(interrupted, workers, items), env=_environment(0.0, trace),
                            check=True, capture_output=True, text=True)
    assert _files(interrupted) == reference
    rebuilt = (trace / "builds.log").read_text().split()
    store = ShardStore(interrupted)
    # Only the shards that had not been finished were built again.
    assert len(rebuilt) <= items - finished + (workers - 1)
    assert f"reused={items - len(rebuilt)}" in result.stdout or f"built={len(rebuilt)}" in result.stdout
    assert all(store.is_done("checks", path.stem) for path in (interrupted / "checks").glob("*.parquet"))


def test_two_processes_on_one_data_dir_do_not_corrupt_it(tmp_path: Path) -> None:
    commands = [_toy_command(tmp_path / "shared", 1, 10) for _ in range(2)]
    processes = [subprocess.Popen(command, stdout=subprocess.PIPE, text=True, env=_environment(0.05))
                 for command in commands]
    outputs = [process.communicate()[0] for process in processes]
    assert all(process.returncode == 0 for process in processes), outputs
    subprocess.run(_toy_command(tmp_path / "alone", 1, 10), check=True, capture_output=True)
    assert _files(tmp_path / "shared") == _files(tmp_path / "alone")
    built = sum(int(output.split("built=")[1].split()[0]) for output in outputs)
    assert built == 10  # the shard locks kept the two from building the same shard twice


def test_atomic_write_leaves_no_partial_final_file(tmp_path: Path) -> None:
    store = ShardStore(tmp_path)
    _run(tmp_path)
    names = [path.name for path in (tmp_path / "checks").iterdir() if path.is_file()]
    assert all(name.endswith((".parquet", ".sha256", ".notes.json")) for name in names)
    for path in (tmp_path / "checks").glob("*.parquet"):
        assert file_sha256(path) == store.verify("checks", path.stem).sha256


def test_writing_rows_of_the_wrong_schema_names_the_table(tmp_path: Path) -> None:
    import pyarrow as pa  # noqa: PLC0415

    with pytest.raises(ValueError, match="checks"):
        ShardStore(tmp_path).write("checks", "k" * 64, "item", pa.table({"model_id": ["a"]}))
    assert not (tmp_path / "checks" / f"{'k' * 64}.parquet").exists()


# -- configs ----------------------------------------------------------------------


def test_config_errors_name_the_key_the_value_and_what_is_allowed() -> None:
    with pytest.raises(ConfigError) as error:
        build_config({"pipeline": {"name": "x"}, "toy": {"rows": "many"}}, {"toy": ToyParams}, origin="p.toml")
    message = str(error.value)
    assert "p.toml" in message and "[toy] rows" in message and "'many'" in message and "integer" in message
    with pytest.raises(ConfigError, match=r"\[toy\] colour"):
        build_config({"toy": {"colour": 1}}, {"toy": ToyParams}, origin="p.toml")
    with pytest.raises(ConfigError, match="unknown section"):
        build_config({"toys": {}}, {"toy": ToyParams}, origin="p.toml")


def test_overrides_and_environment_variables(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TOY_DIR", "/data/toys")
    config = build_config(
        {"pipeline": {"name": "x", "seed": 3}, "toy": {"rows": 5, "workdir": "${TOY_DIR}/a"}},
        {"toy": ToyParams},
        overrides=["toy.rows=9", "toy.scale=0.5", "pipeline.seed=4"],
    )
    assert config.params["toy"].rows == 9
    assert config.params["toy"].scale == 0.5
    assert config.params["toy"].workdir == "/data/toys/a"
    assert config.pipeline.seed == 4
    fallback = build_config({"toy": {"workdir": "${TOY_UNSET_VARIABLE:-/fallback}"}}, {"toy": ToyParams})
    assert fallback.params["toy"].workdir == "/fallback"
    with pytest.raises(ConfigError, match="TOY_UNSET_VARIABLE"):
        build_config({"toy": {"workdir": "${TOY_UNSET_VARIABLE}"}}, {"toy": ToyParams})


def test_atomic_writes_get_ordinary_file_permissions(tmp_path: Path) -> None:
    """Shards and manifests are shared with other users: not the 0600 of a temporary file."""
    from osgd.store import atomic_write_bytes  # noqa: PLC0415

    previous = os.umask(0o022)
    try:
        atomic_write_bytes(tmp_path / "a.bin", b"x")
    finally:
        os.umask(previous)
    assert (tmp_path / "a.bin").stat().st_mode & 0o777 == 0o644


def test_a_shard_another_process_is_building_is_passed_over_then_waited_for(tmp_path: Path) -> None:
    """Several runs on one data dir (one machine or many) share out the work."""
    import threading  # noqa: PLC0415

    stage = ToyStage()
    shards = stage.planned(ToyParams(items=4), 7, {})
    store = ShardStore(tmp_path)
    busy = shards[0]
    locked, others_done = threading.Event(), threading.Event()
    order: list[str] = []

    def other_process() -> None:
        with ShardStore(tmp_path).lock("checks", busy.key) as held:
            assert held
            locked.set()
            others_done.wait(timeout=60)

    holder = threading.Thread(target=other_process)
    holder.start()
    locked.wait(timeout=10)

    def on_item(item_id: str, status: str) -> None:
        order.append(item_id)
        if len(order) == len(shards) - 1:
            others_done.set()

    report = run_stage(stage, shards, store, SerialExecutor(), on_item=on_item)
    holder.join()
    assert others_done.is_set()
    assert order[-1] == busy.item.item_id  # built after the lock was let go, not first
    assert report.built == len(shards) and report.ok


# -- caches and leftovers that cannot lie ---------------------------


def test_a_shard_copied_over_another_is_caught_by_the_key_it_holds(tmp_path: Path) -> None:
    _, shards = _run(tmp_path)
    reference = _files(tmp_path)
    store = ShardStore(tmp_path)
    source, target = shards[0].key, shards[1].key
    # Bytes and checksum file copied: the checksum file names the other key.
    for path in (store.shard_path, store.checksum_path):
        path("checks", target).write_bytes(path("checks", source).read_bytes())
    with pytest.raises(ShardError, match="checksum file of shard"):
        store.verify("checks", target)
    # A checksum file made to fit the copied bytes: the key inside the shard gives it away.
    record = json.loads(store.checksum_path("checks", source).read_text())
    store.checksum_path("checks", target).write_text(json.dumps({**record, "key": target}))
    with pytest.raises(ShardError, match=f"holds the shard of key {source[:12]}, not of its file name"):
        store.verify("checks", target)
    # With no manifest to compare with, a run still rebuilds it, and nothing else.
    report, _ = _run(tmp_path)
    assert report.built == 1 and "holds the shard of key" in report.rebuilt[0]
    assert _files(tmp_path) == reference


def _leftover(folder: Path, name: str) -> Path:
    """A temporary file as a write killed before its rename leaves it."""
    folder.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{name}.", suffix=".tmp", dir=folder)
    os.write(handle, b"half a shard")
    os.close(handle)
    return Path(temporary)


def test_leftover_temporary_and_lock_files_are_removed_but_held_ones_kept(tmp_path: Path) -> None:
    _, shards = _run(tmp_path)
    store = ShardStore(tmp_path)
    folder = tmp_path / "checks"
    assert not list((folder / ".locks").iterdir()), "lock files are removed as their lock is let go"
    stale = [_leftover(folder, f"{shards[0].key}.parquet"), _leftover(tmp_path / "manifests", "toy.json")]
    stale.append(_leftover(tmp_path / "cache" / "decompositions", "0" * 64 + ".npz"))
    stale_locks = [folder / ".locks" / f"{shard.key}.lock" for shard in shards[:3]]
    for path in stale_locks:
        path.touch()
    # A write in progress in another process: its temporary file is flock-ed.
    busy = _leftover(folder, f"{shards[1].key}.parquet")
    with open(busy, "rb") as writer, store.lock("checks", shards[3].key) as held:
        fcntl.flock(writer.fileno(), fcntl.LOCK_EX)
        assert held
        assert store.clean_leftovers() == (3, 3)
        assert busy.exists() and (folder / ".locks" / f"{shards[3].key}.lock").exists()
    assert not any(path.exists() for path in stale + stale_locks)
    assert _files(tmp_path)  # the shards themselves are untouched
    assert all(store.is_done("checks", shard.key) for shard in shards)


def _someone_waits_for_a_lock() -> bool:
    try:
        return "-> FLOCK" in Path("/proc/locks").read_text()
    except OSError:  # no /proc: carry on without knowing
        return True


def test_a_removed_lock_file_still_keeps_the_shard_exclusive(tmp_path: Path) -> None:
    """A waiter that wakes up on the file its holder removed must lock the new file, not share it."""
    import threading  # noqa: PLC0415

    store = ShardStore(tmp_path)
    waiting, acquired, release = threading.Event(), threading.Event(), threading.Event()

    def waiter() -> None:
        waiting.set()
        with store.lock("checks", "k" * 64) as held:
            assert held
            acquired.set()
            release.wait(timeout=60)

    with store.lock("checks", "k" * 64) as held:
        assert held
        thread = threading.Thread(target=waiter)
        thread.start()
        waiting.wait(timeout=10)
        deadline = time.monotonic() + 10
        while not _someone_waits_for_a_lock() and time.monotonic() < deadline:
            time.sleep(0.01)  # until the waiter sleeps in flock on the file about to be removed
    assert acquired.wait(timeout=30)
    with store.lock("checks", "k" * 64, wait=False) as third:
        assert not third, "two holders of one shard's lock"
    release.set()
    thread.join()
    assert not list((tmp_path / "checks" / ".locks").iterdir())


def test_config_integers_take_no_string_and_no_boolean() -> None:
    for value in ("4", True, 4.5):
        with pytest.raises(ConfigError, match=rf"p\.toml: \[toy\] rows = {re.escape(repr(value))}: .*integer"):
            build_config({"toy": {"rows": value}}, {"toy": ToyParams}, origin="p.toml")
    with pytest.raises(ConfigError, match=r"\[toy\] scale = 'big': .*number"):
        build_config({"toy": {"scale": "big"}}, {"toy": ToyParams}, origin="p.toml")
    with pytest.raises(ConfigError, match=r"\[pipeline\] seed = '1'"):
        build_config({"pipeline": {"seed": "1"}}, {"toy": ToyParams}, origin="p.toml")
    config = build_config({"toy": {"rows": 4, "scale": 2}}, {"toy": ToyParams}, origin="p.toml")
    assert config.params["toy"].rows == 4 and config.params["toy"].scale == 2.0  # an integer is a number


def test_an_unknown_key_lists_the_allowed_keys_and_an_override_is_blamed_for_its_error() -> None:
    with pytest.raises(ConfigError) as error:
        build_config({"toy": {"colour": 1}}, {"toy": ToyParams}, origin="p.toml")
    assert str(error.value) == (
        "p.toml: [toy] colour = 1: unknown key; allowed keys: items, rows, scale, fail_item, workdir"
    )
    with pytest.raises(ConfigError) as error:
        build_config({"toy": {"rows": 5}}, {"toy": ToyParams}, origin="p.toml", overrides=["toy.rows=many"])
    assert str(error.value).startswith("override 'toy.rows=many': [toy] rows = 'many': ")
    assert "p.toml" not in str(error.value)
    with pytest.raises(ConfigError, match=r"^override 'toys.rows=3': unknown section \[toys\]"):
        build_config({}, {"toy": ToyParams}, origin="p.toml", overrides=["toys.rows=3"])
