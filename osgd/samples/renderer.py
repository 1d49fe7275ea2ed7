"""Depth and instance-mask rendering of a scene: EGL, embree or TinyRenderer.

Backends
--------
``embree``
    An exact CPU ray caster on embreex, used directly (trimesh's wrapper
    costs 3x more; REFERENCE section 8): one ray per pixel centre of each
    object's projected box, at the object's mesh in its own frame, whose
    embree scene is built once per process (:class:`osgd.raycast.EmbreeScenes`); the
    nearest hit wins, and the same casts count each object's silhouette.
``egl``
    pybullet's EGL plugin (Mesa llvmpipe on a machine without a GPU, the
    real driver where there is one): depth within 0.03 mm of an exact ray
    cast (REFERENCE section 8). Loading the
    plugin where no EGL driver exists makes the process exit with no
    exception, so :func:`egl_available` first tries it in a subprocess.
``tiny``
    pybullet's TinyRenderer: no GL needed, silhouettes about a pixel off.

``auto`` picks the first that works, in that order, and logs why it skipped
any.

Output
------
Depth is the z coordinate in the camera frame (what a depth camera
reports), metres, 0 where nothing was hit. The mask holds, per pixel,
``i + 1`` for the ``i``-th object passed in, 0 for the floor and for
nothing. The floor is a square of side ``2 * floor_half_size`` at ``z = 0``
centred under the camera.
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import logging
import pkgutil
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from osgd.camera import CameraIntrinsics
from osgd.physics import pybullet_module
from osgd.quiet import native_output_hidden
from osgd.raycast import EmbreeScenes, plane_hit_distances, rotate_grid_rays, rotate_rows
from osgd.samples.viewpoint import CameraPose

log = logging.getLogger(__name__)

#: Backend names in the order ``auto`` tries them: the exact ray caster first, since with each mesh's scene
#: built once per worker it is also the fastest on a CPU (``benchmarks/bench_render.py``) and needs no GL
#: driver.
BACKENDS: tuple[str, ...] = ("embree", "egl", "tiny")

#: Clip planes of the GL backends, metres: wider than the sensor range (the
#: stage applies that afterwards) so nothing in view is clipped, with the near
#: plane as far out as that allows, because the EGL depth buffer resolves
#: only ~0.4 mm at 0.7 m with a 1 cm near plane (0.04 mm with this one).
_GL_NEAR, _GL_FAR = 0.1, 6.0


@dataclass(frozen=True)
class RenderObject:
    """One object to draw.

    Attributes
    ----------
    key : str
        Identifies the mesh (e.g. the model id): backends cache uploaded
        meshes by it, so equal keys must mean equal meshes.
    vertices : (V, 3) float
        Mesh frame, metres.
    faces : (F, 3) int
    position : (3,) float
        Mesh-frame origin in the world, metres.
    quaternion : (4,) float
        Mesh-frame orientation in the world, ``(x, y, z, w)``.
    """

    key: str
    vertices: np.ndarray
    faces: np.ndarray
    position: np.ndarray
    quaternion: np.ndarray

    def world_vertices(self) -> np.ndarray:
        """Vertices in the world frame, (V, 3) float64."""
        return self.to_world(self.vertices)

    def to_world(self, points: np.ndarray) -> np.ndarray:
        """Mesh-frame points (N, 3) in the world frame, (N, 3) float64."""
        rotation = Rotation.from_quat(np.asarray(self.quaternion, dtype=np.float64)).as_matrix()
        return rotate_rows(points, rotation) + np.asarray(self.position, dtype=np.float64)


@dataclass(frozen=True)
class Rendering:
    """What a renderer returns.

    Attributes
    ----------
    depth : (H, W) float64
        Camera-frame z, metres; 0 where no surface was hit.
    mask : (H, W) int32
        ``i + 1`` where object ``i`` is seen, 0 for floor and background.
    """

    depth: np.ndarray
    mask: np.ndarray
    silhouettes: np.ndarray | None = None


class Renderer(Protocol):
    """The interface every backend implements."""

    name: str

    def render(
        self,
        objects: Sequence[RenderObject],
        intrinsics: CameraIntrinsics,
        pose: CameraPose,
        floor: bool = True,
    ) -> Rendering:
        """Render ``objects`` (and the floor) seen from ``pose``."""
        ...


# -- embree ------------------------------------------------------------------

def floor_mesh(centre_xy: np.ndarray, half_size: float) -> tuple[np.ndarray, np.ndarray]:
    """Two triangles at z = 0, normal up: vertices (4, 3), faces (2, 3)."""
    x, y = float(centre_xy[0]), float(centre_xy[1])
    vertices = np.array(
        [[x - half_size, y - half_size, 0.0], [x + half_size, y - half_size, 0.0],
         [x + half_size, y + half_size, 0.0], [x - half_size, y + half_size, 0.0]]
    )
    return vertices, np.array([[0, 1, 2], [0, 2, 3]])


def _hull_vertex_indices(vertices: np.ndarray) -> np.ndarray:
    """Indices of the convex hull's vertices; every vertex where the hull is flat or degenerate."""
    from scipy.spatial import ConvexHull, QhullError  # noqa: PLC0415

    try:
        return np.sort(ConvexHull(vertices).vertices)
    except (QhullError, ValueError):
        return np.arange(len(vertices))


