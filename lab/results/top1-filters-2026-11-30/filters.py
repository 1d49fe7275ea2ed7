"""Which of the ground truth's filters removes the grasps where a checkpoint's top-1 lands (a diagnostic, issue #15).

Usage::

    python lab/results/top1-filters-2026-11-30/filters.py CHECKPOINT OUT.json [--samples N] [--pipeline NAME]

For each detection that claims an object with ground-truth grasps on the first N (206) test samples of the
``recipe`` pipeline, or the one ``--pipeline`` names (the rule of ``benchmarks/grasp_ranking.py``,
``claimed_objects``), its top-1 grasp is matched (the mAP-G rule, ``togcrf.metrics.grasp_match_matrix``) against
the object's annotated grasps projected into the sample's camera, filter by filter, as the samples stage applies
them (``osgd.samples.stage._object_grasps``, with the pipeline's parameters from its manifest): every annotated
grasp (grasps stage); the stable ones (checks stage); those whose closing line is at least 45 degrees from the
optical axis and whose centre is in the image; those whose contacts are visible; those whose hand touches no other
object (the valid grasps, before the suppression).
Each top-1 is counted at the last filter it still matches a grasp after: ``valid``, ``hand collides``,
``contacts hidden``, ``closing line near the optical axis or centre outside``, ``unstable in the check``, or
``no annotated grasp``. The camera view is rebuilt from the sample (its clean depth, mask, intrinsics and pose),
the pile from its scene; nothing is rendered.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from collections import Counter
from itertools import islice
from pathlib import Path

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from osgd.camera import KINECT_V2, CameraIntrinsics
from osgd.contract.samples import Sample, iter_samples, sample_shards
from osgd.contract.taxonomy import CATEGORIES
from osgd.gripper import PANDA
from osgd.models.rows import BODY_COLUMNS, model_rows
from osgd.samples.collision import pile_collider
from osgd.samples.projection import (
    GraspSet,
    angle_to_optical_axis,
    centres_in_image,
    contacts_visible,
    grasp_rectangles,
    grasp_set_from_rows,
)
from osgd.samples.stage import SamplesStageParams
from osgd.samples.viewpoint import CameraPose
from osgd.store import ShardStore
from togcrf.checkpoint import load_checkpoint
from togcrf.metrics import grasp_match_matrix

ROOT = Path(__file__).resolve().parents[3]
LEVELS = ("no annotated grasp", "unstable in the check", "closing line near the optical axis or centre outside",
          "contacts hidden", "hand collides", "valid")


class Pipeline:
    """A pipeline's models, annotated grasps with their check, scenes and samples parameters, read once."""

    def __init__(self, data: Path, name: str) -> None:
        store = ShardStore(data)
        manifest = store.read_manifest(name)
        if manifest is None:
            raise SystemExit(f"{store.manifest_path(name)}: no manifest; build the pipeline first")
        manifest = manifest["stages"]

        def keys(stage: str) -> list[str]:
            return [shard["key"] for shard in manifest[stage]["shards"]]

        self.models = model_rows(store.read_many("models", keys("models"), columns=list(BODY_COLUMNS)))
        checks = store.read_many("checks", keys("checks"), columns=["model_id", "grasp_id", "stable"]).to_pylist()
        stable = {(row["model_id"], row["grasp_id"]) for row in checks if row["stable"]}
        rows: dict[str, list[dict]] = {}
        for row in store.read_many("grasps", keys("grasps")).to_pylist():
            rows.setdefault(row["model_id"], []).append(row)
        self.grasps = {model: grasp_set_from_rows(found) for model, found in rows.items()}
        self.stable = {model: np.array([(model, row["grasp_id"]) in stable for row in found], bool)
                       for model, found in rows.items()}
        self.scenes = {row["scene_id"]: row for row in store.read_many("scenes", keys("scenes")).to_pylist()}
        known = set(SamplesStageParams.model_fields)
        self.params = SamplesStageParams(**{key: value for key, value in manifest["samples"]["params"].items()
                                            if key in known})


