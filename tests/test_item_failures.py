"""Items fail alone, with one line a person can act on.

A models folder in the original OSGD layout and a folder of users' meshes,
each with a good model and a broken one, go through every stage with the
command line: the good models are built through to the samples, the broken
files are named in one table at the end, the exit code is 1, and a rerun
after fixing the files builds only the fixed items and what depends on them.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import trimesh
from typer.testing import CliRunner

from osgd.cli import app
from osgd.config import load_config
from osgd.models.osgd_import import MESH_PATH, load_osgd_model
from osgd.pipeline import pipeline_status, stage_params_classes
from osgd.store import ShardStore

runner = CliRunner()

#: Two boxes in ShapeNet-like units, Y up: a handle along x and a head across it at +x.
_BOXES = (((-0.5, -0.04, -0.04), (0.35, 0.04, 0.04)), ((0.3, -0.2, -0.06), (0.5, 0.2, 0.06)))


def _box_obj(low: tuple[float, ...], high: tuple[float, ...], first: int) -> list[str]:
    box = trimesh.creation.box(bounds=[low, high])
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in box.vertices]
    lines += [f"f {a + first} {b + first} {c + first}" for a, b, c in box.faces]
    return lines


def hammer_obj(names: tuple[str, str]) -> str:
    """An OBJ of two named objects, as Blender 2.79 wrote the authors' models."""
    lines = ["# Blender v2.79 OBJ File", "mtllib model_normalized.mtl"]
    first = 1
    for name, (low, high) in zip(names, _BOXES, strict=True):
        lines += [f"o {name}", *_box_obj(low, high, first)]
        first += 8
    return "\n".join(lines) + "\n"


def write_osgd_model(models_dir: Path, folder: str, obj_text: str) -> Path:
    """``<folder>/model/model_normalized.obj`` and two annotation files (Blender's Z-up frame)."""
    model = models_dir / folder
    (model / "model").mkdir(parents=True)
    (model / MESH_PATH).write_text(obj_text)
    (model / "annotations").mkdir()
    # Pairs across the handle: OBJ (x, +-0.04, 0) is Blender (x, 0, +-0.04).
    pairs = np.array([[x, 0.0, sign * 0.05] for x in (-0.4, -0.2, 0.0) for sign in (-1.0, 1.0)])
    np.save(model / "annotations" / "hand_over.npy", pairs)
    np.save(model / "annotations" / "hammer.npy", pairs + np.array([0.05, 0.0, 0.0]))
    return model / MESH_PATH


#: Object names that end in a backslash (IFC-style escapes), as in one of the authors' models.
BACKSLASH_NAMES = ("\\X2\\9524628A\\X0\\", "\\X2\\5934\\X0\\")


def test_obj_object_names_ending_in_a_backslash_are_read_as_names(tmp_path: Path) -> None:
    mesh_path = write_osgd_model(tmp_path, "hammer_002", hammer_obj(BACKSLASH_NAMES))
    assert "o \\X2\\9524628A\\X0\\\nv " in mesh_path.read_text()
    model = load_osgd_model(tmp_path / "hammer_002")
    # Every vertex and face of both objects; trimesh alone glued the next vertex line onto the name.
    assert model.mesh.vertices.shape == (16, 3) and model.mesh.faces.shape == (24, 3)
    assert model.mesh.faces.max() == 15
    np.testing.assert_allclose(model.mesh.bounds, [[-0.5, -0.2, -0.06], [0.5, 0.2, 0.06]])
    assert {pair.task for pair in model.pairs} == {"hand over", "hammer"} and len(model.pairs) == 6


def _mallet_stl(path: Path) -> None:
    handle = trimesh.creation.box(bounds=[[-100, -12, -8], [100, 12, 8]])
    head = trimesh.creation.box(bounds=[[85, -50, -15], [115, 50, 15]])
    trimesh.util.concatenate([handle, head]).export(path)


PIPELINE = """
[pipeline]
name = "mixed"
seed = 0

[models]
sources = ["osgd", "user"]
osgd_dir = "osgd"
user_dir = "user"
decomposition = "hull"

[grasps]
approach_count = 4
sampler_max_pairs = 8

[scenes]
count = 2
scenes_per_shard = 1
min_objects = 2
max_objects = 3

[samples]
renderer = "embree"
crop_size = 96
"""

GOOD_OBJ = hammer_obj(("handle", "head"))
#: The last face names vertex 99 of 16: trimesh raises IndexError reading it.
BROKEN_OBJ = GOOD_OBJ + "f 1 2 99\n"


