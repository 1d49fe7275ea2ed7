"""The generator's simulation as the robot experiment (``togcrf.robot``) uses it: its one door into osgd.

``togcrf`` reads the generator's data through :mod:`osgd.contract`; its
robot experiment also drops piles, renders them and closes the gripper on
them with the generator's own stages, and reaches them through this module
only. It is thin: every name is one of the stages' own, re-exported, or a
function of a line or two that hands its arguments to them.

Frames and units
----------------
Lengths in metres, angles in radians, times in seconds, masses in kg,
forces in N; quaternions ``(x, y, z, w)``.

- World: ``z`` up, the table (floor) is the plane ``z = 0``, the stack
  stage's walled area is centred on the origin (:mod:`osgd.scenes.drop`).
- Object poses are of each model's *mesh frame* (the frame of its
  ``models`` row's vertices), never pybullet's inertial frame
  (:mod:`osgd.physics`).
- Camera: OpenCV (``x`` right, ``y`` down the image, ``z`` forward;
  :mod:`osgd.camera`); a :class:`CameraPose` is the camera frame in the
  world, ``p_world = rotation @ p_camera + position``
  (:mod:`osgd.samples.viewpoint`). Pixels: ``(0, 0)`` is the centre of the
  top-left pixel; depth is along the optical axis, 0 = no reading.
- Gripper frame (:mod:`osgd.gripper`): origin at the grasp centre (mid-way
  down the pads), ``x`` the closing axis from finger A to finger B, ``z``
  the approach direction; ``opening`` is the pad-to-pad distance.

What it offers
--------------
The world of a pipeline
    :func:`load_pipeline`, :class:`PipelineConfig`, :class:`ConfigError`
    (the pipeline config and its stages' parameters); :class:`ShardStore`
    (its manifest and checksummed shards); :class:`Gripper`, :data:`PANDA`;
    :class:`GraspSet`, :func:`grasp_set_from_rows` (a model's grasps,
    object frame); :func:`grasp_annotator` and :func:`pose_label` (the
    grasps stage's task label of a gripper pose on a model).
A pile
    :class:`ModelPool`, :class:`Release`, :func:`draw_releases` (the stack
    stage's draw) and :func:`drop_pile` (its drop, at rest: a ``scenes``
    row).
Its image
    :class:`CameraIntrinsics`, :class:`CameraPose`, :func:`look_at`,
    :class:`RenderObject`, :func:`make_renderer`, :func:`stage_renderer`
    and :func:`render_pile` (the render stage's ``samples`` row: noisy
    depth, mask, camera, ground-truth rectangles); :func:`pile_collider`
    (the render stage's gripper-against-pile collision test).
A grasp executed with the hand
    :func:`physics_client`, :func:`pybullet_module`,
    :func:`add_floor_and_walls`, :func:`create_object_body`,
    :func:`get_mesh_pose`, :func:`create_hand` (the checks stage's
    simulated gripper, :class:`SimulatedHand`), :data:`FINGER_A`,
    :data:`FINGER_B` (its fingers' link indices).

Imports
-------
Every osgd module is imported at the top. None of them imports pybullet when
imported (:func:`pybullet_module` does, on first use), but the grasps
modules load trimesh and embreex, which a reader of the dataset does not
need: ``togcrf.robot.cli`` imports this module when a command runs, not when
``togcrf`` starts.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pyarrow as pa

from osgd.camera import CameraIntrinsics
from osgd.checks.hand import FINGER_A, FINGER_B, SimulatedHand, create_hand
from osgd.config import ConfigError, PipelineConfig
from osgd.contract.taxonomy import TABLE1, Taxonomy
from osgd.grasps.labels import effective_rules
from osgd.grasps.model_grasps import GraspAnnotator, ModelInput
from osgd.grasps.params import GraspsStageParams
from osgd.gripper import PANDA, Gripper
from osgd.physics import create_object_body, get_mesh_pose, physics_client, pybullet_module
from osgd.pipeline import load_pipeline
from osgd.samples.collision import pile_collider
from osgd.samples.projection import GraspSet, grasp_set_from_rows
from osgd.samples.renderer import Renderer, RenderObject, make_renderer
from osgd.samples.stage import SamplesStageParams, render_sample, resolve_renderer
from osgd.samples.viewpoint import CameraPose, look_at
from osgd.scenes.drop import DrawFunction, ModelPool, Release, SceneResult, build_world, draw_releases, generate_scene
from osgd.scenes.params import ScenesStageParams
from osgd.store import ShardStore

__all__ = [
    "FINGER_A",
    "FINGER_B",
    "PANDA",
    "CameraIntrinsics",
    "CameraPose",
    "ConfigError",
    "GraspAnnotator",
    "GraspSet",
    "Gripper",
    "ModelPool",
    "PipelineConfig",
    "Release",
    "RenderObject",
    "Renderer",
    "SceneResult",
    "ShardStore",
    "SimulatedHand",
    "add_floor_and_walls",
    "create_hand",
    "create_object_body",
    "draw_releases",
    "drop_pile",
    "get_mesh_pose",
    "grasp_annotator",
    "grasp_set_from_rows",
    "load_pipeline",
    "look_at",
    "make_renderer",
    "physics_client",
    "pile_collider",
    "pose_label",
    "pybullet_module",
    "render_pile",
    "stage_renderer",
]


def grasp_annotator(model: pa.Table, params: GraspsStageParams, gripper: Gripper, seed: int,
                    taxonomy: Taxonomy = TABLE1) -> GraspAnnotator:
    """The grasps stage's annotator of one model: its label rule and its surface samples.

    Parameters
    ----------
    model : pyarrow.Table
        The model's ``models`` row (the first row is used).
    params : GraspsStageParams
        The pipeline's ``[grasps]`` parameters (their ``label_rules`` over the default rules).
    gripper : Gripper
    seed : int
        The pipeline seed (the surface samples derive from it and the model id).
    taxonomy : Taxonomy
        The pipeline's (its parts and label rules).
    """
    return GraspAnnotator(ModelInput.from_table(model, 0, taxonomy), params,
                          effective_rules(params.label_rules, taxonomy), gripper, seed)


def pose_label(annotator: GraspAnnotator, position: np.ndarray, rotation: np.ndarray, opening: float) -> str:
    """The task label the grasps stage gives one gripper pose on the annotator's model.

    Parameters
    ----------
    annotator : GraspAnnotator
        From :func:`grasp_annotator`.
    position : (3,) float
        Gripper origin (grasp centre) in the object (mesh) frame, m.
    rotation : (3, 3) float
        Gripper frame in the object frame (columns: closing, across, approach).
    opening : float
        Distance between the pads, m.

    Returns
    -------
    str
        One of ``osgd.contract.taxonomy.TASKS``; "no task" also when the model
        has no part labels.

    Notes
    -----
    The stage labels the poses of its own grasps inside
    :class:`~osgd.grasps.model_grasps.GraspAnnotator` (``_labels``, over the
    surface samples within the rule's reach of the centre, ``_label_reach``);
    this is the one door to that labeller from outside the stage.
    """
    centre = np.asarray(position, dtype=np.float64)
    nearby = annotator.surface.near(centre, annotator._label_reach)
    return annotator._labels(centre, np.asarray(rotation, dtype=np.float64)[None], float(opening), nearby)[0]


def drop_pile(pool: ModelPool, params: ScenesStageParams, pipeline_seed: int, scene_index: int,
              draw: DrawFunction = draw_releases) -> SceneResult:
    """Draw and drop the pile of one scene index with the stack stage (:func:`osgd.scenes.drop.generate_scene`).

    Its draws derive from ``(pipeline_seed, scene_index, attempt)`` only;
    ``draw`` replaces the stage's :func:`draw_releases`. The result's ``row``
    is a ``scenes`` row (objects: ``model_id``, ``category``, mesh-frame
    ``position`` (m) and ``quaternion`` in the world, at rest), or None when
    every attempt was rejected (``rejections`` by reason).
    """
    return generate_scene(pool, params, pipeline_seed, scene_index, draw=draw)


def stage_renderer(name: str) -> tuple[Renderer, list[str]]:
    """The render stage's renderer for a ``samples.renderer`` value, with a note when ``auto`` fell back."""
    return resolve_renderer(name)


def render_pile(scene: Mapping[str, Any], models: Mapping[str, Mapping[str, Any]],
                stable_grasps: Mapping[str, GraspSet], params: SamplesStageParams, seed: int, renderer: Renderer,
                gripper: Gripper, depth_range: tuple[float, float], view: int = 0) -> dict[str, Any]:
    """One view of a pile with the render stage (:func:`osgd.samples.stage.render_sample`): a ``samples`` row.

    The row holds the camera (``intrinsics`` ``fx, fy, cx, cy`` in px,
    ``width``, ``height``, ``camera_position`` (m) and ``camera_quaternion``
    of the camera frame in the world), the encoded noisy ``depth`` (m) and
    ``mask`` (``object_index + 1`` per pixel; decode them with
    :mod:`osgd.contract.encoding`), the objects' boxes and the ground-truth
    ``grasps`` (rectangles ``x, y, h, w, theta`` in px and rad, their tasks and
    camera-frame poses) of ``stable_grasps`` (object frame). Depth outside
    ``depth_range`` (near, far; m) reads 0; ``seed`` is the pipeline seed.
    """
    return render_sample(scene, view, models, stable_grasps, params, seed, renderer, gripper, depth_range)


def add_floor_and_walls(client: int, params: ScenesStageParams) -> list[int]:
    """The stack stage's floor (the plane ``z = 0``) and four walls in a pybullet client: body ids, floor first."""
    return build_world(client, params)
