"""Importing osgd and togcrf changes nothing in the process.

What must set process state (``PYTHONHASHSEED`` for the workers, the
logging set-up) does it in the entry points, and pybullet is imported on first
use (:func:`osgd.physics.pybullet_module`): importing a module leaves the
environment, ``sys.modules``, trimesh's logger and file descriptors 1 and 2
as they were. The import checks run in a fresh interpreter, since this one
has imported everything already.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from typing import Any

import pytest

#: Modules whose import must have no effect, the entry points' among them.
MODULES = (
    "osgd",
    "osgd.physics",
    "osgd.cli",
    "osgd.pipeline",
    "osgd.executor",
    "osgd.models.osgd_import",
    "osgd.checks.trial",
    "osgd.scenes.drop",
    "osgd.scenes.statistics",
    "osgd.samples.collision",
    "osgd.samples.renderer",
    "togcrf.cli",
    "togcrf.robot.execute",
)

#: Imports MODULES, reads an OBJ file with osgd's reader, and prints what the
#: process looked like before and after as JSON. ``os.dup2`` is wrapped to
#: record every descriptor something points elsewhere, even for a while.
#: Two libraries are imported first because their own imports set environment
#: variables, which is no doing of osgd's or togcrf's: OpenCV adds its
#: libraries to ``LD_LIBRARY_PATH``; torch's dynamo (which ``torchvision.ops``
#: loads) sets ``TORCHINDUCTOR_CACHE_DIR``.
SCRIPT = r"""
import importlib, json, logging, os, sys, tempfile

import cv2
import torchvision.ops

redirected = []
_dup2 = os.dup2


def dup2(fd, fd2, inheritable=True):
    redirected.append(fd2)
    return _dup2(fd, fd2, inheritable)


os.dup2 = dup2


def state():
    return {
        "environ": dict(os.environ),
        "descriptors": [list(os.fstat(fd)[1:3]) for fd in (1, 2)],  # (inode, device)
        "trimesh_level": logging.getLogger("trimesh").level,
        "root_handlers": len(logging.getLogger().handlers),
    }


before = state()
for name in sys.argv[1:]:
    importlib.import_module(name)
imported = state()
imported["pybullet"] = "pybullet" in sys.modules
imported["redirected"] = list(redirected)
from osgd.models.osgd_import import read_obj
with tempfile.NamedTemporaryFile("w", suffix=".obj", delete=False) as obj:
    obj.write("mtllib missing.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
read_obj(obj.name)
os.unlink(obj.name)
print(json.dumps({"before": before, "imported": imported, "read": state()}))
"""


def _run_script(modules: tuple[str, ...] = MODULES) -> dict[str, Any]:
    """The script's report, run in a fresh interpreter with the test's environment."""
    result = subprocess.run([sys.executable, "-c", SCRIPT, *modules], capture_output=True, text=True,
                            check=False, timeout=600)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def report() -> dict[str, Any]:
    return _run_script()


def test_imports_leave_the_environment_alone(report: dict[str, Any]) -> None:
    assert report["imported"]["environ"] == report["before"]["environ"]


def test_imports_load_no_pybullet(report: dict[str, Any]) -> None:
    assert report["imported"]["pybullet"] is False


def test_imports_leave_stdout_and_stderr_where_they_point(report: dict[str, Any]) -> None:
    assert not {1, 2} & set(report["imported"]["redirected"]), "file descriptor 1 or 2 was redirected on import"
    assert report["imported"]["descriptors"] == report["before"]["descriptors"]


def test_imports_and_reading_a_mesh_leave_the_loggers_alone(report: dict[str, Any]) -> None:
    for after in (report["imported"], report["read"]):
        assert after["trimesh_level"] == report["before"]["trimesh_level"]
        assert after["root_handlers"] == report["before"]["root_handlers"]


def test_pybullet_module_imports_pybullet_on_first_use_without_its_banner() -> None:
    script = ("import sys, osgd.physics\n"
              "assert 'pybullet' not in sys.modules\n"
              "module = osgd.physics.pybullet_module()\n"
              "assert module is sys.modules['pybullet'] is osgd.physics.pybullet_module()\n")
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=False, timeout=600)
    assert result.returncode == 0, result.stderr
    assert "pybullet build time" not in result.stdout + result.stderr


def test_the_process_client_registers_one_exit_handler(monkeypatch: pytest.MonkeyPatch) -> None:
    from osgd import physics  # noqa: PLC0415

    registered = []
    monkeypatch.setattr(physics.atexit, "register", registered.append)
    monkeypatch.setattr(physics._ProcessClient, "client", None)
    monkeypatch.setattr(physics._ProcessClient, "exit_handler_registered", False)
    first = physics.process_client()
    assert physics.process_client() == first
    physics.pybullet_module().disconnect(first)  # lost: the next call connects again
    second = physics.process_client()
    physics.pybullet_module().disconnect(second)
    assert registered == [physics._disconnect]


def test_the_hash_seed_is_set_for_the_workers_and_a_serial_build_is_warned(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    from osgd import cli  # noqa: PLC0415
    from osgd.executor import ProcessPoolExecutor, SerialExecutor  # noqa: PLC0415

    monkeypatch.setenv("PYTHONHASHSEED", "unset below")  # so that monkeypatch removes what the CLI sets
    monkeypatch.delenv("PYTHONHASHSEED")
    monkeypatch.setattr(cli._Global, "hash_seed_differs", False)
    cli._seed_worker_hashes()
    assert os.environ["PYTHONHASHSEED"] == "0"
    with caplog.at_level("WARNING", logger="osgd.cli"):
        cli._warn_if_built_with_other_hashes(ProcessPoolExecutor(2))
        assert not caplog.records
        cli._warn_if_built_with_other_hashes(SerialExecutor())
    assert "PYTHONHASHSEED" in caplog.text

    monkeypatch.setenv("PYTHONHASHSEED", "0")  # chosen before the process started: nothing to say
    cli._seed_worker_hashes()
    assert not cli._Global.hash_seed_differs