#: :func:`hull_vertices`' indices by mesh key, for the life of the process (a few per model).
_HULL_INDICES: dict[str, np.ndarray] = {}


def hull_vertices(obj: RenderObject) -> np.ndarray:
    """The mesh's convex-hull vertices, (K, 3) float64, mesh frame; their indices computed once per key.

    A perspective projection's ``u`` and ``v`` are extreme at a hull vertex,
    so these bound the object's projected box exactly, at a fraction of the
    vertices (the authors' meshes have up to ~100k).
    """
    vertices = np.asarray(obj.vertices, dtype=np.float64).reshape(-1, 3)
    indices = _HULL_INDICES.get(obj.key)
    if indices is None:
        indices = _HULL_INDICES[obj.key] = _hull_vertex_indices(vertices)
    return vertices[indices]


@dataclass(frozen=True)
class ObjectHits:
    """One object cast alone: a ray per pixel centre of its projection's bounding box.

    Attributes
    ----------
    rows, columns : (N,) int64
        The pixel of each ray; may lie outside the image.
    hit : (N,) bool
    depth : (N,) float64
        Camera-frame z of the hit (the world triangle's plane, float64), 0 where missed.
    """

    rows: np.ndarray
    columns: np.ndarray
    hit: np.ndarray
    depth: np.ndarray


def cast_object(scenes: EmbreeScenes, obj: RenderObject, intrinsics: CameraIntrinsics,
                pose: CameraPose) -> ObjectHits | None:
    """Cast a ray through every pixel centre of the object's projected box at the object alone.

    The rays are turned into the mesh's frame (origin ``R^T (c - p)``,
    direction ``R^T R_c r``) and cast at its cached scene; the depth of a
    hit is recomputed in float64 on the world triangle (:mod:`osgd.raycast`),
    so it does not depend on the processor's SIMD.

    Returns
    -------
    ObjectHits or None
        None when a vertex lies behind the camera's image plane (no finite projection).
    """
    scene = scenes.scene(obj.key, obj.vertices, obj.faces)
    rotation = Rotation.from_quat(np.asarray(obj.quaternion, dtype=np.float64)).as_matrix()
    position = np.asarray(obj.position, dtype=np.float64)
    vertices = np.asarray(obj.vertices, dtype=np.float64)
    camera = pose.world_to_camera(rotate_rows(hull_vertices(obj), rotation) + position)
    if np.any(camera[:, 2] <= 1e-6):
        return None
    pixels = intrinsics.project(camera)
    low = np.floor(pixels.min(axis=0)).astype(np.int64)
    high = np.ceil(pixels.max(axis=0)).astype(np.int64)
    row_values, column_values = np.arange(low[1], high[1] + 1), np.arange(low[0], high[0] + 1)
    rows, columns = np.repeat(row_values, len(column_values)), np.tile(column_values, len(row_values))
    ray_x = (column_values - intrinsics.cx) / intrinsics.fx
    ray_y = (row_values - intrinsics.cy) / intrinsics.fy
    turn = rotation.T @ pose.rotation  # camera frame to the mesh's, in one turn
    local = np.stack(rotate_grid_rays(ray_x, ray_y, turn), axis=-1, dtype=np.float32).reshape(-1, 3)
    origin = rotate_rows((pose.position - position)[None, :], rotation.T).astype(np.float32)
    primitives = np.asarray(scene.run(np.broadcast_to(origin, local.shape).copy(), local))  # -1 where missed
    hit = primitives >= 0
    depth = np.zeros(len(hit))
    corners = vertices[np.asarray(obj.faces)[primitives[hit]]].reshape(-1, 3)
    triangles = (rotate_rows(corners, rotation) + position).reshape(-1, 3, 3)  # the hit triangles in the world
    origins = np.broadcast_to(np.asarray(pose.position, dtype=np.float64), (len(triangles), 3))
    hit_rays = np.stack([ray_x[columns[hit] - low[0]], ray_y[rows[hit] - low[1]], np.ones(len(triangles))], axis=1)
    depth[hit] = plane_hit_distances(origins, rotate_rows(hit_rays, pose.rotation), triangles)
    return ObjectHits(rows, columns, hit, depth)