def object_levels(pipeline: Pipeline, sample: Sample, scene_index: int, collider) -> tuple[np.ndarray, np.ndarray]:
    """One object's annotated grasps as image rectangles (G, 5) and the number of filters each passes (G,)."""
    params = pipeline.params
    obj = pipeline.scenes[sample.scene_id]["objects"][scene_index]
    grasps: GraspSet = pipeline.grasps.get(obj["model_id"])
    if grasps is None or not len(grasps):
        return np.zeros((0, 5)), np.zeros(0, int)
    fx, fy, cx, cy = sample.intrinsics
    height, width = sample.depth.shape
    intrinsics = CameraIntrinsics(width, height, fx, fy, cx, cy, KINECT_V2.near, KINECT_V2.far)
    pose = CameraPose.from_quaternion(sample.camera_position, sample.camera_quaternion)
    rotation = Rotation.from_quat(np.asarray(obj["quaternion"], np.float64)).as_matrix()
    world = grasps.transformed(rotation, np.asarray(obj["position"], np.float64))
    camera = world.transformed(pose.rotation.T, -pose.rotation.T @ pose.position)
    passed = np.zeros(len(grasps), int)
    stable = pipeline.stable[obj["model_id"]]
    facing = (angle_to_optical_axis(camera.closing) >= params.min_angle_to_optical_axis - 1e-9) & centres_in_image(
        camera, intrinsics)
    visible = contacts_visible(camera, sample.depth_clean, sample.mask, scene_index + 1, intrinsics,
                               params.contact_tolerance)
    passed += stable
    passed += stable & facing
    passed += stable & facing & visible
    candidates = np.nonzero(stable & facing & visible)[0]
    if len(candidates):
        quaternions = world.subset(candidates).quaternions
        near = collider.near_objects(world.positions[candidates], world.rotations[candidates],
                                     world.widths[candidates])
        for position, grasp in enumerate(candidates):
            passed[grasp] += not collider.collides(scene_index, world.positions[grasp], world.rotations[grasp],
                                                   float(world.widths[grasp]), quaternions[position], near[position])
    return grasp_rectangles(camera, intrinsics, PANDA.finger_width), passed


def tally_sample(model, config, pipeline: Pipeline, sample: Sample, counts: dict[str, Counter],
                 misses: list[dict]) -> None:
    """Add the level of each claimed object's top-1 grasp to ``counts`` (per category and ``all``), and each
    top-1 that matches no valid grasp to ``misses`` (what :func:`draw_misses` draws)."""
    from grasp_ranking import claimed_objects, detect, top1_grasp  # noqa: PLC0415 (benchmarks/, on the path by main)

    detections, truth = detect(model, config, sample)
    claimed = claimed_objects(detections, truth)
    if not claimed:
        return
    objects = pipeline.scenes[sample.scene_id]["objects"]
    with pile_collider(pipeline.models, objects, PANDA, pipeline.params.collision_tolerance) as collider:
        for detection, target in claimed:
            scene_index = int(sample.object_indices[target])
            rectangles, passed = object_levels(pipeline, sample, scene_index, collider)
            top = top1_grasp(detections, detection)[None]
            matches = grasp_match_matrix(top, rectangles)[0] if len(rectangles) else np.zeros(0, bool)
            level = 1 + int(passed[matches].max()) if matches.any() else 0
            for name in ("all", CATEGORIES[int(truth.categories[target])]):
                counts[name][LEVELS[level]] += 1
                counts[name]["valid grasps"] += int(np.sum(passed == len(LEVELS) - 2))
                if not level:
                    counts[name].update(unannotated_kind(sample, scene_index, top[0], rectangles, passed))
            if level < len(LEVELS) - 1:
                misses.append({"sample": sample.sample_id, "depth": sample.depth, "box": truth.boxes[target],
                               "category": CATEGORIES[int(truth.categories[target])], "level": LEVELS[level],
                               "top": top[0], "rectangles": rectangles, "passed": passed})


#: How :func:`draw_misses` colours an object's annotated grasps, by the number of filters they pass.
PASSED_COLOURS = {2: ("tab:blue", "stable, closing line near the optical axis"), 4: ("tab:orange", "hand collides"),
                  5: ("tab:green", "valid")}


