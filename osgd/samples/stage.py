"""The samples stage: noisy depth images with boxes and task-labelled grasp rectangles.

One work item per ``scenes`` shard; it reads that shard and every shard of
``models``, ``grasps`` and ``checks``, and writes ``views_per_scene`` rows
per scene (``sample_id = f"{scene_id}_view{n}"``). Per sample:

1. a camera pose above the pile (:mod:`osgd.samples.viewpoint`), drawn
   from ``(pipeline seed, scene_index, view)``;
2. depth and instance mask of the objects' full meshes and the floor
   (:mod:`osgd.samples.renderer`); readings outside the sensor's range
   become 0;
3. noise on a copy of the depth (:mod:`osgd.samples.noise`);
4. boxes and visible fractions (:mod:`osgd.samples.boxes`); objects below
   ``min_visible_fraction`` are dropped with their grasps;
5. the stable grasps (``checks.stable``) of each kept object, moved to the
   camera frame, filtered and projected (:mod:`osgd.samples.projection`,
   :mod:`osgd.samples.collision`).

The split (train or test) is, by default, a function of the scene id alone
(sha256), so a scene stays in its split whatever else changes. Where the
scenes stage holds tools out (``[scenes.split] by = "model"``,
:mod:`osgd.scenes.split`) a sample is test when every object of its scene is
a test model; the samples items then carry the scenes' split settings.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Any, Literal

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from pydantic import Field, model_validator
from scipy.spatial.transform import Rotation

from osgd.camera import KINECT_V2, CameraIntrinsics
from osgd.contract.encoding import CLEAN_DEPTH_PNG_PARAMS, encode_depth, encode_mask
from osgd.contract.schemas import SAMPLES, samples_schema
from osgd.contract.shards import ShardRecord
from osgd.contract.taxonomy import TABLE1
from osgd.gripper import PANDA, Gripper
from osgd.models.rows import BODY_COLUMNS, model_rows
from osgd.samples.boxes import SilhouetteCounter, visible_boxes
from osgd.samples.collision import PileCollider, pile_collider
from osgd.samples.noise import NoiseModel, add_noise
from osgd.samples.projection import (
    GraspSet,
    angle_to_optical_axis,
    centres_in_image,
    contacts_visible,
    grasp_rectangles,
    grasp_set_from_rows,
    suppress,
)
from osgd.samples.renderer import BACKENDS, Renderer, Rendering, RenderObject, hull_vertices, make_renderer
from osgd.samples.viewpoint import CameraPose, draw_camera_pose
from osgd.scenes.split import SplitParams, model_sides, scene_split, unit_hash
from osgd.stage import BuildResult, PlannedShard, Stage, StageParams, WorkItem, item_taxonomy, read_once_per_worker
from osgd.store import ShardStore

log = logging.getLogger(__name__)

#: Mixed into every sample's seed so the samples stage draws differently
#: from other stages seeded with the same pipeline seed.
_STAGE_SALT = 0x5A3D1E


#: The ``models`` columns the split by model reads (:func:`osgd.scenes.split.model_sides`).
SPLIT_COLUMNS: tuple[str, ...] = ("model_id", "name", "category")


def sample_payload(key_params: dict, seed: int, scenes_item: str, split: dict | None = None) -> dict:
    """The payload of the samples item of one scenes shard: all its samples depend on besides the shards.

    The parameters (``renderer`` already resolved), the seed, the scenes
    item, the camera's depth range and the gripper, which the build would
    otherwise read from modules (``osgd.camera``, ``osgd.gripper``), and,
    where the scenes split by model, their split settings (``split``, the
    JSON of a :class:`~osgd.scenes.split.SplitParams`; absent otherwise).
    """
    payload = {
        "params": key_params,
        "seed": int(seed),
        "scenes_item": scenes_item,
        "depth_range": [KINECT_V2.near, KINECT_V2.far],
        "gripper": dataclasses.asdict(PANDA),
    }
    if split is not None:
        payload["split"] = split
    return payload


def scenes_split(scenes: Sequence[PlannedShard]) -> dict | None:
    """The split settings of the planned scenes shards (their ``[scenes.split]``), or None for the default.

    Raises
    ------
    ValueError
        If the shards were planned with different split settings.
    """
    found = {json.dumps(shard.item.payload.get("params", {}).get("split"), sort_keys=True) for shard in scenes}
    if len(found) > 1:
        raise ValueError(f"the scenes shards were planned with different [scenes.split] settings: {sorted(found)}")
    return json.loads(found.pop()) if found else None


def split_models(store: ShardStore, model_keys: Sequence[str], split: dict) -> dict[str, str]:
    """The side (train or test) of every model of the ``models`` shards ``model_keys`` under ``split``.

    Raises
    ------
    ValueError
        If ``split`` names a test model the shards do not hold.
    """
    rows = store.read_many("models", list(model_keys), columns=list(SPLIT_COLUMNS)).to_pylist()
    return model_sides(rows, SplitParams(**split))


class SamplesStageParams(StageParams):
    """Parameters of the samples stage (the ``[samples]`` config section)."""

    views_per_scene: int = Field(1, ge=1, description="Depth images per scene, each from its own camera pose.")
    test_fraction: float = Field(
        0.1, ge=0.0, le=1.0, description="Share of scenes in the test split (paper: not stated; 90/10 is ours); "
        "unused where [scenes.split] by = 'model', whose scene_fraction and held-out tools decide."
    )
    renderer: Literal["auto", "egl", "embree", "tiny"] = Field(
        "auto", description="Rendering backend; auto tries embree, egl, tiny in that order."
    )
    image_width: int = Field(KINECT_V2.width, ge=8, description="Image width, px (Kinect v2 depth: 512).")
    image_height: int = Field(KINECT_V2.height, ge=8, description="Image height, px (Kinect v2 depth: 424).")
    fx: float = Field(KINECT_V2.fx, gt=0, description="Focal length along x, px (Kinect v2: 70.6 deg over 512 px).")
    fy: float = Field(KINECT_V2.fy, gt=0, description="Focal length along y, px.")
    cx: float | None = Field(None, description="Principal point x, px; default: the image centre.")
    cy: float | None = Field(None, description="Principal point y, px; default: the image centre.")
    crop_size: int = Field(
        320, ge=0, description="Side of the square image around the objects, px; 0 keeps the whole Kinect frame. "
        "The original generator cropped a square around the union of the object boxes and resized it "
        "(300 and 500 px); rendering straight into that window's intrinsics gives the same image without "
        "resampling.")
    crop_margin: tuple[float, float] = Field(
        (1.05, 1.3), description="The window's side is the longer side of the objects' union box times a factor "
        "drawn uniformly in this range (the original generator's U(1.05, 1.3)).")
    camera_height: float = Field(
        0.75, gt=0, description="Camera height above the table, m (0.25 m past the Kinect v2's 0.5 m near limit)."
    )
    max_tilt: float = Field(0.17, ge=0, le=1.0, description="Largest tilt of the optical axis from vertical, rad.")
    max_yaw: float = Field(0.26, ge=0, le=np.pi, description="Largest turn of the image about the optical axis, rad.")
    noise_model: Literal["none", "gaussian", "sensor"] = Field(
        "gaussian", description="gaussian: the paper's zero-mean gaussian; sensor: adds correlated, edge, hole noise."
    )
    noise_sigma: float = Field(0.002, ge=0, description="Gaussian depth noise std, m (Kinect v2: ~1-2 mm).")
    correlated_sigma: float = Field(0.002, ge=0, description="sensor model: correlated noise std, m (REFERENCE 6).")
    correlated_cell: int = Field(16, ge=1, description="sensor model: correlated noise grid cell, px.")
    edge_hole_fraction: float = Field(0.3, ge=0, le=1, description="sensor model: share of edge pixels lost.")
    hole_fraction: float = Field(0.002, ge=0, le=1, description="sensor model: share of all pixels lost.")
    min_visible_fraction: float = Field(
        0.1, ge=0, le=1, description="Objects whose visible share of their silhouette is below this are dropped."
    )
    min_angle_to_optical_axis: float = Field(
        np.pi / 4, ge=0, le=np.pi / 2, description="Grasps whose closing line is nearer the optical axis are dropped, "
        "rad (paper: 45 deg).")
    nms_radius: float = Field(
        0.015, ge=0, description="NMS radius on 3-D grasp centres, m (original: 0.05 model units, ~1-1.5 cm).")
    contact_tolerance: float = Field(
        0.01, ge=0, description="A contact is hidden when another object is this much in front of it, m.")
    collision_tolerance: float = Field(
        0.001, ge=0, description="Gripper penetration into another object that still counts as free, m.")

    def intrinsics(self, near: float = KINECT_V2.near, far: float = KINECT_V2.far) -> CameraIntrinsics:
        """The camera intrinsics these parameters describe, with the given depth range (m)."""
        return CameraIntrinsics(
            width=self.image_width,
            height=self.image_height,
            fx=self.fx,
            fy=self.fy,
            cx=(self.image_width - 1) / 2 if self.cx is None else self.cx,
            cy=(self.image_height - 1) / 2 if self.cy is None else self.cy,
            near=near,
            far=far,
        )

    @model_validator(mode="after")
    def _ordered_margin(self) -> SamplesStageParams:
        low, high = self.crop_margin
        if not 1.0 <= low <= high:
            raise ValueError(f"crop_margin {list(self.crop_margin)} must satisfy 1 <= low <= high")
        return self

    def noise(self) -> NoiseModel:
        """The depth noise these parameters describe."""
        return NoiseModel(
            model=self.noise_model,
            sigma=self.noise_sigma,
            correlated_sigma=self.correlated_sigma,
            correlated_cell=self.correlated_cell,
            edge_hole_fraction=self.edge_hole_fraction,
            hole_fraction=self.hole_fraction,
        )


def split_of(scene_id: str, test_fraction: float) -> str:
    """``"test"`` or ``"train"``, from the sha256 of the scene id alone (:func:`osgd.scenes.split.unit_hash`)."""
    return "test" if unit_hash(scene_id) < test_fraction else "train"


def sample_rng(seed: int, scene_index: int, view: int) -> np.random.Generator:
    """The random generator of one sample: camera pose first, then noise."""
    entropy = [seed % 2**64, _STAGE_SALT, scene_index % 2**64, view]
    return np.random.default_rng(np.random.SeedSequence(entropy))


def _pose_matrix(position: Sequence[float], quaternion: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    return Rotation.from_quat(np.asarray(quaternion, dtype=np.float64)).as_matrix(), np.asarray(
        position, dtype=np.float64
    )


@dataclasses.dataclass(frozen=True)
class _CameraView:
    """What the camera of one sample saw: the frame grasps are judged in.

    Attributes
    ----------
    intrinsics : CameraIntrinsics
        The (possibly cropped) camera.
    pose : CameraPose
        Camera pose in the world frame.
    depth_clean : (H, W) float64
        Noise-free depth, m; 0 outside the sensor's range.
    mask : (H, W) int32
        Object index + 1 per pixel, 0 for the floor.
    """

    intrinsics: CameraIntrinsics
    pose: CameraPose
    depth_clean: np.ndarray
    mask: np.ndarray


def render_sample(
    scene: Mapping[str, Any],
    view: int,
    models: Mapping[str, Mapping[str, Any]],
    stable_grasps: Mapping[str, GraspSet],
    params: SamplesStageParams,
    seed: int,
    renderer: Renderer,
    gripper: Gripper = PANDA,
    depth_range: tuple[float, float] = (KINECT_V2.near, KINECT_V2.far),
    sides: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """One row of the ``samples`` table.

    Parameters
    ----------
    scene : mapping
        A ``scenes`` row (dict).
    view : int
        View number within the scene.
    models : mapping of model id to ``models`` row (dict)
    stable_grasps : mapping of model id to GraspSet
        Each model's stable grasps, object frame.
    params : SamplesStageParams
    seed : int
        The pipeline seed.
    renderer : Renderer
    gripper : Gripper
        The hand whose collisions and finger width the grasps are judged with.
    depth_range : (float, float)
        The camera's near and far limits, m: depth outside reads 0.
    sides : mapping of model id to "train" or "test", optional
        Where the split is by model: the sample's split is
        :func:`osgd.scenes.split.scene_split` of the scene's models. None: by
        scene id against ``params.test_fraction``.

    Returns
    -------
    dict
        Keyed by the columns of ``osgd.contract.schemas.SAMPLES``.
    """
    intrinsics = params.intrinsics(*depth_range)
    objects = list(scene["objects"])
    rng = sample_rng(seed, int(scene["scene_index"]), view)
    positions = np.array([obj["position"] for obj in objects], dtype=np.float64).reshape(-1, 3)
    aim = np.array([*positions[:, :2].mean(axis=0), 0.0]) if len(positions) else np.zeros(3)
    pose = draw_camera_pose(rng, aim, params.camera_height, params.max_tilt, params.max_yaw)

    render_objects = _render_objects(objects, models)
    if params.crop_size and render_objects:
        intrinsics = crop_around_objects(intrinsics, pose, render_objects, params.crop_size,
                                         float(rng.uniform(*params.crop_margin)))
    rendering = renderer.render(render_objects, intrinsics, pose)
    in_range = (rendering.depth >= intrinsics.near) & (rendering.depth <= intrinsics.far)
    depth_clean = np.where(in_range, rendering.depth, 0.0)
    depth = add_noise(depth_clean, rng, params.noise())

    sample_objects = _visible_objects(objects, render_objects, rendering, intrinsics, pose,
                                      params.min_visible_fraction)
    camera_view = _CameraView(intrinsics, pose, depth_clean, rendering.mask)
    sample_grasps: list[dict[str, Any]] = []
    with pile_collider(models, objects, gripper, params.collision_tolerance) as collider:
        for sample_object in sample_objects:
            index = sample_object["object_index"]
            grasps = stable_grasps.get(objects[index]["model_id"])
            if grasps is not None and len(grasps):
                sample_grasps += _object_grasps(index, objects[index], grasps, camera_view, collider, params, gripper)

    mask = rendering.mask
    if mask.max(initial=0) > 255:
        raise ValueError(f"scene {scene['scene_id']}: more than 255 objects do not fit the 8-bit mask")
    return {
        "sample_id": f"{scene['scene_id']}_view{view}",
        "scene_id": scene["scene_id"],
        "split": (split_of(scene["scene_id"], params.test_fraction) if sides is None
                  else scene_split([obj["model_id"] for obj in objects], sides)),
        "height": intrinsics.height,
        "width": intrinsics.width,
        "depth": encode_depth(depth),
        "depth_clean": encode_depth(depth_clean, CLEAN_DEPTH_PNG_PARAMS),
        "mask": encode_mask(mask),
        "intrinsics": intrinsics.as_array().tolist(),
        "camera_position": pose.position.tolist(),
        "camera_quaternion": pose.quaternion.tolist(),
        "renderer": renderer.name,
        "objects": sample_objects,
        "grasps": sample_grasps,
    }


def _render_objects(
    objects: Sequence[Mapping[str, Any]], models: Mapping[str, Mapping[str, Any]]
) -> list[RenderObject]:
    """The scene's objects posed in the world, with their models' meshes, in scene order."""
    render_objects = []
    for obj in objects:
        model = models[obj["model_id"]]
        render_objects.append(RenderObject(
            key=obj["model_id"],
            vertices=np.asarray(model["vertices"], dtype=np.float64).reshape(-1, 3),
            faces=np.asarray(model["faces"], dtype=np.int64).reshape(-1, 3),
            position=np.asarray(obj["position"], dtype=np.float64),
            quaternion=np.asarray(obj["quaternion"], dtype=np.float64),
        ))
    return render_objects


@functools.cache
def worker_silhouettes() -> SilhouetteCounter:
    """This process's :class:`SilhouetteCounter`: its embree scenes serve every item the worker builds."""
    return SilhouetteCounter()