@dataclass
class EmbreeRenderer:
    """Exact ray casting with embreex: one ray per pixel centre.

    Each object is cast alone over its projected box, at its mesh's scene
    cached in :class:`osgd.raycast.EmbreeScenes` (rays turned into the mesh's frame), and
    the nearest hit per pixel wins; the floor is the plane ``z = 0``. The
    same casts count the pixels each object covers alone, so the rendering
    carries its ``silhouettes`` with no second cast per object.

    Parameters
    ----------
    floor_half_size : float
        Half the side of the floor square, metres.
    """

    floor_half_size: float = 5.0
    name: str = field(default="embree", init=False)
    scenes: EmbreeScenes = field(default_factory=EmbreeScenes, repr=False)

    def render(
        self,
        objects: Sequence[RenderObject],
        intrinsics: CameraIntrinsics,
        pose: CameraPose,
        floor: bool = True,
    ) -> Rendering:
        height, width = intrinsics.height, intrinsics.width
        depth = self._floor_depth(intrinsics, pose) if floor else np.zeros(height * width)
        mask = np.zeros(height * width, dtype=np.int32)
        silhouettes = np.zeros(len(objects), dtype=np.int64)
        for index, obj in enumerate(objects):
            hits = cast_object(self.scenes, obj, intrinsics, pose)
            if hits is None:
                continue
            silhouettes[index] = np.count_nonzero(hits.hit)
            inside = hits.hit & (hits.rows >= 0) & (hits.rows < height) & (hits.columns >= 0) & (hits.columns < width)
            pixel = hits.rows[inside] * width + hits.columns[inside]
            nearer = (depth[pixel] == 0) | (hits.depth[inside] < depth[pixel])  # than the floor or earlier objects
            depth[pixel[nearer]] = hits.depth[inside][nearer]
            mask[pixel[nearer]] = index + 1
        return Rendering(depth.reshape(height, width), mask.reshape(height, width), silhouettes)

    def _floor_depth(self, intrinsics: CameraIntrinsics, pose: CameraPose) -> np.ndarray:
        """Depth of the floor square (``z = 0``, centred under the camera) per pixel, 0 where it is not seen.

        A ray ``c + t d`` (``d`` with camera-frame z 1, so ``t`` is the depth)
        meets the plane at ``t = -c_z / d_z``.
        """
        x = (np.arange(intrinsics.width) - intrinsics.cx) / intrinsics.fx
        y = (np.arange(intrinsics.height) - intrinsics.cy) / intrinsics.fy
        direction_x, direction_y, direction_z = rotate_grid_rays(x, y, pose.rotation)
        height = float(pose.position[2])
        with np.errstate(divide="ignore", invalid="ignore"):
            distances = -height / direction_z
        seen = ((distances > 0) & (np.abs(distances * direction_x) <= self.floor_half_size)
                & (np.abs(distances * direction_y) <= self.floor_half_size))  # offsets from the point under the camera
        return np.where(seen, distances, 0.0).reshape(-1)


def write_obj(vertices: np.ndarray, faces: np.ndarray, path: Path) -> Path:
    """Write one triangle mesh (V, 3) float, (F, 3) int as an OBJ file."""
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in vertices]
    lines.extend(f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces)
    path.write_text("\n".join(lines) + "\n")
    return path


_EGL_PROBE = """
import pkgutil, pybullet
client = pybullet.connect(pybullet.DIRECT)
loader = pkgutil.get_loader("eglRenderer")
plugin = pybullet.loadPlugin(loader.get_filename(), "_eglRendererPlugin", physicsClientId=client)
assert plugin >= 0, "loadPlugin returned %d" % plugin
pybullet.getCameraImage(8, 8, renderer=pybullet.ER_BULLET_HARDWARE_OPENGL, physicsClientId=client)
print("egl-ok")
"""

