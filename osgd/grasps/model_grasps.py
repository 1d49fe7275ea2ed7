"""The grasps of one model: contact pairs -> collision-free, labelled 6-DoF grasps.

Contact pairs come from the model's hand-made annotations (OSGD) when it has
any, and from the antipodal sampler otherwise. Each pair gives a grasp
centre (the midpoint), a closing axis (contact a -> contact b) and an opening
(contact distance plus ``Gripper.clearance``); the gripper is tried at
``approach_count`` approaches evenly around the closing axis and each
collision-free one is a grasp. Annotated pairs carry their task (from the
annotation file); sampled ones are labelled from the parts between the pads
(:mod:`osgd.grasps.labels`).
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import pyarrow as pa
import trimesh

from osgd.contract.schemas import GRASPS, mesh_from_arrow, vectors_to_arrow
from osgd.contract.taxonomy import TABLE1, Taxonomy
from osgd.grasps.antipodal import sample_pairs, spread_order, thin_pairs
from osgd.grasps.geometry import (
    GripperCollision,
    ObjectSurface,
    approach_directions,
    closing_region,
    convex_planes,
    gripper_rotations,
    local_points,
    rotations_to_quaternions,
)
from osgd.grasps.labels import LabelRule, ToolAxis, holding_parts, label_grasp, tool_axis
from osgd.grasps.params import GraspsStageParams
from osgd.gripper import Gripper

log = logging.getLogger(__name__)

#: The ``origin`` of a sampled grasp.
ANTIPODAL = "antipodal"


@dataclass(frozen=True)
class ModelInput:
    """What the grasps of one model are computed from (a ``models`` row).

    Attributes
    ----------
    model_id, name, category : str
    vertices : (V, 3) float64
        Object frame, m.
    faces : (F, 3) int64
    face_parts : (F,) int64
        Part index per face (the taxonomy's parts), -1 unknown.
    convex_parts : list of (vertices, faces)
        The collision compound.
    annotated_pairs : list of dict
        ``task``, ``contact_a``, ``contact_b`` (object frame, m), ``file``.
    """

    model_id: str
    name: str
    category: str
    vertices: np.ndarray
    faces: np.ndarray
    face_parts: np.ndarray
    convex_parts: list[tuple[np.ndarray, np.ndarray]]
    annotated_pairs: list[dict]

    @classmethod
    def from_table(cls, table: pa.Table, row: int, taxonomy: Taxonomy = TABLE1) -> ModelInput:
        """Row ``row`` of a ``models`` table, whose categories, parts and tasks are the taxonomy's.

        Raises
        ------
        ValueError
            If the row is inconsistent (naming the model and the problem).
        """
        def cell(name: str):
            return table.column(name)[row]

        model_id = cell("model_id").as_py()
        name = cell("name").as_py()
        category = cell("category").as_py()
        vertices, faces = mesh_from_arrow(cell("vertices"), cell("faces"))
        face_parts = np.asarray(cell("face_parts").as_py(), dtype=np.int64)
        where = f"model {name} ({model_id})"
        if category not in taxonomy.category_names:
            raise ValueError(f"{where}: unknown category {category!r}")
        if len(face_parts) != len(faces):
            raise ValueError(f"{where}: {len(face_parts)} face_parts for {len(faces)} faces")
        if len(faces) == 0:
            raise ValueError(f"{where}: the mesh has no faces")
        if np.any(faces >= len(vertices)) or np.any(faces < 0):
            raise ValueError(f"{where}: a face indexes a vertex that does not exist")
        if np.any((face_parts < -1) | (face_parts >= len(taxonomy.parts))):
            raise ValueError(f"{where}: face_parts outside -1..{len(taxonomy.parts) - 1}")
        convex_parts = [
            mesh_from_arrow(part["vertices"], part["faces"]) for part in cell("convex_parts").values
        ] if cell("convex_parts").values is not None else []
        pairs = cell("annotated_pairs").as_py()
        for index, pair in enumerate(pairs):
            if pair["task"] not in taxonomy.tasks:
                raise ValueError(f"{where}: annotated pair {index} ({pair['file']}) has unknown task {pair['task']!r}")
        return cls(model_id, name, category, vertices, faces, face_parts, convex_parts, pairs)


@dataclass
class _Rows:
    """Grasp columns, appended pair by pair."""

    task: list[str] = field(default_factory=list)
    position: list[np.ndarray] = field(default_factory=list)
    rotation: list[np.ndarray] = field(default_factory=list)
    width: list[float] = field(default_factory=list)
    contact_a: list[np.ndarray] = field(default_factory=list)
    contact_b: list[np.ndarray] = field(default_factory=list)
    origin: list[str] = field(default_factory=list)
    pair_index: list[int] = field(default_factory=list)
    quality: list[float] = field(default_factory=list)

    def add(self, *, task, centre, rotation, width, contact_a, contact_b, origin, pair_index, quality) -> None:
        self.task.append(task)
        self.position.append(centre)
        self.rotation.append(rotation)
        self.width.append(width)
        self.contact_a.append(contact_a)
        self.contact_b.append(contact_b)
        self.origin.append(origin)
        self.pair_index.append(pair_index)
        self.quality.append(quality)

    def table(self, model_id: str) -> pa.Table:
        count = len(self.task)
        if count == 0:
            return GRASPS.empty_table()
        quaternions = rotations_to_quaternions(np.stack(self.rotation))
        return pa.table(
            {
                "model_id": pa.array([model_id] * count, pa.string()),
                "grasp_id": pa.array(np.arange(count, dtype=np.int32)),
                "task": pa.array(self.task, pa.string()),
                "position": vectors_to_arrow(np.stack(self.position)),
                "quaternion": vectors_to_arrow(quaternions, 4),
                "width": pa.array(np.asarray(self.width, dtype=np.float64)),
                "contact_a": vectors_to_arrow(np.stack(self.contact_a)),
                "contact_b": vectors_to_arrow(np.stack(self.contact_b)),
                "origin": pa.array(self.origin, pa.string()),
                "pair_index": pa.array(np.asarray(self.pair_index, dtype=np.int32)),
                "quality": pa.array(np.asarray(self.quality, dtype=np.float64)),
            },
            schema=GRASPS,
        )


def model_seed(seed: int, model_id: str) -> np.random.SeedSequence:
    """The seed of one model's random draws: the pipeline seed and the model id."""
    digest = int(hashlib.sha256(model_id.encode()).hexdigest()[:16], 16)
    return np.random.SeedSequence([int(seed) & 0xFFFFFFFFFFFFFFFF, digest])


class GraspAnnotator:
    """Turns one model's contact pairs into grasp rows.

    Parameters
    ----------
    model : ModelInput
    params : GraspsStageParams
    rules : dict of category to LabelRule
        The effective label rules.
    gripper : Gripper
    seed : int
        The pipeline seed.
    """

    def __init__(
        self,
        model: ModelInput,
        params: GraspsStageParams,
        rules: dict[str, LabelRule],
        gripper: Gripper,
        seed: int,
    ) -> None:
        self.model = model
        self.params = params
        self.rule = rules[model.category]
        self.gripper = gripper
        self.rng = np.random.default_rng(model_seed(seed, model.model_id))
        self.mesh = trimesh.Trimesh(model.vertices, model.faces, process=False)
        self.surface = ObjectSurface.sample(
            self.mesh, model.face_parts, params.surface_spacing, self.rng, params.max_surface_points
        )
        self.collision = GripperCollision(
            self.surface, convex_planes(model.convex_parts), gripper, params.collision_margin
        )
        self.notes: list[str] = []
        # Every largest clearance of the rule must be seen from the grasp centre.
        self._label_reach = float(
            np.linalg.norm(closing_region(gripper, gripper.max_opening))
            + max(self.rule.task_clearance, self.rule.hand_over_clearance)
        )

    @cached_property
    def axis(self) -> ToolAxis | None:
        """The tool's axis from its handle end to its working end (:func:`osgd.grasps.labels.tool_axis`)."""
        return tool_axis(self.mesh, self.model.face_parts, self.rule)

    @cached_property
    def _holding_parts(self) -> np.ndarray:
        """The surface samples' parts as the label rule sees them (:func:`osgd.grasps.labels.holding_parts`)."""
        return holding_parts(self.surface.parts, self.surface.points, self.axis, self.rule)

    @property
    def where(self) -> str:
        return f"model {self.model.name} ({self.model.model_id})"

    def grasps(self) -> pa.Table:
        """The model's grasps in the ``grasps`` schema; notes in :attr:`notes`."""
        rows = _Rows()
        if self.model.annotated_pairs:
            self._annotated(rows)
        else:
            self._sampled(rows)
        return rows.table(self.model.model_id)

    # -- the two sources of contact pairs ------------------------------------
    def _annotated(self, rows: _Rows) -> None:
        too_wide: dict[str, list[float]] = {}
        degenerate: dict[str, int] = {}
        blocked: dict[str, int] = {}
        for index, pair in enumerate(self.model.annotated_pairs):
            contact_a = np.asarray(pair["contact_a"], dtype=np.float64)
            contact_b = np.asarray(pair["contact_b"], dtype=np.float64)
            distance = float(np.linalg.norm(contact_b - contact_a))
            if distance < 1e-6:
                degenerate[pair["file"]] = degenerate.get(pair["file"], 0) + 1
                continue
            width = distance + self.gripper.clearance
            if width > self.gripper.max_opening:
                too_wide.setdefault(pair["file"], []).append(width)
                continue
            if not self._add_pair(
                rows, contact_a, contact_b, pair_index=index, origin=pair["file"], task=pair["task"], quality=np.nan
            ):
                blocked[pair["file"]] = blocked.get(pair["file"], 0) + 1
        for file, widths in sorted(too_wide.items()):
            self.notes.append(
                f"{self.where}: dropped {len(widths)} pair(s) of {file} wider than the gripper's "
                f"{self.gripper.max_opening:.3f} m opening (opening needed {min(widths):.3f}-{max(widths):.3f} m)"
            )
        for file, count in sorted(degenerate.items()):
            self.notes.append(f"{self.where}: dropped {count} pair(s) of {file} whose two points coincide")
        for file, count in sorted(blocked.items()):
            self.notes.append(f"{self.where}: {count} pair(s) of {file} have no collision-free approach")

    def _sampled(self, rows: _Rows) -> None:
        params = self.params
        pairs = sample_pairs(
            self.mesh,
            self.rng,
            params.sampler_points,
            friction=params.friction,
            max_distance=self.gripper.max_opening - self.gripper.clearance,
        )
        pairs = pairs.take(thin_pairs(pairs, params.thin_distance, params.thin_angle))
        pairs = pairs.take(spread_order(pairs))
        kept = 0
        for index in range(len(pairs)):
            if kept >= params.sampler_max_pairs:
                break
            if self._add_pair(
                rows, pairs.contact_a[index], pairs.contact_b[index],
                pair_index=kept, origin=ANTIPODAL, task=None, quality=pairs.quality[index],
            ):
                kept += 1
        if kept == 0:
            self.notes.append(f"{self.where}: the antipodal sampler found no collision-free grasp")
        if np.all(self.model.face_parts < 0):
            self.notes.append(f"{self.where}: no part labels, every sampled grasp is labelled 'no task'")

    # -- one pair -----------------------------------------------------------
    def _add_pair(
        self,
        rows: _Rows,
        contact_a: np.ndarray,
        contact_b: np.ndarray,
        *,
        pair_index: int,
        origin: str,
        task: str | None,
        quality: float,
    ) -> bool:
        """Append the pair's collision-free grasps; False when there are none.

        ``task`` None means: label each grasp from the parts it touches.
        """
        centre = (contact_a + contact_b) / 2
        distance = float(np.linalg.norm(contact_b - contact_a))
        closing_axis = (contact_b - contact_a) / distance
        width = distance + self.gripper.clearance
        rotations = gripper_rotations(closing_axis, approach_directions(closing_axis, self.params.approach_count))
        reach = self.collision.reach(width) if task is not None else max(self.collision.reach(width), self._label_reach)
        nearby = self.surface.near(centre, reach)
        free = self.collision.free(centre, rotations, width, nearby)
        if not free.any():
            return False
        rotations = rotations[free]
        tasks = [task] * len(rotations) if task is not None else self._labels(centre, rotations, width, nearby)
        for rotation, grasp_task in zip(rotations, tasks, strict=True):
            rows.add(task=grasp_task, centre=centre, rotation=rotation, width=width, contact_a=contact_a,
                     contact_b=contact_b, origin=origin, pair_index=pair_index, quality=float(quality))
        return True

    def _labels(self, centre: np.ndarray, rotations: np.ndarray, width: float, nearby: np.ndarray) -> list[str]:
        """Task label of each gripper pose (:func:`osgd.grasps.labels.label_grasp`)."""
        local = np.abs(local_points(self.surface.points[nearby], centre, rotations))
        parts = self._holding_parts[nearby]
        position = None if self.axis is None else float(self.axis.position(centre[None])[0])
        grown = closing_region(self.gripper, width, self.params.label_margin)
        exact = closing_region(self.gripper, width)
        touched = np.all(local <= grown, axis=-1)
        # Distance of each sample to the region between the pads: (K, N).
        distance = np.linalg.norm(np.maximum(local - exact, 0.0), axis=-1)
        present = np.unique(parts)
        labels = []
        for pose in range(len(rotations)):
            part_distances = {int(part): float(distance[pose, parts == part].min()) for part in present}
            labels.append(label_grasp(self.model.category, self.rule, parts[touched[pose]], part_distances, position))
        return labels


def rules_payload(rules: dict[str, LabelRule]) -> dict[str, dict]:
    """The rules as JSON-able values, for item payloads (and so shard keys)."""
    return {category: json.loads(rule.model_dump_json()) for category, rule in rules.items()}
