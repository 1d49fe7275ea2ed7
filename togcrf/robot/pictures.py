"""The picture of a failed trial.

Left: the noisy depth image the policy saw, the pile's tools boxed and
named (ground truth, solid), a checkpoint's detections (dashed yellow,
category and score under the box), the ground-truth rectangles of the
trial's task thin and green, the chosen rectangle thick and red. Right: a render of the pile
at the moment of failure (after closing for ``empty_close``, after the hold
otherwise; at rest when no grasp was executed), seen from beside the
gripper, across its closing axis, from 45 cm away and 20 degrees above the
point between the fingertips and the table: each tool in its own colour,
the hand dark grey.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from osgd.contract.taxonomy import CATEGORIES
from osgd.simulation import CameraIntrinsics, CameraPose, RenderObject, look_at
from togcrf.geometry import rectangle_corners
from togcrf.robot.execute import Execution
from togcrf.robot.observation import Observation
from togcrf.robot.protocol import Trial

#: Side of the render, px, and its horizontal field of view, rad.
_VIEW_SIZE, _VIEW_FOV = 360, math.radians(50)
_COLOURS = np.array([[0.12, 0.47, 0.71], [1.0, 0.5, 0.05], [0.17, 0.63, 0.17], [0.84, 0.15, 0.16],
                     [0.58, 0.4, 0.74], [0.55, 0.34, 0.29], [0.89, 0.47, 0.76], [0.74, 0.74, 0.13]])
_HAND, _FLOOR = np.array([0.25, 0.25, 0.25]), np.array([0.93, 0.9, 0.83])


def hand_mesh(gripper: Any, opening: float) -> tuple[np.ndarray, np.ndarray]:
    """The simulated hand at an opening as one triangle mesh in the gripper frame.

    The fingers at the opening, the palm at the maximum opening, as
    :func:`osgd.simulation.create_hand` builds it (a palm does not shrink).
    """
    parts = [box for box in gripper.boxes(opening) if box[0] != "palm"]
    parts += [box for box in gripper.boxes(gripper.max_opening) if box[0] == "palm"]
    boxes = [trimesh.creation.box(extents=2 * half, transform=trimesh.transformations.translation_matrix(centre))
             for _, centre, half in parts]
    mesh = trimesh.util.concatenate(boxes)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def _side_camera(target: np.ndarray, across: np.ndarray) -> tuple[CameraIntrinsics, CameraPose]:
    side = np.array([across[0], across[1], 0.0])
    side = side / np.linalg.norm(side) if np.linalg.norm(side) > 1e-9 else np.array([0.0, -1.0, 0.0])
    position = target + 0.42 * side + np.array([0.0, 0.0, 0.16])
    focal = _VIEW_SIZE / 2 / math.tan(_VIEW_FOV / 2)
    intrinsics = CameraIntrinsics(width=_VIEW_SIZE, height=_VIEW_SIZE, fx=focal, fy=focal, cx=(_VIEW_SIZE - 1) / 2,
                                  cy=(_VIEW_SIZE - 1) / 2, near=0.05, far=3.0)
    return intrinsics, look_at(position, target, np.cross([0.0, 0.0, 1.0], side))


def render_state(world: Any, observation: Observation, execution: Execution | None, renderer: Any) -> np.ndarray:
    """An RGB image (H, W, 3) of the pile (and hand) at the end of an execution, or at rest."""
    scene = observation.scene
    poses = execution.object_poses if execution is not None else [
        (np.asarray(obj["position"]), np.asarray(obj["quaternion"])) for obj in scene["objects"]]
    objects = []
    for obj, (position, quaternion) in zip(scene["objects"], poses, strict=True):
        model = world.models[obj["model_id"]]
        objects.append(RenderObject(obj["model_id"], np.asarray(model["vertices"], dtype=np.float64).reshape(-1, 3),
                                    np.asarray(model["faces"], dtype=np.int64).reshape(-1, 3), position, quaternion))
    if execution is not None:
        opening = round(float(execution.hand_opening), 4)
        vertices, faces = hand_mesh(world.gripper, opening)
        objects.append(RenderObject(f"robot-hand-{opening:.4f}", vertices, faces, *execution.hand_pose))
        # Between the fingertips and the table under them: the tool in the hand and the pile below.
        hand = np.asarray(execution.hand_pose[0])
        target = np.array([hand[0], hand[1], max(hand[2] - world.gripper.finger_depth / 2, 0.0) / 2 + 0.01])
        across = execution.grasp.rotation[:, 1]
    else:
        target = np.array([*np.mean([pose[0][:2] for pose in poses], axis=0), 0.03])
        across = np.array([0.0, -1.0, 0.0])
    intrinsics, pose = _side_camera(target, across)
    rendering = renderer.render(objects, intrinsics, pose)
    return _colour(rendering.depth, rendering.mask, len(scene["objects"]), execution is not None)


def _colour(depth: np.ndarray, mask: np.ndarray, count: int, with_hand: bool) -> np.ndarray:
    """Colour by object, darker with depth."""
    palette = np.vstack([_FLOOR, *[_COLOURS[index % len(_COLOURS)] for index in range(count)],
                         *([_HAND] if with_hand else [])])
    hit = depth > 0
    image = np.ones((*depth.shape, 3))
    if hit.any():
        low, high = np.percentile(depth[hit], [1, 99])
        shade = 1.0 - 0.45 * np.clip((depth - low) / max(high - low, 1e-6), 0.0, 1.0)
        image = np.where(hit[..., None], palette[np.clip(mask, 0, len(palette) - 1)] * shade[..., None], 1.0)
    return image


def failure_picture(path: Path, trial: Trial, policy: str, observation: Observation, rectangle: np.ndarray | None,
                    execution: Execution | None, reason: str, state: np.ndarray, detections: Any = None,
                    categories: Sequence[str] = CATEGORIES) -> Path:
    """Draw a failed trial (see the module text) into a PNG; ``detections`` (a checkpoint's, named by its
    ``categories``) dashed in yellow."""

    figure = Figure(figsize=(11, 5.6), dpi=90)
    left, right = figure.subplots(1, 2)
    depth = observation.depth
    valid = depth > 0
    low, high = np.percentile(depth[valid], [1, 99]) if valid.any() else (0.0, 1.0)
    left.imshow(np.where(valid, depth, np.nan), cmap="gray_r", vmin=low - 0.3 * (high - low), vmax=high)
    for index, obj in enumerate(observation.sample["objects"]):
        x1, y1, x2, y2 = obj["box"]
        colour = _COLOURS[obj["object_index"] % len(_COLOURS)]
        left.add_patch(Rectangle((x1, y1), x2 - x1, y2 - y1, fill=False, edgecolor=colour, linewidth=1.2))
        left.text(x1, y1 - 2 - 9 * (index % 2), obj["category"], color="white", fontsize=7,
                  bbox={"facecolor": colour, "edgecolor": "none", "pad": 1})
    if detections is not None:
        _draw_detections(left, detections, categories)
    for grasp in observation.sample["grasps"]:
        if grasp["task"] == trial.task:
            corners = rectangle_corners(np.asarray(grasp["rectangle"]))
            left.plot(*np.vstack([corners, corners[:1]]).T, color="#3cb44b", linewidth=0.8)
    if rectangle is not None:
        corners = rectangle_corners(np.asarray(rectangle))
        for start, end, width in ((0, 1, 4.0), (1, 2, 1.5), (2, 3, 4.0), (3, 0, 1.5)):
            left.plot(corners[[start, end], 0], corners[[start, end], 1], color="red", linewidth=width)
    left.set_xlim(0, depth.shape[1])
    left.set_ylim(depth.shape[0], 0)
    left.set_axis_off()
    named = f" ({trial.category})" if trial.category else ""
    left.set_title(f"{policy}: {trial.task}{named}, trial {trial.repeat}", fontsize=10)
    right.imshow(state)
    right.set_axis_off()
    right.set_title(_state_title(observation, execution, reason), fontsize=9)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path)
    return path


def _draw_detections(axes: Any, detections: Any, categories: Sequence[str]) -> None:
    """A checkpoint's detections: dashed yellow boxes, category (of the model's ``categories``) and score at the
    bottom-left corner."""
    for box, category, score in zip(detections.boxes, detections.categories, detections.scores, strict=True):
        x1, y1, x2, y2 = box
        axes.add_patch(Rectangle((x1, y1), x2 - x1, y2 - y1, fill=False, edgecolor="yellow", linewidth=1.0,
                                     linestyle="--"))
        axes.text(x1, y2 + 8, f"{categories[int(category)]} {score:.2f}", color="black", fontsize=6,
                  bbox={"facecolor": "yellow", "edgecolor": "none", "pad": 1})


def _state_title(observation: Observation, execution: Execution | None, reason: str) -> str:
    if execution is None:
        return f"{reason}: nothing executed"
    categories = observation.categories
    held = categories[execution.gripped] if execution.gripped >= 0 else "nothing"
    stop = f", approach stopped by {execution.stopped_by}" if execution.stopped else ""
    label = f", label {execution.label!r}" if execution.label else ""
    return f"{reason}: gripped {held}{label}, rise {execution.rise * 100:.1f} cm{stop}"