def _visible_objects(
    objects: Sequence[Mapping[str, Any]],
    render_objects: Sequence[RenderObject],
    rendering: Rendering,
    intrinsics: CameraIntrinsics,
    pose: CameraPose,
    min_visible_fraction: float,
) -> list[dict[str, Any]]:
    """The ``objects`` entries of a sample: every object seen enough, in scene order.

    Parameters
    ----------
    objects : sequence of mapping
        The scene's objects (``scenes`` row entries).
    render_objects : sequence of RenderObject
        The same objects, posed.
    rendering : Rendering
        Its mask (object index + 1 per pixel, 0 for the floor) and, from the
        embree renderer, the pixels each object covers alone.
    intrinsics : CameraIntrinsics
    pose : CameraPose
    min_visible_fraction : float
        Objects showing less of their silhouette than this are left out.

    Returns
    -------
    list of dict
        ``object_index``, ``model_id``, ``category``, ``box`` (4,) and ``visible_fraction`` per kept object.
    """
    boxes, visible = visible_boxes(rendering.mask, len(objects))
    sample_objects = []
    for index, obj in enumerate(objects):
        if visible[index] == 0:
            continue
        silhouette = (int(rendering.silhouettes[index]) if rendering.silhouettes is not None
                      else worker_silhouettes().count(render_objects[index], intrinsics, pose))
        fraction = min(1.0, visible[index] / silhouette) if silhouette else 0.0
        if fraction < min_visible_fraction:
            continue
        sample_objects.append({
            "object_index": index,
            "model_id": obj["model_id"],
            "category": obj["category"],
            "box": boxes[index].tolist(),
            "visible_fraction": fraction,
        })
    return sample_objects


