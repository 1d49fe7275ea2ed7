"""Collision shapes of scanned tools: today's preset against the ``scan`` preset, in one run.

A procedural tool of each category stands in for a real one whose true
solid is known; a *scan* of it is the tool turned, remeshed to edges of at
most 2 mm and noised by 0.2 mm per axis (``bench_parts.scanned``), and a
*scan with holes* also loses 2 % of its faces at random (a sensor's blind
spots). Each mesh is decomposed by the preset ``auto`` gives a procedural
or authors' model of its category (``fast``, or ``thin`` for forks) and by
the ``scan`` preset, and
the compound is compared with the true solid on 100,000 points drawn in its
box:

- **excess**: volume inside some convex part but outside the solid, as a
  share of the solid's volume (filled concavities: between a fork's tines,
  a wrench's jaws, a hammer's claw and head);
- **missing**: volume of the solid inside no part.

Usage::

    python benchmarks/bench_decomposition.py                       # all ten categories
    python benchmarks/bench_decomposition.py --categories fork,wrench --json out.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from osgd.kernels import pin_kernels

pin_kernels()

import numpy as np  # noqa: E402
import trimesh  # noqa: E402

from osgd.contract.taxonomy import CATEGORIES  # noqa: E402
from osgd.grasps.geometry import convex_planes  # noqa: E402
from osgd.models import decomposition, procedural  # noqa: E402
from osgd.models.stage import item_rng  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_parts import SCAN_EDGE, SCAN_NOISE  # noqa: E402

#: Share of a scan's faces dropped for the variant with holes.
HOLE_SHARE = 0.02
#: Points drawn in the solid's box (grown by 5 mm) to measure the volumes.
VOLUME_POINTS = 100_000


def scans(mesh: trimesh.Trimesh, rng: np.random.Generator) -> dict[str, tuple[trimesh.Trimesh, trimesh.Trimesh]]:
    """Variant name -> (the mesh decomposed, the true solid in the same frame)."""
    transform = trimesh.transformations.random_rotation_matrix(rng.random(3))
    truth = mesh.copy()
    truth.apply_transform(transform)
    vertices, faces = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=SCAN_EDGE, max_iter=20)
    vertices = vertices + rng.normal(0.0, SCAN_NOISE, vertices.shape)
    scan = trimesh.Trimesh(vertices, faces, process=False)
    scan.apply_transform(transform)
    holes = trimesh.Trimesh(scan.vertices, scan.faces[rng.random(len(scan.faces)) > HOLE_SHARE], process=False)
    return {"as built": (truth, truth), "scan": (scan, truth), "scan with holes": (holes, truth)}


def volumes(truth: trimesh.Trimesh, parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[float, float]:
    """(excess, missing) volume of a compound against the true solid, as shares of the solid's volume."""
    rng = np.random.default_rng(0)
    low, high = truth.bounds[0] - 0.005, truth.bounds[1] + 0.005
    points = rng.uniform(low, high, (VOLUME_POINTS, 3))
    solid = truth.contains(points)
    covered = np.zeros(len(points), bool)
    for normals, offsets in convex_planes(parts):
        covered |= np.all(points @ normals.T <= offsets[None, :] + 1e-9, axis=1)
    return float((covered & ~solid).sum() / solid.sum()), float((solid & ~covered).sum() / solid.sum())


def measure(category: str) -> list[dict]:
    """Every variant of the category's tool under both presets."""
    generated = procedural.generate(category, item_rng(0, f"procedural/{category}_00"))
    category_preset = decomposition.resolve_preset("auto", category)
    rows = []
    for variant, (mesh, truth) in scans(generated.mesh, np.random.default_rng(1)).items():
        for label, preset, max_faces in ((category_preset, category_preset, 0), ("scan, whole", "scan", 0),
                                         ("scan", "scan", decomposition.SCAN_MAX_FACES)):
            start = time.perf_counter()
            result = decomposition.decompose(np.asarray(mesh.vertices), np.asarray(mesh.faces), preset,
                                             scan_max_faces=max_faces)
            seconds = time.perf_counter() - start
            excess, missing = volumes(truth, result.parts)
            rows.append({"category": category, "variant": variant, "preset": label, "faces": len(mesh.faces),
                         "hulls": len(result.parts), "excess": excess, "missing": missing, "seconds": seconds,
                         "repair": result.description.get("repair"), "notes": result.notes})
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--categories", default=",".join(CATEGORIES), help="comma-separated categories")
    parser.add_argument("--json", type=Path, help="write every row here")
    arguments = parser.parse_args()
    rows = []
    print("| category | mesh | preset | faces | hulls | excess | missing | seconds |")
    print("|---|---|---|---:|---:|---:|---:|---:|")
    for category in arguments.categories.split(","):
        for row in measure(category):
            rows.append(row)
            print(f"| {row['category']} | {row['variant']} | {row['preset']} | {row['faces']} | {row['hulls']} | "
                  f"{100 * row['excess']:.1f} % | {100 * row['missing']:.1f} % | {row['seconds']:.1f} |", flush=True)
        if arguments.json:  # after each category, so that a run stopped early keeps what it measured
            arguments.json.parent.mkdir(parents=True, exist_ok=True)
            arguments.json.write_text(json.dumps({"command": " ".join(sys.argv), "rows": rows}, indent=1))
    for variant in ("as built", "scan", "scan with holes"):
        for preset in ("category's", "scan, whole", "scan"):
            chosen = [row for row in rows if row["variant"] == variant
                      and (row["preset"] == preset or (preset == "category's" and "scan" not in row["preset"]))]
            print(f"{variant}, {preset}: median excess {100 * np.median([r['excess'] for r in chosen]):.1f} %, "
                  f"worst {100 * max(r['excess'] for r in chosen):.1f} %, "
                  f"worst missing {100 * max(r['missing'] for r in chosen):.1f} %, "
                  f"{sum(r['seconds'] for r in chosen):.0f} s for {len(chosen)} meshes")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
