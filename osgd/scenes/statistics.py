"""How stacked the scenes are: contacts, top-down overlap and occlusion.

The paper's point (section I) is "serious overlaps and occlusions"; these
numbers show how far the scenes have them. Everything is recomputed from the
stored poses, so the ``scenes`` table stores nothing extra:

- contacts: the posed collision compounds (:mod:`osgd.physics`) are placed
  as static bodies and pybullet's closest points within ``contact_distance``
  say which objects touch which, and which lie *on* another (the contact
  normal points up into the upper object);
- top-down overlap: an object overlaps another when their silhouettes seen
  straight from above share more than ``overlap_fraction`` of the smaller
  one (ray-cast views, :mod:`osgd.scenes.views`);
- occlusion: the share of an object's top-down silhouette hidden under
  another object.
"""

from __future__ import annotations

import atexit
import functools
import json
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from osgd.contract.shards import ShardRecord
from osgd.physics import PileWorld, pybullet_module
from osgd.scenes.views import cast_view, load_models, posed_meshes, view_scenes, with_mesh_arrays
from osgd.store import ShardStore

#: The ``models`` columns :func:`scene_statistics` reads: the bodies' and the meshes'.
STATISTICS_COLUMNS = ("model_id", "vertices", "faces", "convex_parts", "mass", "center_of_mass", "inertia",
                      "friction", "decomposition")

#: Objects closer than this touch, metres (pybullet rests bodies a fraction of a millimetre apart or in).
CONTACT_DISTANCE = 0.002
#: A contact normal steeper than this (cosine to world z) means one object lies on the other.
LYING_COSINE = 0.5
#: Silhouettes sharing more than this share of the smaller one overlap.
OVERLAP_FRACTION = 0.02
#: Top-down pixel size of the overlap and occlusion views, metres.
VIEW_PIXEL = 0.002
#: An object hidden beyond this share of its silhouette counts as occluded.
OCCLUDED_FRACTION = 0.1


@dataclass(frozen=True)
class SceneStatistics:
    """Per-scene stacking figures.

    Attributes
    ----------
    objects : int
    touching : int
        Objects in contact with at least one other object.
    lying_on : int
        Objects that lie on another object (supported from below by it).
    off_floor : int
        Objects that do not touch the floor at all.
    overlapping : int
        Objects whose top-down silhouette overlaps another's.
    occlusion : tuple of float
        Per object, the share of its top-down silhouette hidden by others.
    """

    objects: int
    touching: int
    lying_on: int
    off_floor: int
    overlapping: int
    occlusion: tuple[float, ...]


def _floor(client: int) -> list[int]:
    """A static plane at z = 0, the floor the contacts are measured against."""
    pybullet = pybullet_module()
    plane = pybullet.createCollisionShape(pybullet.GEOM_PLANE, physicsClientId=client)
    return [pybullet.createMultiBody(0, plane, physicsClientId=client)]


@functools.cache
def contacts_world() -> PileWorld:
    """This process's world for :func:`scene_contacts`: the floor, and each model's body made once.

    Loading each scene's bodies into a new client is slow; the bodies are
    made once and moved from scene to scene. Disconnected at exit.
    """
    world = PileWorld(_floor)
    atexit.register(world.close)
    return world


def scene_contacts(scene: Mapping[str, Any], models: Mapping[str, Mapping[str, Any]],
                   contact_distance: float = CONTACT_DISTANCE) -> tuple[int, int, int]:
    """Count touching, lying-on and off-the-floor objects of one scene.

    Returns
    -------
    touching, lying_on, off_floor : int
    """
    world = contacts_world()
    bodies = world.place(models, scene["objects"])
    try:
        return count_contacts(world.client, world.fixtures[0], bodies, contact_distance)
    finally:
        world.park(bodies)


def count_contacts(client: int, floor: int, bodies: list[int],
                   contact_distance: float = CONTACT_DISTANCE) -> tuple[int, int, int]:
    """Count touching, lying-on and off-the-floor bodies of a pile loaded in ``client``.

    Parameters
    ----------
    client : int
        pybullet client holding the pile and the floor.
    floor : int
        The floor's body.
    bodies : list of int
        The pile's bodies, in scene order.
    contact_distance : float
        Gap under which two bodies count as touching, metres.

    Returns
    -------
    touching, lying_on, off_floor : int
    """
    pybullet = pybullet_module()
    touching, lying_on, on_floor = set(), set(), set()
    for index, body in enumerate(bodies):
        if pybullet.getClosestPoints(body, floor, contact_distance, physicsClientId=client):
            on_floor.add(index)
        for other_index in range(index + 1, len(bodies)):
            points = pybullet.getClosestPoints(body, bodies[other_index], contact_distance, physicsClientId=client)
            if not points:
                continue
            touching.update((index, other_index))
            # contactNormalOnB points from the other body (B) towards this one (A).
            normal_z = np.mean([point[7][2] for point in points])
            if normal_z > LYING_COSINE:
                lying_on.add(index)
            elif normal_z < -LYING_COSINE:
                lying_on.add(other_index)
    return len(touching), len(lying_on), len(bodies) - len(on_floor)


