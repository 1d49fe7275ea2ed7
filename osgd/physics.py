"""pybullet bodies from ``models`` rows: the one place objects enter physics.

Used by the check stage (grasp trials), the stack stage (dropping piles,
judging their stored parts, the stacking statistics' contacts) and the
render stage (the gripper against the pile), the last two through
:class:`PileWorld`, a worker's world of static piles for closest-point
queries.

Frames
------
A pybullet body has a link frame (here: the object's mesh frame) and an
inertial frame (the centre of mass, along the principal axes of inertia).
``getBasePositionAndOrientation`` and ``resetBasePositionAndOrientation``
work on the *inertial* frame (REFERENCE section 8: 5 cm apart on a hammer),
so this module converts at the boundary: callers only ever see mesh-frame
poses, through :func:`get_mesh_pose` and :func:`set_mesh_pose`.

Collision shape
---------------
The convex parts of the ``convex_parts`` column become one compound shape:
they are written as one OBJ file with one ``o`` object per part, which
pybullet loads as a compound of convex hulls. (A plain ``GEOM_MESH`` from
vertices on a dynamic body would be the convex hull of the whole mesh, and
``createCollisionShapeArray`` takes no vertex arrays.)

A part of many vertices makes every contact query slow (Bullet's support
function visits each vertex). With ``max_hull_vertices``, each such part
collides as :func:`reduced_hull`: the hull of a few of its corners, inside
the part. Bodies then rest up to the part's ``shrink`` deeper in each
other than their stored parts would; the scenes stage judges the settled
pile's interpenetration on the stored parts
(:func:`osgd.scenes.drop.stored_penetration`).

Coordinates
-----------
pybullet makes every body a Featherstone multibody (a free base of six
degrees of freedom) unless asked for "maximal coordinates", a plain
``btRigidBody``. For a single free object both give the same motion under
the same contacts; the multibody's constraint rows cost more to solve, so
piles of plain rigid bodies stack faster. ``maximal_coordinates`` chooses.
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import hashlib
import shutil
import tempfile
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np

from osgd.quiet import import_pybullet
from osgd.raycast import rotate_rows

if TYPE_CHECKING:
    from osgd.gripper import Gripper


@functools.cache
def pybullet_module() -> ModuleType:
    """The pybullet module, imported on first use without its build-time banner.

    Importing :mod:`osgd.physics` does not import pybullet (nor send file
    descriptors 1 and 2 to /dev/null while it loads, as
    :func:`osgd.quiet.import_pybullet` does): the code that creates physics
    clients and bodies calls this first.
    """
    return import_pybullet()


@functools.cache
def _obj_folder() -> Path:
    """A per-process temporary folder for compound OBJ files, made on first use and removed at exit."""
    folder = Path(tempfile.mkdtemp(prefix="osgd-physics-"))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    return folder


def write_compound_obj(convex_parts: list[tuple[np.ndarray, np.ndarray]], path: Path) -> Path:
    """Write convex parts as one OBJ file, one ``o`` object per part.

    Parameters
    ----------
    convex_parts : list of (vertices (V, 3) float, faces (F, 3) int)
        Object frame, metres.
    path : Path
    """
    lines = []
    offset = 1
    for index, (vertices, faces) in enumerate(convex_parts):
        lines.append(f"o part{index}")
        lines.extend(f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in np.asarray(vertices, dtype=np.float64))
        lines.extend(f"f {a + offset} {b + offset} {c + offset}" for a, b, c in np.asarray(faces, dtype=np.int64))
        offset += len(vertices)
    path.write_text("\n".join(lines) + "\n")
    return path


def reduced_hull(vertices: np.ndarray, max_vertices: int) -> tuple[np.ndarray, np.ndarray, float]:
    """The hull of at most ``max_vertices`` well-spread corners of a convex part.

    Farthest-point sampling on the part's hull corners, from the corner
    farthest from their mean: each next corner is the one farthest from
    those taken. The result lies inside the part; ``shrink`` says how far
    the part reaches beyond it. A part already that small, or whose chosen
    corners lie in one plane, is returned as its own hull.

    Parameters
    ----------
    vertices : (V, 3) float
        A convex part's vertices, metres.
    max_vertices : int
        Most corners of the result (at least 4).

    Returns
    -------
    corners : (C, 3) float64
    faces : (F, 3) int64
        Triangles of the hull of ``corners``.
    shrink : float
        The farthest any corner of the part lies beyond a face plane of the
        result, metres (0 for a part returned as its own hull).
    """
    from scipy.spatial import ConvexHull, QhullError  # noqa: PLC0415

    points = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    try:
        hull = ConvexHull(points)
    except (QhullError, ValueError):
        return points, np.zeros((0, 3), dtype=np.int64), 0.0
    corners = points[hull.vertices]
    if len(corners) <= max(max_vertices, 4):
        return (*_hull_mesh(hull), 0.0)
    centre = corners.mean(axis=0)
    chosen = [int(np.argmax(np.einsum("ij,ij->i", corners - centre, corners - centre)))]
    distance = np.einsum("ij,ij->i", corners - corners[chosen[0]], corners - corners[chosen[0]])
    while len(chosen) < max_vertices:
        chosen.append(int(np.argmax(distance)))
        offset = corners - corners[chosen[-1]]
        distance = np.minimum(distance, np.einsum("ij,ij->i", offset, offset))
    try:
        reduced = ConvexHull(corners[chosen])
    except (QhullError, ValueError):  # the chosen corners lie in one plane: keep the part
        return (*_hull_mesh(hull), 0.0)
    shrink = float(np.max(corners @ reduced.equations[:, :3].T + reduced.equations[:, 3]))
    return (*_hull_mesh(reduced), max(shrink, 0.0))


def _hull_mesh(hull: Any) -> tuple[np.ndarray, np.ndarray]:
    """The corners of a :class:`scipy.spatial.ConvexHull` and its triangles indexing them."""
    index = np.full(len(hull.points), -1, dtype=np.int64)
    index[hull.vertices] = np.arange(len(hull.vertices))
    return hull.points[hull.vertices], index[hull.simplices]


def _cell_mesh(vertices: Any, faces: Any) -> tuple[np.ndarray, np.ndarray]:
    return (
        np.asarray(vertices, dtype=np.float64).reshape(-1, 3),
        np.asarray(faces, dtype=np.int64).reshape(-1, 3),
    )


@dataclass(frozen=True)
class ObjectBody:
    """A model instantiated in a pybullet world.

    Attributes
    ----------
    body_id : int
    model_id : str
    client : int
        The physics client it lives in.
    inertial_position : (3,) float64
        Centre of mass in the mesh frame, metres.
    inertial_quaternion : (4,) float64
        Principal axes of inertia in the mesh frame, (x, y, z, w).
    """

    body_id: int
    model_id: str
    client: int
    inertial_position: np.ndarray
    inertial_quaternion: np.ndarray


def principal_inertia(inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Diagonalise an inertia tensor.

    Parameters
    ----------
    inertia : (3, 3) float
        About the centre of mass, in object axes, kg m^2.

    Returns
    -------
    moments : (3,) float64
        Principal moments, kg m^2.
    quaternion : (4,) float64
        Rotation from the principal axes to object axes, (x, y, z, w).
    """
    from scipy.spatial.transform import Rotation  # noqa: PLC0415

    symmetric = (np.asarray(inertia, dtype=np.float64) + np.asarray(inertia, dtype=np.float64).T) / 2
    moments, axes = np.linalg.eigh(symmetric)
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return np.maximum(moments, 1e-9), Rotation.from_matrix(axes).as_quat()


