"""``osgd show scene``: a pile seen from above and from the side.

Both panels are orthographic ray-cast views of the visual meshes
(:mod:`osgd.scenes.views`), one colour per object, shaded by distance so
that what lies on top reads lighter; the legend names each object's
category and model.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from osgd.scenes.statistics import scene_statistics
from osgd.scenes.views import View, cast_view, find_scene, load_models, posed_meshes
from osgd.store import ShardStore


def _shaded(view: View, colours: np.ndarray) -> np.ndarray:
    """(H, W, 3) float RGB: object colour dimmed with distance, white background."""
    image = np.ones((*view.object_index.shape, 3))
    hit = view.object_index >= 0
    if not hit.any():
        return image
    distance = view.distance[hit]
    near, far = distance.min(), distance.max()
    light = 1.0 - 0.6 * (distance - near) / max(far - near, 1e-9)
    image[hit] = colours[view.object_index[hit]] * light[:, None]
    return image


def show_scene(store: ShardStore, scene_id: str, out: str | Path) -> str:
    """Draw one scene from above and from the side into a PNG file.

    Parameters
    ----------
    store : ShardStore
    scene_id : str
        e.g. ``scene_000042``.
    out : path
        PNG to write.

    Returns
    -------
    str
        A line describing what was drawn.

    Raises
    ------
    KeyError
        If the scene or one of its models is not in the data dir.
    """
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib.patches import Patch  # noqa: PLC0415

    scene = find_scene(store, scene_id)
    models = load_models(store, {obj["model_id"] for obj in scene["objects"]},
                         ["model_id", "name", "vertices", "faces", "convex_parts", "mass", "center_of_mass",
                          "inertia", "friction"])
    meshes = posed_meshes(scene, models)
    colours = np.asarray(plt.get_cmap("tab10").colors)[np.arange(len(meshes)) % 10]
    top, side = cast_view(meshes, "top", pixel=0.001), cast_view(meshes, "side", pixel=0.001)
    statistics = scene_statistics(scene, models)

    figure, (top_axes, side_axes) = plt.subplots(
        1, 2, figsize=(11, 5.5), gridspec_kw={"width_ratios": [1.0, 1.0]}, constrained_layout=True
    )
    top_axes.imshow(_shaded(top, colours), extent=top.extent, interpolation="nearest")
    top_axes.set(title="from above (world x right, y up)", xlabel="x (m)", ylabel="y (m)")
    side_axes.imshow(_shaded(side, colours), extent=side.extent, interpolation="nearest")
    side_axes.axhline(0.0, color="0.3", linewidth=1.0)
    side_axes.set(title="from the side (world x right, z up)", xlabel="x (m)", ylabel="z (m)")
    handles = [
        Patch(color=colours[index], label=f"{index}: {mesh.category} ({models[mesh.model_id]['name']}), "
              f"{statistics.occlusion[index]:.0%} hidden")
        for index, mesh in enumerate(meshes)
    ]
    side_axes.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False)
    figure.suptitle(
        f"{scene_id}: {statistics.objects} objects, {statistics.touching} touching another, "
        f"{statistics.lying_on} lying on another, {statistics.overlapping} overlapping from above "
        f"(settled: {scene['settled']}, {scene['sim_time']:.2f} s simulated)",
        fontsize=10,
    )
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=110)
    plt.close(figure)
    return f"wrote {out} ({statistics.objects} objects)"
