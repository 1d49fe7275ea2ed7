"""The osgd command line, invoked as a person would."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from osgd.cli import app

runner = CliRunner()


def test_help_lists_every_stage_command() -> None:
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    for command in ("annotate", "check", "stack", "render", "run", "status", "show", "export"):
        assert command in result.output


def test_a_bad_config_value_names_file_key_and_value(tmp_path: Path) -> None:
    config = tmp_path / "bad.toml"
    config.write_text('[pipeline]\nname = "bad"\nseed = "zero"\n')
    result = runner.invoke(app, ["--data-dir", str(tmp_path / "data"), "status", "--config", str(config)])
    assert result.exit_code == 2
    assert "bad.toml" in result.output and "seed" in result.output and "'zero'" in result.output


def test_an_unknown_section_is_an_error(tmp_path: Path) -> None:
    config = tmp_path / "typo.toml"
    config.write_text('[pipeline]\nname = "typo"\n[scene]\ncount = 3\n')
    result = runner.invoke(app, ["status", "--config", str(config)])
    assert result.exit_code == 2
    assert "unknown section" in result.output and "scene" in result.output


def test_a_missing_config_is_named(tmp_path: Path) -> None:
    result = runner.invoke(app, ["status", "--config", str(tmp_path / "nope.toml")])
    assert result.exit_code == 2
    assert "nope.toml" in result.output


def test_module_entry_point_runs() -> None:
    result = subprocess.run([sys.executable, "-m", "osgd", "--help"], capture_output=True, text=True, check=False)
    assert result.returncode == 0
    assert "Usage" in result.stdout


ROOT = Path(__file__).resolve().parents[1]


def test_every_committed_pipeline_config_is_valid() -> None:
    from osgd.pipeline import load_pipeline  # noqa: PLC0415

    configs = sorted((ROOT / "pipelines").glob("*.toml"))
    assert {path.stem for path in configs} >= {"default", "golden", "osgd", "gpu", "recipe-pairs96"}
    for path in configs:
        assert load_pipeline(path).pipeline.name == path.stem


def test_config_prints_every_parameter_and_reads_back_equal(tmp_path: Path) -> None:
    from osgd.pipeline import load_pipeline  # noqa: PLC0415

    result = runner.invoke(app, ["config", "--config", str(ROOT / "pipelines" / "default.toml"),
                                 "--set", "scenes.count=7"])
    assert result.exit_code == 0, result.output
    assert "scenes.count" not in result.output and "count = 7" in result.output
    saved = tmp_path / "default.toml"
    saved.write_text(result.output)
    original = load_pipeline(ROOT / "pipelines" / "default.toml", ["scenes.count=7"])
    again = load_pipeline(saved)
    assert again.pipeline == original.pipeline
    assert again.params == original.params
    # Each field is written with its description as a comment above it.
    assert "# scenes in all" in result.output


# -- one line per problem ---------------------------------------------


GOLDEN = ROOT / "pipelines" / "golden.toml"


def test_config_errors_keep_their_section_and_blame_the_override() -> None:
    result = runner.invoke(app, ["status", "--config", str(GOLDEN), "--set", "scenes.count=true"])
    assert result.exit_code == 2
    assert result.output.strip() == (
        "error: override 'scenes.count=true': [scenes] count = True: Input should be a valid integer"
    )


def _single_error_line(result) -> str:
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1, result.output
    return lines[0]


def test_a_data_dir_that_is_a_file_is_one_line(tmp_path: Path) -> None:
    afile = tmp_path / "data"
    afile.write_text("not a folder")
    for command in (["status", "--config", str(GOLDEN)], ["run", str(GOLDEN)]):
        line = _single_error_line(runner.invoke(app, ["--data-dir", str(afile), *command]))
        assert line == f"error: data dir {afile} is a file, not a folder; give --data-dir a folder path"
    below = afile / "sub"
    line = _single_error_line(runner.invoke(app, ["--data-dir", str(below), "run", str(GOLDEN)]))
    assert f"data dir {below} lies under {afile}, which is a file" in line


def _unwritable_folder(tmp_path: Path) -> Path:
    """A folder path this process cannot write in.

    chmod stops an ordinary user; root ignores it, but not sysfs, which
    refuses new folders even to root.
    """
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    for candidate in (locked / "data", Path("/sys/osgd-data")):
        try:
            candidate.mkdir()
        except OSError:
            return candidate
        candidate.rmdir()
    pytest.skip("found no folder this process cannot write in")


def test_an_unwritable_data_dir_is_one_line(tmp_path: Path) -> None:
    data = _unwritable_folder(tmp_path)
    line = _single_error_line(runner.invoke(app, ["--data-dir", str(data), "run", str(GOLDEN)]))
    assert line.startswith(f"error: data dir {data} is not writable (")
    assert line.endswith("give --data-dir a folder you can write to, or fix the folder's permissions")


def test_line_progress_reports_items_rate_and_time_left() -> None:
    import threading  # noqa: PLC0415

    from osgd.progress import LineProgress  # noqa: PLC0415

    lines: list[str] = []
    ticked = threading.Event()
    now = [100.0]

    def write(line: str) -> None:
        lines.append(line)
        if "items/s" in line:
            ticked.set()

    with LineProgress(write, interval=0.01, clock=lambda: now[0]) as progress:
        progress.on_stage("models", 10)
        for status in ("built", "built", "reused", "failed"):
            progress.on_item("models", "item", status)
        now[0] = 108.0
        assert ticked.wait(timeout=30), "no line while the stage ran"
    assert lines[0] == "models: 10 items"
    assert "models: 4/10 items (2 built, 1 reused, 1 failed), 0.50 items/s, time left 12s, elapsed 8s" in lines
    assert lines[-1] == "models: 4/10 items (2 built, 1 reused, 1 failed), done in 8s"


def test_a_full_disk_is_one_line(tmp_path: Path) -> None:
    """A data dir on a file system with no room left: a 64 KiB tmpfs, filled (needs the right to mount)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(disk)],
                             capture_output=True, check=False)
    if mounted.returncode != 0:
        pytest.skip("cannot mount a small tmpfs here (needs root and the right to mount)")
    try:
        (disk / "data").mkdir()
        with open(disk / "filler", "wb", buffering=0) as filler, pytest.raises(OSError):
            while True:
                filler.write(b"\0" * 4096)
        line = _single_error_line(runner.invoke(app, ["--data-dir", str(disk / "data"), "run", str(GOLDEN)]))
        assert line == (f"error: data dir {disk / 'data'} is not writable (No space left on device); "
                        "free some space there or give --data-dir a folder on a disk with room")
    finally:
        subprocess.run(["umount", str(disk)], check=False)


