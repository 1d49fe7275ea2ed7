"""Bad inputs and crashes: bounded reads of configs and inputs, unreadable sources named at the
models stage, no orphan workers, ``osgd status`` exit codes, progress lines written once."""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import trimesh
from typer.testing import CliRunner

from osgd.cli import _unrepeated, app
from osgd.pipeline import STATUS_EXIT_CODES, StageStatus, status_exit_code

ROOT = Path(__file__).resolve().parents[1]
runner = CliRunner()


def _osgd(*args: str, timeout: float = 60, memory: int = 2 << 30) -> subprocess.CompletedProcess:
    """``python -m osgd ARGS`` with its address space bounded (an unbounded read fails fast, not the machine)."""
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (memory, memory))

    return subprocess.run([sys.executable, "-m", "osgd", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout, preexec_fn=limit, check=False)


def _one_error_line(result: subprocess.CompletedProcess, *expected: str) -> None:
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    for text in expected:
        assert text in lines[0]
    assert "Traceback" not in result.stderr


# -- configs --------------------------------------------------------------------------------------------
def test_a_character_device_as_config_is_one_line_not_an_unbounded_read() -> None:
    _one_error_line(_osgd("run", "/dev/zero"), "/dev/zero", "a character device, not a regular file")


def test_a_fifo_as_config_is_one_line_and_never_opened(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe.toml"
    os.mkfifo(fifo)
    _one_error_line(_osgd("run", str(fifo), timeout=60), str(fifo), "a FIFO (named pipe)")


def test_a_huge_config_is_refused_by_its_size(tmp_path: Path) -> None:
    huge = tmp_path / "huge.toml"
    with open(huge, "wb") as handle:
        handle.truncate(3 << 30)  # sparse: 3 GiB that take no disk
    _one_error_line(_osgd("run", str(huge)), str(huge), "3.0 GiB, more than the 16.0 MiB")


def test_a_random_binary_config_names_the_file(tmp_path: Path) -> None:
    junk = tmp_path / "random.toml"
    junk.write_bytes(bytes(range(256)) * 4)
    result = runner.invoke(app, ["run", str(junk)])
    assert result.exit_code == 2
    assert f"{junk}: not a pipeline config: not UTF-8 text" in result.output


def test_a_config_that_is_a_folder_or_a_link_loop_is_named(tmp_path: Path) -> None:
    loop = tmp_path / "loop.toml"
    os.symlink(loop, loop)
    result = runner.invoke(app, ["run", str(loop)])
    assert result.exit_code == 2 and f"{loop}: cannot be read as a pipeline config: a symbolic link loop" in (
        result.output)
    result = runner.invoke(app, ["run", str(tmp_path)])
    assert result.exit_code == 2 and "a folder, not a regular file" in result.output


# -- unreadable sources ---------------------------------------------------------------------------------
def _write_user_dir(folder: Path) -> None:
    folder.mkdir()
    mesh = trimesh.creation.box(bounds=[[-100, -12, -8], [100, 12, 8]])
    os.symlink("nowhere.stl", folder / "broken.stl")
    os.symlink("loop_b.stl", folder / "loop_a.stl")
    os.symlink("loop_a.stl", folder / "loop_b.stl")
    os.mkfifo(folder / "pipe.obj")
    mesh.export(folder / "piped.stl")  # a good mesh whose sidecar is a FIFO
    os.mkfifo(folder / "piped.toml")
    trimesh.creation.icosphere(subdivisions=3).export(folder / "big.stl")  # over the size limit the test sets
    (folder / "big.toml").write_text('category = "hammer"\nlength = 0.3\n')


def _write_osgd_dir(folder: Path) -> None:
    (folder / "hammer_001" / "model").mkdir(parents=True)
    os.symlink("gone.obj", folder / "hammer_001" / "model" / "model_normalized.obj")
    os.symlink("knife_009", folder / "knife_009")  # a folder that is a link to itself


def test_unreadable_sources_are_failed_items_named_at_the_models_stage(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("OSGD_MAX_INPUT_BYTES", "10000")
    _write_user_dir(tmp_path / "user")
    _write_osgd_dir(tmp_path / "osgd")
    config = tmp_path / "unreadable.toml"
    config.write_text(f'[models]\nsources = ["user", "osgd"]\nuser_dir = "{tmp_path / "user"}"\n'
                      f'osgd_dir = "{tmp_path / "osgd"}"\n')
    result = runner.invoke(app, ["--data-dir", str(tmp_path / "data"), "--workers", "1", "annotate",
                                 "--config", str(config)])
    assert result.exit_code == 1, result.output
    rows = {line.split()[1]: line for line in result.output.splitlines() if line.startswith("  models  ")}
    expected = {
        "user/broken": ("broken.stl", "a broken symbolic link (to 'nowhere.stl'"),
        "user/loop_a": ("loop_a.stl", "a symbolic link loop"),
        "user/loop_b": ("loop_b.stl", "a symbolic link loop"),
        "user/pipe": ("pipe.obj", "a FIFO (named pipe), not a regular file"),
        "user/piped": ("piped.toml", "a FIFO (named pipe), not a regular file"),
        "user/big": ("big.stl", "more than the 9.8 KiB an input file may have"),
        "osgd/hammer_001": ("hammer_001/model/model_normalized.obj", "a broken symbolic link (to 'gone.obj'"),
        "osgd/knife_009": ("knife_009", "a symbolic link loop"),
    }
    assert set(expected) <= set(rows), result.output
    for item, (file, cause) in expected.items():
        assert file in rows[item] and cause in rows[item], rows[item]
    assert "models: 0 shards, 0 rows (0 built, 0 reused, 8 failed)" in result.output
    stage_times = next(line for line in result.output.splitlines() if line.strip().startswith("models  ") and
                       "%" in line)
    assert stage_times.split()[1:5] == ["8", "0", "0", "8"]


# -- no orphans -----------------------------------------------------------------------------------------
def _children(pid: int) -> set[int]:
    """Every live (not zombie) descendant of ``pid``."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if fields[0] != "Z":
                parents[int(entry.name)] = int(fields[1])
    found, frontier = set(), {pid}
    while frontier:
        frontier = {child for child, parent in parents.items() if parent in frontier} - found
        found |= frontier
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_workers_end_when_the_main_process_is_killed(tmp_path: Path) -> None:
    main = subprocess.Popen([sys.executable, "-m", "osgd", "--data-dir", str(tmp_path / "data"), "--workers", "2",
                             "run", "pipelines/golden.toml"], cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    workers: set[int] = set()
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(workers) < 3:  # two workers and the resource tracker
            workers = _children(main.pid)
            time.sleep(0.2)
        assert len(workers) >= 3, f"the run started {len(workers)} child processes"
        os.kill(main.pid, signal.SIGKILL)
        main.wait(10)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and any(_alive(pid) for pid in workers):
            time.sleep(0.1)
        assert not [pid for pid in workers if _alive(pid)], "worker processes outlived the main process"
    finally:  # a failed test leaves no processes either (only this run's: a multiprocessing child or the run)
        for pid in _children(main.pid) | workers:
            with contextlib.suppress(OSError):
                if _alive(pid) and b"multiprocessing" in Path(f"/proc/{pid}/cmdline").read_bytes():
                    os.kill(pid, signal.SIGKILL)
        if main.poll() is None:
            main.kill()


def test_a_worker_initializer_leaves_a_live_parent_alone() -> None:
    from osgd.executor import ProcessPoolExecutor  # noqa: PLC0415

    results = dict(ProcessPoolExecutor(2).map_unordered(abs, [-1, -2, -3]))
    assert results == {0: 1, 1: 2, 2: 3}


# -- osgd status ----------------------------------------------------------------------------------------
def test_status_exit_code_is_zero_only_when_everything_is_done() -> None:
    done = StageStatus("models", done=3, missing=0, corrupt=0, stale=0, failed=0)
    assert status_exit_code([done, done]) == 0
    assert status_exit_code([done, StageStatus("grasps", 1, 2, 0, 0, 0)]) == STATUS_EXIT_CODES["missing"]
    everything = StageStatus("scenes", 0, 1, 1, 1, 1)
    assert status_exit_code([everything]) == 4 + 8 + 16 + 32


def test_status_exits_non_zero_for_missing_failed_corrupt_and_stale_shards(tmp_path: Path) -> None:
    user = tmp_path / "user"
    user.mkdir()
    os.symlink("nowhere.obj", user / "broken.obj")
    config = tmp_path / "small.toml"
    config.write_text(f'[pipeline]\nname = "small"\n[models]\nsources = ["procedural", "user"]\n'
                      f'procedural_per_category = 1\nuser_dir = "{user}"\n[grasps]\napproach_count = 1\n'
                      f"sampler_max_pairs = 4\n")
    data = tmp_path / "data"
    built = runner.invoke(app, ["--data-dir", str(data), "--workers", "1", "annotate", "--config", str(config)])
    assert built.exit_code == 1, built.output  # the broken link failed
    status = ["--data-dir", str(data), "status", "--config", str(config)]
    result = runner.invoke(app, status)
    assert result.exit_code == 4 + 8, result.output  # checks, scenes, samples missing; one model failed
    assert "small: not complete: " in result.output and "1 failed" in result.output
    manifest = json.loads((data / "manifests" / "small.json").read_text())
    key = manifest["stages"]["models"]["shards"][0]["key"]
    shard = data / "models" / f"{key}.parquet"
    shard.write_bytes(shard.read_bytes()[:-10] + b"corrupted!")
    (data / "models" / f"{'f' * 64}.parquet").write_bytes(b"left from another plan")
    result = runner.invoke(app, status)
    assert result.exit_code == 4 + 8 + 16 + 32, result.output
    assert "Exit code" in runner.invoke(app, ["status", "--help"]).output


# -- progress lines -------------------------------------------------------------------------------------
def test_a_progress_line_equal_to_the_one_before_is_not_written_again() -> None:
    from osgd.progress import LineProgress  # noqa: PLC0415

    lines: list[str] = []
    with LineProgress(_unrepeated(lines.append), interval=0.05) as progress:
        progress.on_stage("checks", 10)
        time.sleep(0.5)  # ten timer lines while no item has ended: all "checks: 10 items"
        progress.on_item("checks", "a", "built")
        time.sleep(0.2)
    assert lines[0] == "checks: 10 items"
    assert lines.count("checks: 10 items") == 1, lines
    assert any(line.startswith("checks: 1/10 items (1 built)") for line in lines)
    assert all(first != second for first, second in itertools.pairwise(lines))