def draw_misses(misses: list[dict], path: Path, count: int = 12) -> None:
    """A grid of claimed objects whose top-1 (red) lies on no valid grasp: the noisy depth around the object's
    box, its annotated grasps coloured by :data:`PASSED_COLOURS`; the first misses of each level in turn."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib.lines import Line2D  # noqa: PLC0415

    from osgd.samples.projection import rectangle_corners  # noqa: PLC0415

    by_level = [[miss for miss in misses if miss["level"] == level] for level in LEVELS[:-1]]
    chosen = [miss for turn in itertools.zip_longest(*by_level) for miss in turn if miss is not None][:count]
    columns = 4
    figure, grid = plt.subplots(-(-len(chosen) // columns), columns, figsize=(3.2 * columns, 3.4 * -(-len(chosen)
                                                                                                   // columns)))
    for axes, miss in zip(np.ravel(grid), chosen, strict=False):
        x1, y1, x2, y2 = miss["box"]
        centre, half = np.array([x1 + x2, y1 + y2]) / 2, max(x2 - x1, y2 - y1, 48) * 0.7
        depth = np.where(miss["depth"] > 0, miss["depth"], np.nan)
        axes.imshow(depth, cmap="gray_r")
        for rectangle, passed in zip(miss["rectangles"], miss["passed"], strict=True):
            if int(passed) + 1 in PASSED_COLOURS:
                corners = rectangle_corners(rectangle)[0]
                axes.plot(*np.vstack([corners, corners[:1]]).T, color=PASSED_COLOURS[int(passed) + 1][0], lw=0.8)
        corners = rectangle_corners(miss["top"])[0]
        axes.plot(*np.vstack([corners, corners[:1]]).T, color="red", lw=2.0)
        axes.set_xlim(centre[0] - half, centre[0] + half)
        axes.set_ylim(centre[1] + half, centre[1] - half)
        axes.set_title(f"{miss['sample']}: {miss['category']}\ntop-1: {miss['level']}", fontsize=7)
        axes.set_axis_off()
    for axes in np.ravel(grid)[len(chosen):]:
        axes.set_axis_off()
    handles = [Line2D([], [], color="red", lw=2.0, label="top-1 grasp")] + [
        Line2D([], [], color=colour, lw=1.0, label=f"annotated: {label}") for colour, label in PASSED_COLOURS.values()]
    figure.legend(handles=handles, loc="lower center", ncol=4, fontsize=8, frameon=False)
    figure.tight_layout(rect=(0, 0.04, 1, 1))
    figure.savefig(path, dpi=110)
    plt.close(figure)


def unannotated_kind(sample: Sample, scene_index: int, top: np.ndarray, rectangles: np.ndarray,
                     passed: np.ndarray) -> list[str]:
    """Where a top-1 that matches no annotated grasp lies: whose pixels hold its centre, and whether an annotated
    grasp of the object is centred within half the top-1's opening (then only the angle or size misses; for those
    within 30 degrees, also the last filter the best of them passes)."""
    row, column = round(float(top[1])), round(float(top[0]))
    height, width = sample.mask.shape
    owner = int(sample.mask[row, column]) if 0 <= row < height and 0 <= column < width else 0
    on = "own object" if owner == scene_index + 1 else "another object" if owner else "table"
    distance = np.hypot(*(rectangles[:, :2] - top[:2]).T) if len(rectangles) else np.array([np.inf])
    near = distance <= top[2] / 2
    if not near.any():
        return [f"centre on {on}", "no annotated grasp near"]
    turn = np.abs((rectangles[near, 4] - top[4] + np.pi / 2) % np.pi - np.pi / 2)
    aligned = turn < np.deg2rad(30.0)
    if not aligned.any():
        return [f"centre on {on}", "an annotated grasp near, none within 30 degrees"]
    ratio = top[2] / rectangles[near][aligned, 2]
    size = "wider" if np.all(ratio > 1.0) else "narrower" if np.all(ratio < 1.0) else "as wide"
    best = LEVELS[1 + int(passed[near][aligned].max())]
    return [f"centre on {on}", f"an annotated grasp near and within 30 degrees, the top-1 opening {size}",
            f"an annotated grasp near and within 30 degrees, the best of them: {best}"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("json", type=Path)
    parser.add_argument("--samples", type=int, default=206)
    parser.add_argument("--data", type=Path, default=Path("data"))
    parser.add_argument("--pipeline", default="recipe", help="the pipeline whose test samples and grasps are read")
    parser.add_argument("--picture", type=Path, help="also draw a grid of misses (draw_misses) into this PNG")
    arguments = parser.parse_args()
    sys.path.insert(0, str(ROOT / "benchmarks"))
    torch.set_num_threads(1)
    model, config = load_checkpoint(arguments.checkpoint, device="cpu")
    model.eval()
    pipeline = Pipeline(arguments.data, arguments.pipeline)
    counts: dict[str, Counter] = {}
    misses: list[dict] = []
    shards = sample_shards(arguments.data, arguments.pipeline)
    for sample in islice(iter_samples(arguments.data, split="test", shards=shards), arguments.samples):
        for name in ("all", *CATEGORIES):
            counts.setdefault(name, Counter())
        tally_sample(model, config, pipeline, sample, counts, misses)
    report = {"checkpoint": str(arguments.checkpoint), "pipeline": arguments.pipeline, "samples": arguments.samples,
              "levels": list(LEVELS)}
    for name, count in counts.items():
        claimed = sum(count[level] for level in LEVELS)
        if claimed:
            report[name] = {"claimed objects": claimed,
                            "valid grasps per claimed object": round(count["valid grasps"] / claimed, 2),
                            **{f"{level} %": round(100.0 * count[level] / claimed, 1) for level in LEVELS},
                            "of 'no annotated grasp'": {key: round(100.0 * value / claimed, 1) for key, value in
                                                        sorted(count.items()) if key not in LEVELS
                                                        and key != "valid grasps"}}
    arguments.json.write_text(json.dumps(report, indent=1) + "\n")
    if arguments.picture:
        draw_misses(misses, arguments.picture)
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
