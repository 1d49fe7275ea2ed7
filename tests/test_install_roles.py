"""Installs by role: the generator runs without torch, training runs without the generator's
native libraries.

Each test runs a fresh interpreter whose import system refuses some modules: a ``sitecustomize`` on
``PYTHONPATH`` puts a ``sys.meta_path`` finder first, before anything is imported, in that process and in
every worker process it spawns (they inherit the environment). What it was asked for and refused is
written to a file, which the tests read.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import write_synthetic_samples

from osgd.store import ShardStore

ROOT = Path(__file__).resolve().parents[1]

_REFUSER = '''
import os, sys

REFUSED = tuple(os.environ["OSGD_TEST_REFUSE"].split(","))
LOG = os.environ["OSGD_TEST_REFUSE_LOG"]


class _Refuse:
    """Refuses the modules named in OSGD_TEST_REFUSE and their submodules, as if they were not installed."""

    def find_spec(self, name, path=None, target=None):
        if any(name == refused or name.startswith(refused + ".") for refused in REFUSED):
            with open(LOG, "a") as log:
                log.write(name + "\\n")
            raise ImportError(f"{name} is refused by tests/test_install_roles.py (not installed in this role)")
        return None


sys.meta_path.insert(0, _Refuse())
'''


def _refusing_env(tmp_path: Path, refused: tuple[str, ...]) -> tuple[dict[str, str], Path]:
    site = tmp_path / "refuse"
    site.mkdir()
    (site / "sitecustomize.py").write_text(_REFUSER)
    log = tmp_path / "refused.log"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(ROOT)]),
           "OSGD_TEST_REFUSE": ",".join(refused), "OSGD_TEST_REFUSE_LOG": str(log), "OSGD_PROGRESS_INTERVAL": "600"}
    return env, log


def _run(command: list[str], env: dict[str, str], timeout: float) -> subprocess.CompletedProcess:
    return subprocess.run(command, env=env, cwd=ROOT, capture_output=True, text=True, timeout=timeout, check=False)


def test_the_refuser_refuses(tmp_path: Path) -> None:
    env, log = _refusing_env(tmp_path, ("torch",))
    result = _run([sys.executable, "-c", "import torch"], env, 60)
    assert result.returncode == 1 and "refused by tests/test_install_roles.py" in result.stderr
    assert log.read_text().split() == ["torch"]


#: The training role has neither the generator's physics, decomposition and ray-casting libraries.
GENERATOR_ONLY = ("pybullet", "coacd", "embreex", "trimesh.ray")


@pytest.mark.slow
def test_the_generator_builds_the_golden_pipeline_without_torch(tmp_path: Path) -> None:
    env, log = _refusing_env(tmp_path, ("torch", "torchvision"))
    data = tmp_path / "data"
    result = _run([sys.executable, "-m", "osgd", "--data-dir", str(data), "--workers", "2", "run",
                   "pipelines/golden.toml"], env, 900)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    manifest = json.loads((data / "manifests" / "golden.json").read_text())
    assert all(entry["complete"] for entry in manifest["stages"].values())
    assert set(manifest["stages"]) == {"models", "grasps", "checks", "scenes", "samples"}
    # Nothing asked for torch, in the main process or in a worker.
    assert not log.exists(), log.read_text()


_TRAIN = '''
import json, sys
from togcrf.train import TrainConfig, train

train(TrainConfig(**json.loads(sys.argv[1])))
loaded = sorted(name for name in sys.modules if name.split(".")[0] in ("pybullet", "coacd", "embreex", "trimesh"))
print(json.dumps(loaded))
'''


def test_training_runs_without_the_generators_native_libraries(tmp_path: Path) -> None:
    data = tmp_path / "data"
    write_synthetic_samples(ShardStore(data), 8, seed=3)
    # A few steps of a small run (the basic options of tests/test_togcrf_train.py::quick_config).
    config = {"data": str(data), "out": str(tmp_path / "run"), "pipeline": "synthetic", "model": "tog-crfs",
              "backbone": "resnet18", "epochs": 1, "batch_size": 2, "max_samples": 4, "image_size": 64,
              "warmup_steps": 1, "device": "cpu"}
    env, log = _refusing_env(tmp_path, GENERATOR_ONLY)
    result = _run([sys.executable, "-c", _TRAIN, json.dumps(config, default=str)], env, 900)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    # trimesh itself imports trimesh.ray, so no trimesh module may be loaded either.
    assert json.loads(result.stdout.strip().splitlines()[-1]) == []
    assert (tmp_path / "run" / "checkpoint.pt").is_file()
    assert not log.exists(), f"the training path asked for {log.read_text().split()}"


def test_togcrf_help_works_without_the_generators_native_libraries(tmp_path: Path) -> None:
    env, log = _refusing_env(tmp_path, GENERATOR_ONLY)
    result = _run([sys.executable, "-c", "from togcrf.cli import run; run()", "--help"], env, 300)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "train" in result.stdout
    assert not log.exists(), f"togcrf --help asked for {log.read_text().split()}"


@pytest.mark.parametrize("role, refused", [("core", ("torch", "torchvision")), ("train", GENERATOR_ONLY)])
def test_each_role_names_only_its_own_libraries(role: str, refused: tuple[str, ...]) -> None:
    import tomllib  # noqa: PLC0415

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    names = {requirement.split(">")[0].split("<")[0].split("[")[0].strip()
             for requirement in [*project["dependencies"], *extras[role]]}
    distributions = {"torch": "torch", "torchvision": "torchvision", "pybullet": "pybullet", "coacd": "coacd",
                     "embreex": "embreex", "trimesh.ray": "trimesh"}
    assert not names & {distributions[module] for module in refused}
    assert {"osgd[core,train]"} <= set(extras["robot"]) and "osgd[core,train]" in extras["dev"]
