"""Damaged and degenerate users' meshes fail their item of the models stage, naming the file and the cause.

A mesh that repair would strip of more than ``max_repair_loss`` of its faces (faces on non-finite vertices,
zero-area faces) or that is degenerate (one triangle: flat, no volume) is a failed item, listed in the end-of-run
table with its cause, never an empty shard; a clean mesh next to them builds.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import trimesh
from typer.testing import CliRunner

from osgd.cli import app
from osgd.models.procedural import generate
from osgd.models.stage import ModelsStage, item_rng
from osgd.models.validation import DamagedMesh, check_mesh
from osgd.stage import run_stage
from osgd.store import ShardStore

SIDECAR = 'category = "hammer"\nlength = 0.3\n'


def _hammer() -> trimesh.Trimesh:
    return generate("hammer", item_rng(0, "procedural/hammer_00")).mesh


def _with_nan_vertices(mesh: trimesh.Trimesh, faces: int) -> trimesh.Trimesh:
    """The mesh with every vertex of its first ``faces`` faces set to NaN."""
    vertices = np.array(mesh.vertices)
    vertices[mesh.faces[:faces].ravel()] = np.nan
    return trimesh.Trimesh(vertices, mesh.faces, process=False)


def _one_triangle() -> trimesh.Trimesh:
    return trimesh.Trimesh([[0.0, 0.0, 0.0], [300.0, 0.0, 0.0], [0.0, 30.0, 0.0]], [[0, 1, 2]], process=False)


def _write(folder: Path, stem: str, mesh: trimesh.Trimesh) -> Path:
    folder.mkdir(exist_ok=True)
    path = folder / f"{stem}.ply"
    mesh.export(path)
    (folder / f"{stem}.toml").write_text(SIDECAR)
    return path


def _run_models(user_dir: Path, data: Path, **params):
    stage = ModelsStage()
    planned = stage.planned(stage.Params(sources=["user"], user_dir=str(user_dir), decomposition="hull", **params),
                            0, {})
    return run_stage(stage, planned, ShardStore(data))


def test_nan_vertices_over_the_limit_fail_the_item_naming_the_share(tmp_path: Path) -> None:
    mesh = _with_nan_vertices(_hammer(), 185)
    dropped = int((~np.isfinite(mesh.vertices[mesh.faces]).all(axis=(1, 2))).sum())
    share = dropped / len(mesh.faces)
    assert share > 0.05
    path = _write(tmp_path / "user", "nan", mesh)
    report = _run_models(tmp_path / "user", tmp_path / "data")
    assert not report.ok and [failure.item_id for failure in report.failures] == ["user/nan"]
    failure = report.failures[0]
    assert failure.file == str(path)
    assert f"drop {dropped} of its {len(mesh.faces)} faces ({share:.1%}: {dropped} on non-finite vertices" in (
        failure.cause)
    assert "max_repair_loss = 5.0%" in failure.cause
    assert not report.records  # no shard, empty or not
    # A looser limit lets the same mesh through, repaired, with a note.
    looser = _run_models(tmp_path / "user", tmp_path / "data2", max_repair_loss=1.0)
    assert looser.ok and looser.records[0].rows == 1
    assert any("non-finite" in note for note in looser.notes["user/nan"])


def test_a_one_triangle_mesh_fails_its_item(tmp_path: Path) -> None:
    path = _write(tmp_path / "user", "triangle", _one_triangle())
    report = _run_models(tmp_path / "user", tmp_path / "data")
    assert [failure.item_id for failure in report.failures] == ["user/triangle"]
    assert report.failures[0].file == str(path)
    assert report.failures[0].cause.startswith("degenerate mesh: flat, no volume (1 faces")


def test_check_mesh_limits_the_faces_repair_may_drop() -> None:
    clean = _hammer()
    assert check_mesh(clean, max_loss=0.0).mesh.faces.shape == clean.faces.shape
    damaged = _with_nan_vertices(clean, 3)
    lost = int((~np.isfinite(damaged.vertices[damaged.faces]).all(axis=(1, 2))).sum())
    check_mesh(damaged, max_loss=lost / len(clean.faces))  # exactly at the limit: repaired
    with pytest.raises(DamagedMesh, match=r"damaged mesh: repair would drop \d+ of its"):
        check_mesh(damaged, max_loss=(lost - 1) / len(clean.faces))
    check_mesh(damaged)  # no limit given: repaired, as for the authors' and procedural models
    with pytest.raises(DamagedMesh, match="flat"):
        check_mesh(_one_triangle())


def test_the_failure_table_names_damaged_meshes_and_a_clean_mesh_builds(tmp_path: Path) -> None:
    user = tmp_path / "user"
    nan_path = _write(user, "nan", _with_nan_vertices(_hammer(), 185))
    triangle_path = _write(user, "triangle", _one_triangle())
    _write(user, "clean", _hammer())
    config = tmp_path / "damaged.toml"
    config.write_text(f'[pipeline]\nname = "damaged"\nseed = 0\n\n[models]\nsources = ["user"]\nuser_dir = "{user}"\n'
                      'decomposition = "hull"\n\n[grasps]\napproach_count = 2\nsampler_max_pairs = 4\n')
    result = CliRunner().invoke(app, ["--data-dir", str(tmp_path / "data"), "--workers", "1", "annotate", "--config",
                                      str(config)])
    assert result.exit_code == 1, result.output
    assert "Traceback" not in result.output
    table = result.output[result.output.index("2 item(s) failed"):]
    assert re.search(rf"models +user/nan +{re.escape(str(nan_path))} +damaged mesh: repair would drop \d+ of its "
                     r"\d+ faces \(\d+\.\d%: \d+ on non-finite vertices", table)
    assert re.search(rf"models +user/triangle +{re.escape(str(triangle_path))} +degenerate mesh: flat", table)
    assert re.search(r"^models: \d+ shards, 1 rows \(1 built, 0 reused, 2 failed\)", result.output, re.MULTILINE)
