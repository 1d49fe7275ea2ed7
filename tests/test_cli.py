"""The osgd command line, invoked as a person would."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

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
    assert {path.stem for path in configs} >= {"default", "golden", "osgd"}
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