def scene_statistics(scene: Mapping[str, Any], models: Mapping[str, Mapping[str, Any]]) -> SceneStatistics:
    """Every stacking figure of one ``scenes`` row (models: rows by model id)."""
    touching, lying_on, off_floor = scene_contacts(scene, models)
    meshes = posed_meshes(scene, models)
    view = cast_view(meshes, "top", pixel=VIEW_PIXEL)
    areas = view.footprints.reshape(len(meshes), -1).sum(axis=1)
    overlapping = 0
    for index in range(len(meshes)):
        shared = (view.footprints[index] & view.footprints).reshape(len(meshes), -1).sum(axis=1)
        smaller = np.maximum(np.minimum(areas, areas[index]), 1)
        others = np.arange(len(meshes)) != index
        overlapping += bool(np.any(shared[others] > OVERLAP_FRACTION * smaller[others]))
    visible = np.array([(view.object_index == index).sum() for index in range(len(meshes))])
    occlusion = tuple(float(1.0 - visible[index] / areas[index]) if areas[index] else 0.0
                      for index in range(len(meshes)))
    return SceneStatistics(len(meshes), touching, lying_on, off_floor, overlapping, occlusion)


@dataclass(frozen=True)
class StackingSummary:
    """Figures over many scenes.

    Attributes
    ----------
    scenes : int
        Scenes analysed.
    objects_per_scene : dict of int to int
        How many scenes have each object count.
    objects : int
    touching_share, lying_on_share, off_floor_share, overlapping_share, occluded_share : float
        Shares of all objects.
    mean_occlusion : float
        Mean hidden share of an object's top-down silhouette.
    """

    scenes: int
    objects_per_scene: dict[int, int]
    objects: int
    touching_share: float
    lying_on_share: float
    off_floor_share: float
    overlapping_share: float
    occluded_share: float
    mean_occlusion: float


def summarize_statistics(statistics: Sequence[SceneStatistics]) -> StackingSummary:
    """Pool per-scene figures into shares of all objects."""
    objects = sum(item.objects for item in statistics)
    occlusion = np.array([value for item in statistics for value in item.occlusion])

    def share(count: int) -> float:
        return count / objects if objects else 0.0

    return StackingSummary(
        scenes=len(statistics),
        objects_per_scene=dict(sorted(Counter(item.objects for item in statistics).items())),
        objects=objects,
        touching_share=share(sum(item.touching for item in statistics)),
        lying_on_share=share(sum(item.lying_on for item in statistics)),
        off_floor_share=share(sum(item.off_floor for item in statistics)),
        overlapping_share=share(sum(item.overlapping for item in statistics)),
        occluded_share=float(np.mean(occlusion > OCCLUDED_FRACTION)) if occlusion.size else 0.0,
        mean_occlusion=float(occlusion.mean()) if occlusion.size else 0.0,
    )


def stacking_statistics(store: ShardStore, records: Sequence[ShardRecord], limit: int | None = 200,
                        ) -> tuple[StackingSummary, dict[str, Any]]:
    """Figures of the scenes in the given shards.

    Parameters
    ----------
    store : ShardStore
    records : sequence of ShardRecord
        ``scenes`` shards.
    limit : int or None
        Analyse at most this many scenes (evenly spread) for the geometric
        figures; the simulation figures cover every scene.

    Returns
    -------
    summary : StackingSummary
    simulation : dict
        ``scenes``, ``settled``, ``mean_sim_time`` (s), ``mean_steps``,
        ``attempts``, ``rejections`` (by reason).
    """
    scenes = [row for record in records for row in store.read("scenes", record.key).to_pylist()]
    rejections: Counter = Counter()
    for row in scenes:
        rejections.update(json.loads(row["rejections"]))
    simulation = {
        "scenes": len(scenes),
        "settled": sum(row["settled"] for row in scenes),
        "mean_sim_time": float(np.mean([row["sim_time"] for row in scenes])) if scenes else 0.0,
        "mean_steps": float(np.mean([row["sim_steps"] for row in scenes])) if scenes else 0.0,
        "attempts": sum(row["attempts"] for row in scenes),
        "rejections": dict(sorted(rejections.items())),
    }
    if limit is not None and len(scenes) > limit:
        chosen = np.linspace(0, len(scenes) - 1, limit).round().astype(int)
        scenes = [scenes[index] for index in sorted(set(chosen.tolist()))]
    model_ids = {obj["model_id"] for row in scenes for obj in row["objects"]}
    models = with_mesh_arrays(load_models(store, model_ids, STATISTICS_COLUMNS)) if model_ids else {}
    try:
        summary = summarize_statistics([scene_statistics(row, models) for row in scenes])
    finally:  # the run goes on to other stages in this process: give back the meshes' scenes and bodies
        view_scenes().clear()
        contacts_world().close()
    return summary, simulation


def format_statistics(summary: StackingSummary, simulation: Mapping[str, Any]) -> str:
    """The figures as a few lines of text."""
    per_scene = ", ".join(f"{count}: {scenes}" for count, scenes in summary.objects_per_scene.items())
    rejected = ", ".join(f"{reason} {count}" for reason, count in simulation["rejections"].items()) or "none"
    return "\n".join([
        f"scenes: {simulation['scenes']} ({simulation['settled']} settled), {simulation['attempts']} attempts, "
        f"rejected: {rejected}",
        f"simulated: {simulation['mean_sim_time']:.2f} s, {simulation['mean_steps']:.0f} steps per scene on average",
        f"stacking (over {summary.scenes} scenes, {summary.objects} objects; objects per scene {per_scene}):",
        f"  touching another object {summary.touching_share:.0%}, lying on another {summary.lying_on_share:.0%}, "
        f"not touching the floor {summary.off_floor_share:.0%}",
        f"  top-down: overlapping another {summary.overlapping_share:.0%}, more than "
        f"{OCCLUDED_FRACTION:.0%} hidden {summary.occluded_share:.0%}, mean hidden share "
        f"{summary.mean_occlusion:.0%}",
    ])
