"""Dense synthetic scans as a user brings them: mm, sidecar category+length."""
import sys, numpy as np, trimesh
sys.path.insert(0, "benchmarks")
from osgd.models import procedural
from osgd.models.stage import item_rng
from pathlib import Path
out = Path(sys.argv[1]); out.mkdir(parents=True, exist_ok=True)
for category, edge in [("fork", 0.002), ("wrench", 0.002), ("pliers", 0.0018), ("hammer", 0.0025)]:
    g = procedural.generate(category, item_rng(0, f"procedural/{category}_00"))
    rng = np.random.default_rng(1)
    m = g.mesh
    v, f = trimesh.remesh.subdivide_to_size(m.vertices, m.faces, max_edge=edge, max_iter=30)
    v = v + rng.normal(0, 0.0002, v.shape)
    s = trimesh.Trimesh(v, f, process=False)
    s.apply_transform(trimesh.transformations.random_rotation_matrix(rng.random(3)))
    s.apply_scale(1000.0)
    s.export(out / f"{category}_scan.stl")
    length = float(max(m.extents))
    (out / f"{category}_scan.toml").write_text(f'category = "{category}"\nlength = {length:.4f}\n')
    print(category, len(f))