def _object_grasps(
    index: int,
    obj: Mapping[str, Any],
    grasps: GraspSet,
    camera_view: _CameraView,
    collider: PileCollider,
    params: SamplesStageParams,
    gripper: Gripper,
) -> list[dict[str, Any]]:
    """The ``grasps`` entries of one object: its stable grasps usable from this view.

    A grasp is usable when its closing direction is far enough from the
    optical axis, its centre is in the image and its contacts are visible;
    of those, non-maximum suppression keeps the ones most parallel to the
    image whose hand touches no other object.

    Parameters
    ----------
    index : int
        The object's index in the scene.
    obj : mapping
        The scene's entry of the object (pose).
    grasps : GraspSet
        The object's stable grasps, object frame.
    camera_view : _CameraView
    collider : PileCollider
        The pile, for the hand's collisions.
    params : SamplesStageParams
    gripper : Gripper

    Returns
    -------
    list of dict
        Keyed by the fields of a ``grasps`` entry of ``osgd.contract.schemas.SAMPLES``, ordered by grasp.
    """
    pose, intrinsics = camera_view.pose, camera_view.intrinsics
    object_rotation, object_position = _pose_matrix(obj["position"], obj["quaternion"])
    world = grasps.transformed(object_rotation, object_position)
    camera_rotation_inverse = pose.rotation.T
    camera = world.transformed(camera_rotation_inverse, -camera_rotation_inverse @ pose.position)
    angles = angle_to_optical_axis(camera.closing)
    usable = (
        (angles >= params.min_angle_to_optical_axis - 1e-9)
        & centres_in_image(camera, intrinsics)
        & contacts_visible(camera, camera_view.depth_clean, camera_view.mask, index + 1, intrinsics,
                           params.contact_tolerance)
    )
    candidates = np.nonzero(usable)[0]
    if not len(candidates):
        return []

    quaternions = world.subset(candidates).quaternions
    near = collider.near_objects(world.positions[candidates], world.rotations[candidates], world.widths[candidates])

    def free(position: int) -> bool:
        grasp = candidates[position]
        return not collider.collides(index, world.positions[grasp], world.rotations[grasp], float(world.widths[grasp]),
                                     quaternions[position], near[position])

    kept = np.sort(candidates[suppress(camera.positions[candidates], angles[candidates], params.nms_radius, free)])
    chosen = camera.subset(kept)
    rectangles = grasp_rectangles(chosen, intrinsics, gripper.finger_width)
    quaternions = chosen.quaternions
    return [
        {
            "object_index": index,
            "grasp_id": int(chosen.grasp_ids[row]),
            "task": str(chosen.tasks[row]),
            "rectangle": rectangles[row].tolist(),
            "position": chosen.positions[row].tolist(),
            "quaternion": quaternions[row].tolist(),
            "width": float(chosen.widths[row]),
        }
        for row in range(len(chosen))
    ]


