"""The golden pipeline rebuilds to the committed manifest, byte for byte.

The committed ``data/manifests/golden.json`` records the sha256 of every
shard of ``pipelines/golden.toml``; a change that alters any output shows up
here (and in ``git diff`` after ``make golden-update``).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
COMMITTED = ROOT / "data" / "manifests" / "golden.json"


def test_golden_pipeline_reproduces_the_committed_manifest(tmp_path: Path) -> None:
    environment = {**os.environ, "PYTHONHASHSEED": "0"}
    result = subprocess.run(
        [sys.executable, "-m", "osgd", "--data-dir", str(tmp_path), "--workers", "2", "run",
         str(ROOT / "pipelines" / "golden.toml")],
        capture_output=True, text=True, env=environment, check=False,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    built = json.loads((tmp_path / "manifests" / "golden.json").read_text())
    committed = json.loads(COMMITTED.read_text())
    for stage, entry in committed["stages"].items():
        assert stage in built["stages"], f"stage {stage} missing from the rebuilt manifest"
        got = built["stages"][stage]
        assert got["params"] == entry["params"], f"{stage}: parameters differ from the committed run"
        assert got["shards"] == entry["shards"], (
            f"{stage}: shards differ from data/manifests/golden.json; if the change is intended, "
            f"run `make golden-update` and commit the manifest"
        )
    assert built == committed
