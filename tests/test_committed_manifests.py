"""Every committed manifest is what its pipeline plans today.

``data/manifests/NAME.json`` records the shard keys of ``pipelines/NAME.toml``;
a change to a stage's parameters, version or inputs gives new keys, and the
record must then be rebuilt (``osgd run pipelines/NAME.toml``, then copy the
manifest). Planning needs no shards, so this costs about a second.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from osgd.pipeline import load_pipeline, plan_pipeline

ROOT = Path(__file__).resolve().parents[1]
MANIFESTS = sorted((ROOT / "data" / "manifests").glob("*.json"))


def test_the_committed_manifests_are_those_of_the_shipped_pipelines() -> None:
    names = [path.stem for path in MANIFESTS]
    assert {"golden", "default"} <= set(names)
    assert all((ROOT / "pipelines" / f"{name}.toml").is_file() for name in names), names


@pytest.mark.parametrize("manifest", MANIFESTS, ids=lambda path: path.stem)
def test_a_committed_manifest_records_the_keys_its_pipeline_plans(manifest: Path) -> None:
    recorded = json.loads(manifest.read_text())["stages"]
    planned = plan_pipeline(load_pipeline(ROOT / "pipelines" / f"{manifest.stem}.toml"))
    assert set(planned) == set(recorded)
    for stage, shards in planned.items():
        keys = sorted(shard.key for shard in shards)
        assert keys == sorted(shard["key"] for shard in recorded[stage]["shards"]), (
            f"{manifest.name}: the {stage} keys are not those pipelines/{manifest.stem}.toml plans; rebuild it "
            f"(osgd run pipelines/{manifest.stem}.toml, then copy manifests/{manifest.name})")
