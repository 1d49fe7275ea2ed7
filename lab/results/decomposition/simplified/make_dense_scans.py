"""Dense scan stand-ins as a user brings them: a procedural fork, wrench, pliers and hammer (seed 0) remeshed to
1.8-2.5 mm edges (33,000-166,000 faces), noised by 0.2 mm, turned at random, in millimetres, each with a sidecar of
category and length alone.

    python lab/results/decomposition/simplified/make_dense_scans.py OUT_DIR
"""

import sys
from pathlib import Path

import numpy as np
import trimesh

from osgd.models import procedural
from osgd.models.stage import item_rng

EDGES = {"fork": 0.002, "wrench": 0.002, "pliers": 0.0018, "hammer": 0.0025}


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for category, edge in EDGES.items():
        mesh = procedural.generate(category, item_rng(0, f"procedural/{category}_00")).mesh
        rng = np.random.default_rng(1)
        vertices, faces = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=edge, max_iter=30)
        scan = trimesh.Trimesh(vertices + rng.normal(0, 0.0002, vertices.shape), faces, process=False)
        scan.apply_transform(trimesh.transformations.random_rotation_matrix(rng.random(3)))
        scan.apply_scale(1000.0)
        scan.export(out / f"{category}_scan.stl")
        (out / f"{category}_scan.toml").write_text(f'category = "{category}"\nlength = {max(mesh.extents):.4f}\n')
        print(category, len(faces))


if __name__ == "__main__":
    main(Path(sys.argv[1]))
