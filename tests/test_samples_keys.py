"""Every input of a samples shard is in its key."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import pytest

import osgd.samples.stage as samples_stage
from osgd.samples.stage import SamplesStage, SamplesStageParams
from osgd.stage import PlannedShard, WorkItem

UPSTREAM = {
    "scenes": [PlannedShard(WorkItem("scenes_000", {}), "a" * 64)],
    "models": [PlannedShard(WorkItem("procedural/knife_00", {}), "b" * 64)],
    "grasps": [PlannedShard(WorkItem("procedural/knife_00", {}), "c" * 64)],
    "checks": [PlannedShard(WorkItem("procedural/knife_00", {}), "d" * 64)],
}


def _key(renderer: str = "embree") -> str:
    (shard,) = SamplesStage().planned(SamplesStageParams(renderer=renderer), 0, UPSTREAM)
    return shard.key


def _auto_picks(monkeypatch: pytest.MonkeyPatch, backend: str) -> None:
    def make_renderer(name: str) -> SimpleNamespace:
        return SimpleNamespace(name=backend if name == "auto" else name)

    monkeypatch.setattr(samples_stage, "make_renderer", make_renderer)


def test_auto_is_resolved_before_planning(monkeypatch: pytest.MonkeyPatch) -> None:
    """Two runs whose auto picks another renderer never share keys; auto keys as what it picked."""
    _auto_picks(monkeypatch, "egl")
    egl = _key("auto")
    (shard,) = SamplesStage().planned(SamplesStageParams(renderer="auto"), 0, UPSTREAM)
    assert shard.item.payload["params"]["renderer"] == "egl"
    _auto_picks(monkeypatch, "embree")
    embree = _key("auto")
    assert egl != embree
    assert embree == _key("embree")
    assert egl == _key("egl")


def test_the_camera_depth_range_is_in_the_key(monkeypatch: pytest.MonkeyPatch) -> None:
    before = _key()
    camera = samples_stage.KINECT_V2
    monkeypatch.setattr(samples_stage, "KINECT_V2", dataclasses.replace(camera, near=camera.near - 0.1))
    near = _key()
    monkeypatch.setattr(samples_stage, "KINECT_V2", dataclasses.replace(camera, far=camera.far + 0.5))
    far = _key()
    assert len({before, near, far}) == 3


def test_the_gripper_is_in_the_key(monkeypatch: pytest.MonkeyPatch) -> None:
    before = _key()
    gripper = samples_stage.PANDA
    monkeypatch.setattr(samples_stage, "PANDA", dataclasses.replace(gripper, finger_width=gripper.finger_width + 0.001))
    assert _key() != before


def test_the_build_reads_the_depth_range_and_gripper_from_the_payload() -> None:
    (shard,) = SamplesStage().planned(SamplesStageParams(renderer="embree"), 0, UPSTREAM)
    payload = shard.item.payload
    assert payload["depth_range"] == [samples_stage.KINECT_V2.near, samples_stage.KINECT_V2.far]
    assert payload["gripper"] == dataclasses.asdict(samples_stage.PANDA)
    assert SamplesStageParams(**payload["params"]).intrinsics(0.3, 2.0).near == 0.3