@functools.lru_cache(maxsize=1024)
def _principal_inertia_of(inertia: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """:func:`principal_inertia` of a flat (9,) inertia tensor, computed once per tensor and process.

    Every body of every pile asks for it, mostly for tensors already seen.
    The arrays are read-only, since the cache hands out the same ones.
    """
    moments, quaternion = principal_inertia(np.asarray(inertia, dtype=np.float64).reshape(3, 3))
    moments.flags.writeable = quaternion.flags.writeable = False
    return moments, quaternion


def _compound_name(model: Mapping[str, Any], max_hull_vertices: int) -> str:
    """The file name of a model's collision compound in this process's folder.

    The model id names the mesh, not its convex parts: one mesh cut by two
    decomposition presets (the ``decomposition`` column) gets two files.
    """
    decomposition = hashlib.sha256(str(model.get("decomposition", "")).encode("utf-8")).hexdigest()[:12]
    return f"{model['model_id']}-{decomposition}-{max_hull_vertices}.obj"


def create_object_body(
    client: int,
    model: Mapping[str, Any],
    position: np.ndarray | None = None,
    quaternion: np.ndarray | None = None,
    *,
    mass: float | None = None,
    max_hull_vertices: int = 0,
    maximal_coordinates: bool = False,
) -> ObjectBody:
    """Create a dynamic body for one row of the ``models`` table.

    Parameters
    ----------
    client : int
        pybullet physics client id.
    model : mapping
        A ``models`` row as a dict (``Table.to_pylist()``): ``model_id``,
        ``convex_parts``, ``mass``, ``center_of_mass``, ``inertia``,
        ``friction``.
    position : (3,) float, optional
        Mesh-frame origin in the world, metres (default: origin).
    quaternion : (4,) float, optional
        Mesh-frame orientation in the world, (x, y, z, w) (default: identity).
    mass : float, optional
        Override the model's mass, kg (0 makes the body static).
    max_hull_vertices : int
        Above 0: each convex part of more corners collides as its
        :func:`reduced_hull` of this many (0: the parts as stored).
    maximal_coordinates : bool
        A plain rigid body (pybullet's ``useMaximalCoordinates``, solved by
        Bullet's rigid-body solver) instead of a multibody with a free base
        (the default). Poses, mass, inertia and friction are the same.

    Returns
    -------
    ObjectBody
    """
    pybullet = pybullet_module()
    if not len(model["convex_parts"]):
        raise ValueError(f"model {model['model_id']}: no convex parts to collide with")
    # One compound file per model, decomposition and process; later bodies of the model reuse it.
    obj_path = _obj_folder() / _compound_name(model, max_hull_vertices)
    if not obj_path.exists():
        parts = [_cell_mesh(part["vertices"], part["faces"]) for part in model["convex_parts"]]
        if max_hull_vertices > 0:
            parts = [reduced_hull(vertices, max_hull_vertices)[:2] for vertices, _ in parts]
        write_compound_obj(parts, obj_path)
    shape = pybullet.createCollisionShape(pybullet.GEOM_MESH, fileName=str(obj_path), physicsClientId=client)
    if shape < 0:
        raise RuntimeError(f"model {model['model_id']}: pybullet could not create its collision shape")
    moments, inertial_quaternion = _principal_inertia_of(
        tuple(np.asarray(model["inertia"], dtype=np.float64).reshape(-1).tolist()))
    inertial_position = np.asarray(model["center_of_mass"], dtype=np.float64)
    body_mass = float(model["mass"] if mass is None else mass)
    body = pybullet.createMultiBody(
        baseMass=body_mass,
        baseCollisionShapeIndex=shape,
        baseInertialFramePosition=inertial_position.tolist(),
        baseInertialFrameOrientation=inertial_quaternion.tolist(),
        useMaximalCoordinates=maximal_coordinates,
        physicsClientId=client,
    )
    if body_mass > 0:
        # The mass goes with the inertia: on a body in maximal coordinates, pybullet 3.2 sets the mass to 0 when
        # changeDynamics gives localInertiaDiagonal without it (the body then turns NaN on its first step).
        pybullet.changeDynamics(body, -1, mass=body_mass, localInertiaDiagonal=moments.tolist(),
                                physicsClientId=client)
    lateral, rolling, spinning = (float(value) for value in model["friction"])
    pybullet.changeDynamics(
        body, -1, lateralFriction=lateral, rollingFriction=rolling, spinningFriction=spinning,
        physicsClientId=client,
    )
    handle = ObjectBody(body, str(model["model_id"]), client, inertial_position, inertial_quaternion)
    set_mesh_pose(
        handle,
        np.zeros(3) if position is None else position,
        np.array([0.0, 0.0, 0.0, 1.0]) if quaternion is None else quaternion,
    )
    return handle


def set_mesh_pose(body: ObjectBody, position: np.ndarray, quaternion: np.ndarray) -> None:
    """Place a body so that its mesh frame has the given world pose (velocities kept)."""
    pybullet = pybullet_module()
    com_position, com_quaternion = pybullet.multiplyTransforms(
        list(map(float, position)), list(map(float, quaternion)),
        body.inertial_position.tolist(), body.inertial_quaternion.tolist(),
    )
    pybullet.resetBasePositionAndOrientation(body.body_id, com_position, com_quaternion, physicsClientId=body.client)


def get_mesh_pose(body: ObjectBody) -> tuple[np.ndarray, np.ndarray]:
    """World pose of a body's mesh frame.

    Returns
    -------
    position : (3,) float64
    quaternion : (4,) float64
        (x, y, z, w)
    """
    pybullet = pybullet_module()
    com_position, com_quaternion = pybullet.getBasePositionAndOrientation(body.body_id, physicsClientId=body.client)
    inverse_position, inverse_quaternion = pybullet.invertTransform(
        body.inertial_position.tolist(), body.inertial_quaternion.tolist()
    )
    position, quaternion = pybullet.multiplyTransforms(
        com_position, com_quaternion, inverse_position, inverse_quaternion
    )
    return np.asarray(position, dtype=np.float64), np.asarray(quaternion, dtype=np.float64)


@contextlib.contextmanager
def physics_client(timestep: float = 1.0 / 240.0, gravity: float = -9.81) -> Iterator[int]:
    """A headless (DIRECT) pybullet client, disconnected on exit.

    Parameters
    ----------
    timestep : float
        Seconds per simulation step (pybullet's default 1/240 s).
    gravity : float
        Along world z, m/s^2.
    """
    pybullet = pybullet_module()
    client = pybullet.connect(pybullet.DIRECT)
    try:
        pybullet.setGravity(0.0, 0.0, gravity, physicsClientId=client)
        pybullet.setTimeStep(timestep, physicsClientId=client)
        yield client
    finally:
        pybullet.disconnect(client)


class _ProcessClient:
    """The one physics client of this process (a per-worker cache, not shared state)."""

    client: int | None = None
    exit_handler_registered: bool = False
    in_use: bool = False  # by worker_client


def process_client() -> int:
    """This process's own headless (DIRECT) client, created on first use.

    One client per worker process, reused by every grasp trial and every
    dropped pile the process makes (connecting costs more than a grasp
    trial); disconnected at exit. Its users empty it before each use.
    """
    pybullet = pybullet_module()
    if _ProcessClient.client is None or not pybullet.isConnected(_ProcessClient.client):
        if not _ProcessClient.exit_handler_registered:  # one exit handler per process, however often it reconnects
            atexit.register(_disconnect)
            _ProcessClient.exit_handler_registered = True
        _ProcessClient.client = pybullet.connect(pybullet.DIRECT)
    return _ProcessClient.client


def _disconnect() -> None:
    pybullet = pybullet_module()
    if _ProcessClient.client is not None and pybullet.isConnected(_ProcessClient.client):
        pybullet.disconnect(_ProcessClient.client)
    _ProcessClient.client = None


@contextlib.contextmanager
def worker_client(timestep: float = 1.0 / 240.0, gravity: float = -9.81) -> Iterator[int]:
    """:func:`process_client`, emptied (``resetSimulation``) and set up like a new :func:`physics_client`.

    The same as a new client (a test checks that piles dropped in it equal
    those of new clients, in any order), without connecting anew for each
    use.

    Parameters
    ----------
    timestep, gravity : float
        As in :func:`physics_client`.

    Raises
    ------
    RuntimeError
        When it is already in use in this process (emptying it would empty
        the other user's world).
    """
    pybullet = pybullet_module()
    if _ProcessClient.in_use:
        raise RuntimeError("worker_client is already in use in this process: use physics_client for a second world")
    client = process_client()
    pybullet.resetSimulation(physicsClientId=client)
    pybullet.setGravity(0.0, 0.0, gravity, physicsClientId=client)
    pybullet.setTimeStep(timestep, physicsClientId=client)
    _ProcessClient.in_use = True
    try:
        yield client
    finally:
        _ProcessClient.in_use = False


#: Where bodies wait between piles: body ``i`` at ``PARKING_ORIGIN + PARKING_SPACING * (i % 100, i // 100, 0)``,
#: far from every pile and from each other. A body left where its last pile put it overlaps the next pile's,
#: and pybullet's broadphase then walks every such overlap whenever a body moves there: with the many
#: gripper and object bodies a worker keeps, that would make each move of the gripper slow.
PARKING_ORIGIN = np.array([1000.0, 1000.0, 1000.0])
PARKING_SPACING = 2.0


class PileWorld:
    """A worker's pybullet world of static piles for geometric queries: bodies made once, moved from pile to pile.

    Static bodies are kept per model id and decomposition (equal keys:
    equal collision compounds, as :func:`create_object_body` assumes for its
    compound files), as many per model as a pile has copies of it, and parked far
    away between piles (:data:`PARKING_ORIGIN`). The world is never
    stepped: closest-point queries between two bodies depend only on their
    shapes and poses, so a pile placed here answers them as a pile loaded
    anew in an empty world (a test checks it), without building its
    collision compounds again. Used by the samples stage's
    gripper collisions (:mod:`osgd.samples.collision`, which keeps its
    gripper bodies in :attr:`gripper_bodies`), the scenes stage's test
    of the stored parts (:func:`osgd.scenes.drop.stored_penetration`) and
    the stacking statistics' contacts (:func:`osgd.scenes.statistics.scene_contacts`).

    Parameters
    ----------
    fixtures : callable(client) -> list of int, optional
        Makes the world's fixed bodies (a floor, walls) when it connects;
        their ids are :attr:`fixtures`.
    """

    def __init__(self, fixtures: Callable[[int], list[int]] | None = None) -> None:
        self.client: int | None = None
        self._make_fixtures = fixtures
        self.fixtures: list[int] = []
        self._bodies: dict[str, list[ObjectBody]] = {}
        #: Gripper bodies by gripper, then by opening (metres).
        self.gripper_bodies: dict[Gripper, dict[float, int]] = {}
        self._hull_points: dict[str, np.ndarray] = {}

    def _connected(self) -> int:
        pybullet = pybullet_module()
        if self.client is None or not pybullet.isConnected(self.client):
            self.client = pybullet.connect(pybullet.DIRECT)
            self._bodies.clear()
            self.gripper_bodies.clear()
            self.fixtures = self._make_fixtures(self.client) if self._make_fixtures is not None else []
        return self.client

    def close(self) -> None:
        """Disconnect the world (a later pile connects a new one)."""
        pybullet = pybullet_module()
        if self.client is not None and pybullet.isConnected(self.client):
            pybullet.disconnect(self.client)
        self.client = None

    def bounds(self, models: Mapping[str, Mapping[str, Any]], objects: Sequence[Mapping[str, Any]]) -> np.ndarray:
        """Each object's axis-aligned box in the world, (N, 2, 3): its convex parts' vertices at its pose."""
        from scipy.spatial.transform import Rotation  # noqa: PLC0415

        boxes = np.zeros((len(objects), 2, 3))
        for index, obj in enumerate(objects):
            model = models[obj["model_id"]]
            key = _compound_name(model, 0)
            points = self._hull_points.get(key)
            if points is None:
                points = np.concatenate([np.asarray(part["vertices"], dtype=np.float64).reshape(-1, 3)
                                         for part in model["convex_parts"]])
                self._hull_points[key] = points
            rotation = Rotation.from_quat(np.asarray(obj["quaternion"], dtype=np.float64)).as_matrix()
            world = rotate_rows(points, rotation) + np.asarray(obj["position"], dtype=np.float64)
            boxes[index] = world.min(axis=0), world.max(axis=0)
        return boxes

    def place(self, models: Mapping[str, Mapping[str, Any]], objects: Sequence[Mapping[str, Any]]) -> list[int]:
        """Body ids of the pile's objects, in scene order, each at its scene pose."""
        client = self._connected()
        used: Counter[str] = Counter()
        body_ids = []
        for obj in objects:
            model = models[obj["model_id"]]
            key = _compound_name(model, 0)  # the mesh and its decomposition, as the compound files
            copies = self._bodies.setdefault(key, [])
            if used[key] == len(copies):
                copies.append(create_object_body(client, model, mass=0.0))
            body = copies[used[key]]
            used[key] += 1
            set_mesh_pose(body, np.asarray(obj["position"], dtype=np.float64),
                          np.asarray(obj["quaternion"], dtype=np.float64))
            body_ids.append(body.body_id)
        return body_ids

    def park(self, body_ids: Iterable[int]) -> None:
        """Move bodies to their parking spots (:data:`PARKING_ORIGIN`), away from every pile."""
        pybullet = pybullet_module()
        for body in body_ids:
            spot = PARKING_ORIGIN + PARKING_SPACING * np.array([body % 100, body // 100, 0.0])
            pybullet.resetBasePositionAndOrientation(body, spot.tolist(), [0.0, 0.0, 0.0, 1.0],
                                                     physicsClientId=self.client)