def crop_around_objects(
    intrinsics: CameraIntrinsics,
    pose: CameraPose,
    objects: Sequence[RenderObject],
    size: int,
    margin: float,
) -> CameraIntrinsics:
    """The intrinsics of a square window around all objects, resized to ``size`` px.

    The window is centred on the union of the objects' projected boxes
    (every vertex, hidden or not: the hull's vertices bound them,
    :func:`osgd.samples.renderer.hull_vertices`) and its side is the longer side of that
    union times ``margin``, as the original generator cropped its renders.

    Parameters
    ----------
    intrinsics : CameraIntrinsics
        The full camera.
    pose : CameraPose
    objects : sequence of RenderObject
        Posed objects (world frame).
    size : int
        Output side, px.
    margin : float
        Window side over the union box's longer side, >= 1.
    """
    corners = []
    for obj in objects:
        pixels = intrinsics.project(pose.world_to_camera(obj.to_world(hull_vertices(obj))))
        corners.append((pixels.min(axis=0), pixels.max(axis=0)))
    low = np.min([corner[0] for corner in corners], axis=0) + 0.5  # pixel-edge coordinates
    high = np.max([corner[1] for corner in corners], axis=0) + 0.5
    centre = (low + high) / 2
    side = float(max(high - low)) * margin
    return intrinsics.cropped(centre[0] - side / 2, centre[1] - side / 2, max(side, 1.0), size)


