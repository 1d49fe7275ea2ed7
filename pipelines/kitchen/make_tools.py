"""Meshes of the kitchen taxonomy's tools, with their sidecars: a user's folder of the models stage.

    python pipelines/kitchen/make_tools.py data/kitchen-tools [--count 3] [--seed 0]

writes ``count`` mugs, scissors and whisks (``pipelines/kitchen/taxonomy.toml``), each a binary PLY in
metres built with trimesh (``scale = 1``), with its sidecar (``docs/models.md``, "Users' meshes and the sidecar"); each
category takes its parts from another source:

- **mug** (a hollow wall, a bottom and a handle): a part label file, ``<name>.parts.npy``, one label per face;
- **whisk** (a handle and four wire loops): a half-space region for the wires, ``default_part`` handle;
- **scissors** (closed blades, a pivot and two finger loops): none; the taxonomy's elongated rule finds them.

Sizes are drawn uniformly from the ranges below (metres), so that no two tools are the same; the same
seed writes the same bytes. Tool axes run along x, from the handle end.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np
import shapely.geometry
import trimesh

#: Sections of the round parts (faces around a circle), enough for a depth image at 0.5 m.
SECTIONS = 32


def _ring(major: float, minor: float, stretch: float = 1.0) -> trimesh.Trimesh:
    """A torus in the xy plane about the origin, stretched along x (an elliptic loop of round wire)."""
    ring = trimesh.creation.torus(major_radius=major, minor_radius=minor, major_sections=SECTIONS,
                                  minor_sections=12)
    ring.apply_scale([stretch, 1.0, 1.0])
    return ring


def _labelled(*pieces: tuple[trimesh.Trimesh, int]) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The pieces as one mesh, and the label of each face (the piece's)."""
    mesh = trimesh.util.concatenate([piece for piece, _ in pieces])
    labels = np.concatenate([np.full(len(piece.faces), label, dtype=np.int64) for piece, label in pieces])
    return mesh, labels


def mug(rng: np.random.Generator) -> tuple[trimesh.Trimesh, np.ndarray]:
    """A mug standing on z = 0: labels 0 body (wall and bottom), 1 handle."""
    radius, height, wall = rng.uniform(0.036, 0.045), rng.uniform(0.085, 0.105), rng.uniform(0.004, 0.006)
    body = trimesh.creation.annulus(r_min=radius - wall, r_max=radius, height=height, sections=SECTIONS)
    body.apply_translation([0.0, 0.0, height / 2])
    bottom = trimesh.creation.cylinder(radius=radius - wall * 0.5, height=wall, sections=SECTIONS)
    bottom.apply_translation([0.0, 0.0, wall / 2])
    # The handle: half an elliptic loop, 4.8-5.6 cm tall and 8-11 mm thick, standing 2.5-3.6 cm proud of the wall
    # (its centre line): room for a gripper's fingers, which reach 2.25 cm past the grasp centre.
    span = rng.uniform(0.024, 0.028)  # half the handle's height
    handle = _ring(span, rng.uniform(0.004, 0.0055), stretch=rng.uniform(1.25, 1.45))
    handle = handle.slice_plane([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], cap=True)  # the outer half of the loop
    handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1.0, 0.0, 0.0]))
    handle.apply_translation([radius - wall, 0.0, height * rng.uniform(0.5, 0.58)])
    return _labelled((body, 0), (bottom, 0), (handle, 1))


def whisk(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    """A whisk along +x: the handle from x = 0, four wire loops beyond it; returns the handle's length too."""
    handle_length, handle_radius = rng.uniform(0.10, 0.13), rng.uniform(0.010, 0.013)
    handle = trimesh.creation.cylinder(radius=handle_radius, height=handle_length, sections=SECTIONS)
    handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0.0, 1.0, 0.0]))
    handle.apply_translation([handle_length / 2, 0.0, 0.0])
    width, reach, wire = rng.uniform(0.025, 0.035), rng.uniform(0.12, 0.16), rng.uniform(0.0012, 0.0018)
    loops = []
    for turn in np.arange(4) * np.pi / 4:
        loop = _ring(width, wire, stretch=reach / 2 / width)
        loop.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1.0, 0.0, 0.0]))
        loop.apply_transform(trimesh.transformations.rotation_matrix(turn, [1.0, 0.0, 0.0]))
        loop.apply_translation([handle_length - 0.01 + reach / 2, 0.0, 0.0])
        loops.append(loop)
    return trimesh.util.concatenate([handle, *loops]), handle_length