@functools.cache
def egl_available(timeout: float = 60.0) -> tuple[bool, str]:
    """Whether pybullet's EGL plugin loads and renders here.

    Tried once per process in a subprocess, because a failing load calls
    ``exit(1)`` in the plugin (REFERENCE section 8).

    Returns
    -------
    ok : bool
    reason : str
        Why not, when not.
    """
    try:
        result = subprocess.run(
            [sys.executable, "-c", _EGL_PROBE], capture_output=True, text=True, timeout=timeout, check=False
        )
    except (OSError, subprocess.TimeoutExpired) as error:
        return False, f"EGL probe did not run: {error}"
    if result.returncode == 0 and "egl-ok" in result.stdout:
        return True, ""
    tail = (result.stdout + result.stderr).strip().splitlines()[-3:]
    return False, f"EGL probe exited with {result.returncode}: {' | '.join(tail)}"


def gl_view_matrix(pose: CameraPose) -> list[float]:
    """pybullet's (OpenGL, column-major) view matrix for a camera pose.

    OpenGL's eye frame has ``y`` up and looks along ``-z``: the OpenCV
    camera frame with ``y`` and ``z`` negated.
    """
    world_to_camera = np.eye(4)
    world_to_camera[:3, :3] = pose.rotation.T
    world_to_camera[:3, 3] = -pose.rotation.T @ pose.position
    view = np.diag([1.0, -1.0, -1.0, 1.0]) @ world_to_camera
    return view.T.reshape(-1).tolist()


def gl_projection_matrix(intrinsics: CameraIntrinsics, near: float = _GL_NEAR, far: float = _GL_FAR) -> list[float]:
    """pybullet's (OpenGL, column-major) projection matrix for pinhole intrinsics.

    OpenCV puts pixel centres at integers; GL samples pixel centres at
    half-integers, hence the ``+ 0.5`` on the principal point.
    """
    width, height = intrinsics.width, intrinsics.height
    projection = np.zeros((4, 4))
    projection[0, 0] = 2 * intrinsics.fx / width
    projection[0, 2] = 1 - 2 * (intrinsics.cx + 0.5) / width
    projection[1, 1] = 2 * intrinsics.fy / height
    projection[1, 2] = 2 * (intrinsics.cy + 0.5) / height - 1
    projection[2, 2] = -(far + near) / (far - near)
    projection[2, 3] = -2 * far * near / (far - near)
    projection[3, 2] = -1.0
    return projection.T.reshape(-1).tolist()