def load_stable_grasps(
    store: ShardStore, inputs: Mapping[str, Sequence[str]], model_ids: set[str]
) -> dict[str, GraspSet]:
    """Each model's stable grasps (object frame), joining grasps and checks on (model_id, grasp_id)."""
    value_set = pa.array(sorted(model_ids), type=pa.string())
    grasps = store.read_many("grasps", list(inputs.get("grasps", ())))
    grasps = grasps.filter(pc.is_in(grasps["model_id"], value_set=value_set))
    checks = store.read_many("checks", list(inputs.get("checks", ())), columns=["model_id", "grasp_id", "stable"])
    checks = checks.filter(pc.is_in(checks["model_id"], value_set=value_set))
    stable = {
        (model_id, grasp_id)
        for model_id, grasp_id, ok in zip(
            checks["model_id"].to_pylist(), checks["grasp_id"].to_pylist(), checks["stable"].to_pylist(), strict=True
        )
        if ok
    }
    rows_by_model: dict[str, list[dict]] = {model_id: [] for model_id in model_ids}
    for row in grasps.to_pylist():
        if (row["model_id"], row["grasp_id"]) in stable:
            rows_by_model[row["model_id"]].append(row)
    return {model_id: grasp_set_from_rows(rows) for model_id, rows in rows_by_model.items()}