def scissors(rng: np.random.Generator) -> trimesh.Trimesh:
    """Closed scissors lying flat, blades along +x from the pivot at x = 0, finger loops behind it."""
    blade_length, blade_width, thickness = rng.uniform(0.08, 0.11), rng.uniform(0.014, 0.02), rng.uniform(0.003, 0.004)
    outline = shapely.geometry.Polygon([(0.0, -blade_width / 2), (blade_length, -0.001), (blade_length, 0.001),
                                        (0.0, blade_width / 2)])
    blades = trimesh.creation.extrude_polygon(outline, thickness)
    pivot = trimesh.creation.cylinder(radius=blade_width * 0.6, height=thickness * 1.6, sections=SECTIONS)
    pivot.apply_translation([0.0, 0.0, thickness / 2])
    loop_radius, wire = rng.uniform(0.011, 0.015), rng.uniform(0.003, 0.004)
    behind = rng.uniform(0.05, 0.065)
    pieces = [blades, pivot]
    for side in (-1.0, 1.0):
        loop = _ring(loop_radius, wire, stretch=rng.uniform(1.2, 1.5))
        loop.apply_translation([-behind, side * (loop_radius + wire) * 0.95, thickness / 2])
        shank = trimesh.creation.box([behind - loop_radius, wire * 1.6, thickness])
        shank.apply_translation([-(behind - loop_radius) / 2, side * loop_radius * 0.4, thickness / 2])
        pieces += [loop, shank]
    return trimesh.util.concatenate(pieces)


def _write(folder: Path, name: str, mesh: trimesh.Trimesh, sidecar: str) -> None:
    mesh.export(folder / f"{name}.ply", file_type="ply", encoding="binary")
    (folder / f"{name}.toml").write_text(sidecar, encoding="utf-8")


def _mug_files(folder: Path, name: str, rng: np.random.Generator) -> None:
    mesh, labels = mug(rng)
    np.save(folder / f"{name}.parts.npy", labels, allow_pickle=False)
    _write(folder, name, mesh, f'category = "mug"\nscale = 1.0\n\n[part_labels]\n'
                               f'file = "{name}.parts.npy"\nnames = ["body", "handle"]\n')


def _whisk_files(folder: Path, name: str, rng: np.random.Generator) -> None:
    mesh, handle_length = whisk(rng)
    _write(folder, name, mesh, f'category = "whisk"\nscale = 1.0\ndefault_part = "handle"\n\n'
                               f'[[parts]]\npart = "wires"\nhalf_space = {{ point = [{handle_length:.4f}, 0.0, 0.0], '
                               'normal = [1.0, 0.0, 0.0] }\n')


def _scissors_files(folder: Path, name: str, rng: np.random.Generator) -> None:
    mesh = scissors(rng)
    _write(folder, name, mesh, 'category = "scissors"\nscale = 1.0\n')


#: Each category's writer.
WRITERS: dict[str, Callable[[Path, str, np.random.Generator], None]] = {
    "mug": _mug_files, "whisk": _whisk_files, "scissors": _scissors_files,
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="where the meshes and sidecars go (created)")
    parser.add_argument("--count", type=int, default=3, help="tools per category (default 3)")
    parser.add_argument("--seed", type=int, default=0, help="the seed of the sizes (default 0)")
    args = parser.parse_args()
    args.folder.mkdir(parents=True, exist_ok=True)
    for offset, (category, write) in enumerate(WRITERS.items()):
        rng = np.random.default_rng([args.seed, offset])
        for index in range(args.count):
            write(args.folder, f"{category}_{index:02d}", rng)
    print(f"{args.folder}: {args.count} each of {', '.join(WRITERS)}")


if __name__ == "__main__":
    main()