def _setup(root: Path) -> Path:
    """The OSGD folder (good, backslash names, broken) and the users' folder (good, misspelt category)."""
    osgd_dir, user_dir = root / "osgd", root / "user"
    write_osgd_model(osgd_dir, "hammer_001", GOOD_OBJ)
    write_osgd_model(osgd_dir, "hammer_002", hammer_obj(BACKSLASH_NAMES))
    write_osgd_model(osgd_dir, "knife_003", BROKEN_OBJ)
    user_dir.mkdir()
    _mallet_stl(user_dir / "mallet.stl")
    (user_dir / "mallet.toml").write_text('category = "hammer"\nlength = 0.3\ndefault_part = "handle"\n')
    _mallet_stl(user_dir / "drill.stl")
    (user_dir / "drill.toml").write_text('category = "screwdrivr"\nlength = 0.25\n')
    config = root / "mixed.toml"
    config.write_text(PIPELINE)
    return config


def _counts(output: str) -> dict[str, tuple[int, int, int]]:
    """(built, reused, failed) per stage from the summary lines."""
    pattern = re.compile(r"^(\w+): \d+ shards, \d+ rows \((\d+) built, (\d+) reused, (\d+) failed\)", re.MULTILINE)
    return {match[0]: tuple(map(int, match[1:])) for match in pattern.findall(output)}


def test_broken_models_fail_alone_and_a_rerun_builds_only_the_fixed_ones(tmp_path: Path) -> None:
    config = _setup(tmp_path)
    data = tmp_path / "data"
    arguments = ["--data-dir", str(data), "--workers", "1", "run", str(config)]
    first = runner.invoke(app, arguments)
    assert first.exit_code == 1, first.output
    assert "Traceback" not in first.output
    # The failed items, one table at the end: item, file, cause.
    table = first.output[first.output.index("2 item(s) failed"):]
    broken_obj = f"{tmp_path}/osgd/knife_003/model/model_normalized.obj"
    assert re.search(rf"models +osgd/knife_003 +{re.escape(broken_obj)} +trimesh cannot read it \(IndexError", table)
    assert re.search(rf"models +user/drill +{re.escape(str(tmp_path / 'user' / 'drill.toml'))} +category = "
                     r"'screwdrivr': unknown category 'screwdrivr'; expected one of \[", table)
    # Every stage ran for the good models.
    assert _counts(first.output) == {"models": (3, 0, 2), "grasps": (3, 0, 0), "checks": (3, 0, 0),
                                     "scenes": (2, 0, 0), "samples": (2, 0, 0)}
    manifest = json.loads((data / "manifests" / "mixed.json").read_text())["stages"]
    assert manifest["models"]["failed"] == ["osgd/knife_003", "user/drill"]
    good = {"osgd/hammer_001", "osgd/hammer_002", "user/mallet"}
    for stage in ("models", "grasps", "checks"):
        assert {shard["item"] for shard in manifest[stage]["shards"]} == good
    assert all(shard["rows"] > 0 for stage in ("grasps", "scenes", "samples") for shard in manifest[stage]["shards"])
    store = ShardStore(data)
    names = store.read_many("models", [shard["key"] for shard in manifest["models"]["shards"]])
    by_name = {row["name"]: row for row in names.to_pylist()}
    assert len(by_name["hammer_002"]["vertices"]) == 16  # the backslash names cost no vertex
    # Progress lines, written although the output is not a terminal.
    assert "models: 5 items" in first.output
    assert re.search(r"^models: 5/5 items \(3 built, 2 failed\), done in \d+s$", first.output, re.MULTILINE)
    # status follows the run: the failed items are counted as such, the rest is done.
    pipeline = load_config(config, stage_params_classes())
    status = {row.stage: row for row in pipeline_status(pipeline, store)}
    assert (status["models"].done, status["models"].failed, status["models"].missing) == (3, 2, 0)
    assert (status["samples"].done, status["samples"].missing) == (2, 0)

    # Unchanged files fail again, the same way; --debug adds their tracebacks.
    debug = runner.invoke(app, ["--debug", *arguments])
    assert debug.exit_code == 1 and "2 item(s) failed" in debug.output
    assert "Traceback" in debug.output and "IndexError" in debug.output
    assert _counts(debug.output)["samples"] == (0, 2, 0)

    # What a killed run leaves behind (a temporary file, a lock file) goes with the next run.
    leftovers = [data / "models" / f".{'a' * 64}.parquet.x1y2z3.tmp", data / "models" / ".locks" / f"{'a' * 64}.lock"]
    for path in leftovers:
        path.write_bytes(b"")
    # Fix both files: only they, and what depends on them, are built.
    (tmp_path / "osgd" / "knife_003" / MESH_PATH).write_text(GOOD_OBJ)
    (tmp_path / "user" / "drill.toml").write_text('category = "screwdriver"\nlength = 0.25\n')
    second = runner.invoke(app, arguments)
    assert second.exit_code == 0, second.output
    assert _counts(second.output) == {"models": (2, 3, 0), "grasps": (2, 3, 0), "checks": (2, 3, 0),
                                      "scenes": (2, 0, 0), "samples": (2, 0, 0)}
    assert "failed" not in json.loads((data / "manifests" / "mixed.json").read_text())["stages"]["models"]
    assert not any(path.exists() for path in leftovers)
    assert not list(data.glob("*/.locks/*.lock")) and not list(data.rglob("*.tmp"))