def test_a_models_folder_that_is_not_there_is_one_line(tmp_path: Path) -> None:
    line = _single_error_line(runner.invoke(app, [
        "--data-dir", str(tmp_path / "data"), "run", str(GOLDEN),
        "--set", 'models.sources=["osgd"]', "--set", f"models.osgd_dir={tmp_path / 'nope'}",
    ]))
    assert line == (f"error: stage models cannot plan its work: {tmp_path / 'nope'}: no such folder; "
                    "set [models] osgd_dir to a folder in the OSGD layout")


def test_the_run_summary_has_each_stages_wall_time_share_and_rate() -> None:
    from osgd.cli import stage_time_rows  # noqa: PLC0415
    from osgd.contract.shards import ShardRecord  # noqa: PLC0415
    from osgd.stage import StageReport  # noqa: PLC0415

    def record(rows: int) -> ShardRecord:
        return ShardRecord("scenes", "0" * 64, "item", rows, "0" * 64)

    reports = [StageReport("scenes", [record(25)] * 4, reused=0, built=4, seconds=30.0),
               StageReport("samples", [record(25)] * 4, reused=3, built=1, seconds=90.0)]
    header, scenes, samples, total = stage_time_rows(reports)
    assert header[0] == "stage" and "wall time" in header and "rate" in header
    assert scenes[:7] == ("scenes", "4", "4", "0", "0", "100", "30s")
    assert scenes[7] == "25 %" and samples[7] == "75 %"
    assert scenes[8] == "0.13 items/s, 3.3 rows/s"
    assert samples[8] == "0.01 items/s"  # with shards reused, rows per second would mix in their rows
    assert total[0] == "total" and total[6] == "2m00s"