class PybulletRenderer:
    """pybullet's ``getCameraImage`` with EGL or TinyRenderer.

    One DIRECT client per renderer, kept for the life of the process (the
    EGL plugin loads once per client); meshes are uploaded once per key.

    Parameters
    ----------
    backend : {"egl", "tiny"}
    floor_half_size : float
        Half the side of the floor square, metres.
    """

    def __init__(self, backend: str, floor_half_size: float = 5.0) -> None:
        pybullet = pybullet_module()
        if backend not in ("egl", "tiny"):
            raise ValueError(f"pybullet backend must be 'egl' or 'tiny', not {backend!r}")
        self.name = backend
        self.floor_half_size = floor_half_size
        self._pybullet = pybullet
        self._client = pybullet.connect(pybullet.DIRECT)
        if backend == "egl":
            ok, reason = egl_available()
            if not ok:
                pybullet.disconnect(self._client)
                raise RuntimeError(f"the EGL renderer is not available: {reason}")
            loader = pkgutil.get_loader("eglRenderer")
            with native_output_hidden((1, 2)):
                pybullet.loadPlugin(loader.get_filename(), "_eglRendererPlugin", physicsClientId=self._client)
            atexit.register(self._disconnect_quietly)
            self._mode = pybullet.ER_BULLET_HARDWARE_OPENGL
        else:
            self._mode = pybullet.ER_TINY_RENDERER
        self._shapes: dict[str, int] = {}
        self._folder: Path | None = None
        # A mesh rather than a GEOM_BOX: the EGL plugin draws boxes about
        # 5 mm off their stated extents.
        vertices, faces = floor_mesh(np.zeros(2), floor_half_size)
        self._floor = RenderObject("__floor__", vertices, faces, np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))

    def _disconnect_quietly(self) -> None:
        """At exit: unload the EGL plugin without its goodbye on stdout."""
        with contextlib.suppress(Exception), native_output_hidden((1, 2)):
            self._pybullet.disconnect(self._client)

    def _shape(self, obj: RenderObject) -> int:
        shape = self._shapes.get(obj.key)
        if shape is None:
            # The EGL plugin draws only meshes loaded from files (vertex
            # arrays give "issue extracting mesh"), so every backend here
            # gets an OBJ file, written once per key.
            if self._folder is None:
                self._folder = Path(tempfile.mkdtemp(prefix="osgd-render-"))
                atexit.register(shutil.rmtree, self._folder, ignore_errors=True)
            path = self._folder / f"mesh{len(self._shapes)}.obj"
            write_obj(np.asarray(obj.vertices, dtype=np.float64), np.asarray(obj.faces, dtype=np.int64), path)
            shape = self._pybullet.createVisualShape(
                self._pybullet.GEOM_MESH, fileName=str(path), physicsClientId=self._client
            )
            if shape < 0:
                raise RuntimeError(f"pybullet could not load mesh {obj.key!r} from {path}")
            self._shapes[obj.key] = shape
        return shape

    def render(
        self,
        objects: Sequence[RenderObject],
        intrinsics: CameraIntrinsics,
        pose: CameraPose,
        floor: bool = True,
    ) -> Rendering:
        pybullet, client = self._pybullet, self._client
        bodies: dict[int, int] = {}
        try:
            if floor:
                body = pybullet.createMultiBody(
                    baseVisualShapeIndex=self._shape(self._floor),
                    basePosition=[float(pose.position[0]), float(pose.position[1]), 0.0],
                    physicsClientId=client,
                )
                bodies[body] = 0
            for index, obj in enumerate(objects):
                body = pybullet.createMultiBody(
                    baseVisualShapeIndex=self._shape(obj),
                    basePosition=np.asarray(obj.position, dtype=np.float64).tolist(),
                    baseOrientation=np.asarray(obj.quaternion, dtype=np.float64).tolist(),
                    physicsClientId=client,
                )
                bodies[body] = index + 1
            with native_output_hidden():
                _, _, _, depth_buffer, segmentation = pybullet.getCameraImage(
                    intrinsics.width,
                    intrinsics.height,
                    viewMatrix=gl_view_matrix(pose),
                    projectionMatrix=gl_projection_matrix(intrinsics),
                    renderer=self._mode,
                    physicsClientId=client,
                )
        finally:
            for body in bodies:
                pybullet.removeBody(body, physicsClientId=client)
        shape = (intrinsics.height, intrinsics.width)
        buffer = np.asarray(depth_buffer, dtype=np.float64).reshape(shape)
        segmentation = np.asarray(segmentation, dtype=np.int64).reshape(shape)
        # Invert the GL depth buffer's perspective mapping to camera z.
        depth = _GL_FAR * _GL_NEAR / (_GL_FAR - (_GL_FAR - _GL_NEAR) * buffer)
        hit = segmentation >= 0
        lookup = np.zeros(max([*list(bodies), 0]) + 2, dtype=np.int32)
        for body, label in bodies.items():
            lookup[body] = label
        mask = np.where(hit, lookup[np.clip(segmentation, 0, len(lookup) - 1)], 0).astype(np.int32)
        return Rendering(np.where(hit, depth, 0.0), mask)


# -- choosing ------------------------------------------------------------------

_RENDERERS: dict[str, Renderer] = {}


def make_renderer(name: str) -> Renderer:
    """The renderer called ``name`` (one per process, reused).

    Parameters
    ----------
    name : {"auto", "egl", "embree", "tiny"}
        ``auto``: the first of :data:`BACKENDS` that works; each skipped one
        is logged with its reason.

    Raises
    ------
    RuntimeError
        If the named backend (or, for ``auto``, every backend) is unusable.
    """
    if name == "auto":
        reasons = []
        for backend in BACKENDS:
            try:
                renderer = make_renderer(backend)
            except (RuntimeError, ImportError) as error:
                reasons.append(f"{backend}: {error}")
                log.warning("renderer %s unavailable, trying the next: %s", backend, error)
                continue
            return renderer
        raise RuntimeError("no renderer works here: " + "; ".join(reasons))
    if name not in BACKENDS:
        raise ValueError(f"unknown renderer {name!r}; choose auto or one of {list(BACKENDS)}")
    renderer = _RENDERERS.get(name)
    if renderer is None:
        if name == "embree":
            try:
                import embreex  # noqa: F401, PLC0415
            except ImportError as error:
                raise RuntimeError(f"embreex is not installed ({error})") from error
            renderer = EmbreeRenderer()
        else:
            renderer = PybulletRenderer(name)
        _RENDERERS[name] = renderer
    return renderer


def available_backends() -> list[str]:
    """The backends that work in this process, in :data:`BACKENDS` order."""
    names = []
    for backend in BACKENDS:
        try:
            make_renderer(backend)
        except (RuntimeError, ImportError):
            continue
        names.append(backend)
    return names