def worker_model_inputs(
    store: ShardStore, inputs: Mapping[str, Sequence[str]]
) -> tuple[dict[str, dict[str, Any]], dict[str, GraspSet]]:
    """Every model's row (:func:`osgd.models.rows.model_rows`) and stable grasps, read once per worker.

    Every samples item of a pipeline names the same models, grasps and
    checks shards (:func:`osgd.stage.read_once_per_worker`; reading them
    for each item would cost a large share of its time).

    Parameters
    ----------
    store : ShardStore
    inputs : mapping of table name to shard keys
        The item's ``models``, ``grasps`` and ``checks`` keys.

    Returns
    -------
    models : dict of model id to dict
    stable_grasps : dict of model id to GraspSet
    """
    def read() -> tuple[dict[str, dict[str, Any]], dict[str, GraspSet]]:
        rows = model_rows(store.read_many("models", list(inputs.get("models", ())), columns=list(BODY_COLUMNS)))
        return rows, load_stable_grasps(store, inputs, set(rows))

    keys = [",".join(inputs.get(table, ())) for table in ("models", "grasps", "checks")]
    return read_once_per_worker("samples: models and stable grasps", store, keys, read)


class SamplesStage(Stage):
    """Noisy depth images with boxes and task-labelled grasp rectangles."""

    name = "samples"
    table = "samples"
    # 4: the shards record their vocabulary (osgd.vocabulary); 5: silhouettes in the mesh frame;
    # 6: PNG writer settings per image kind (osgd.contract.encoding; the same decoded images, other bytes)
    version = 6
    inputs = ("models", "grasps", "checks", "scenes")
    Params = SamplesStageParams
    uses_taxonomy = True
    description = "Noisy depth images with boxes and task-labelled grasp rectangles."

    def plan(
        self, params: StageParams, seed: int, upstream: Mapping[str, Sequence[PlannedShard]]
    ) -> list[WorkItem]:
        """One item per scenes shard; the payload holds everything a sample depends on.

        Besides the parameters and the seed: the renderer actually used
        (``auto`` is resolved here, before planning, so two runs whose
        ``auto`` picks differ never share keys), the camera's depth range and
        the gripper, which the build would otherwise read from modules.
        """
        assert isinstance(params, SamplesStageParams)
        shared = {table: tuple(sorted(shard.key for shard in upstream.get(table, ()))) for table in
                  ("models", "grasps", "checks")}
        key_params = params.key_dict()
        scenes = upstream.get("scenes", ())
        if scenes:  # resolving auto may probe EGL: only when there is something to render
            key_params["renderer"] = resolve_backend(params.renderer)
        split = scenes_split(scenes)
        items = []
        for shard in scenes:
            items.append(WorkItem(f"samples_{shard.item.item_id}",
                                  sample_payload(key_params, seed, shard.item.item_id, split),
                                  {"scenes": (shard.key,), **shared}))
        return items

    def manifest_extra(self, shards: Sequence[PlannedShard], store: ShardStore) -> dict[str, Any]:
        """Where the split is by model: ``split``, the settings with the sorted ``train_models`` and ``test_models``."""
        split = next((shard.item.payload["split"] for shard in shards if "split" in shard.item.payload), None)
        if split is None:
            return {}
        sides = split_models(store, shards[0].item.inputs.get("models", ()), split)
        return {"split": {**split,
                          "train_models": sorted(model for model, side in sides.items() if side == "train"),
                          "test_models": sorted(model for model, side in sides.items() if side == "test")}}

    def build(self, item: WorkItem, store: ShardStore) -> BuildResult:
        params = SamplesStageParams(**item.payload["params"])
        seed = int(item.payload["seed"])
        gripper = Gripper(**item.payload["gripper"])
        near, far = item.payload["depth_range"]
        scenes = store.read_many("scenes", list(item.inputs["scenes"])).to_pylist()
        model_ids = {obj["model_id"] for scene in scenes for obj in scene["objects"]}
        every_model, every_stable = worker_model_inputs(store, item.inputs)
        missing = sorted(model_ids - set(every_model))
        if missing:
            raise KeyError(f"scenes shard {item.inputs['scenes'][0]} names models not in the models table: {missing}")
        models = {model_id: every_model[model_id] for model_id in model_ids}
        stable_grasps = {model_id: every_stable[model_id] for model_id in model_ids}
        sides = split_models(store, item.inputs.get("models", ()), item.payload["split"]) \
            if "split" in item.payload else None
        renderer, notes = resolve_renderer(params.renderer)
        rows = [
            render_sample(scene, view, models, stable_grasps, params, seed, renderer, gripper, (near, far), sides)
            for scene in scenes
            for view in range(params.views_per_scene)
        ]
        if sides is not None:
            mixed = [scene["scene_id"] for scene in scenes
                     if len({sides[obj["model_id"]] for obj in scene["objects"]}) > 1]
            if mixed:
                notes.append(f"{len(mixed)} of {len(scenes)} scenes mix train and test models and are test "
                             f"(e.g. {mixed[0]}); the scenes stage draws no such pile")
        empty = [row["sample_id"] for row in rows if not row["grasps"]]
        if empty:
            notes.append(f"{len(empty)} of {len(rows)} samples have no grasp (e.g. {empty[0]})")
        taxonomy = item_taxonomy(item)
        schema = SAMPLES if taxonomy == TABLE1 else samples_schema(taxonomy.vocabulary)
        return BuildResult(pa.Table.from_pylist(rows, schema=schema), notes)

    def summary(self, store: ShardStore, records: Sequence[ShardRecord]) -> str:
        """Samples per split, objects and grasps per sample, grasps per task."""
        tables = [store.read("samples", record.key, columns=["split", "renderer", "objects", "grasps"])
                  for record in records]
        if not tables:
            return "no samples"
        table = pa.concat_tables(tables)
        splits = Counter(table["split"].to_pylist())
        renderers = Counter(table["renderer"].to_pylist())
        object_counts = np.array([len(objects) for objects in table["objects"].to_pylist()])
        grasp_lists = table["grasps"].to_pylist()
        grasp_counts = np.array([len(grasps) for grasps in grasp_lists])
        tasks = Counter(grasp["task"] for grasps in grasp_lists for grasp in grasps)
        lines = [
            f"samples: {table.num_rows} ({', '.join(f'{name} {count}' for name, count in sorted(splits.items()))}); "
            f"renderer: {', '.join(f'{name} {count}' for name, count in sorted(renderers.items()))}",
            f"objects per sample: mean {object_counts.mean():.2f}, min {object_counts.min()}, "
            f"max {object_counts.max()}",
            f"grasps per sample: mean {grasp_counts.mean():.1f}, min {grasp_counts.min()}, max {grasp_counts.max()}; "
            f"samples without grasps: {int((grasp_counts == 0).sum())}",
            "grasps per task: " + ", ".join(f"{task} {count}" for task, count in sorted(tasks.items())),
        ]
        return "\n".join(lines)


def resolve_backend(name: str) -> str:
    """The backend a ``renderer`` parameter names here: ``auto`` becomes the
    first of embree, egl, tiny that works in this process (others unchanged).

    Raises
    ------
    RuntimeError
        If ``auto`` finds no working backend.
    """
    return make_renderer(name).name if name == "auto" else name


def resolve_renderer(name: str) -> tuple[Renderer, list[str]]:
    """The renderer for a ``renderer`` parameter, with a note when ``auto`` fell back."""
    renderer = make_renderer(name)
    notes = []
    if name == "auto" and renderer.name != BACKENDS[0]:
        notes.append(f"renderer auto fell back to {renderer.name}: {BACKENDS[0]} does not work here (the log says why)")
    return renderer, notes
