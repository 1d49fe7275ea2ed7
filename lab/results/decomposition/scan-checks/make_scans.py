"""Scan stand-ins as a user would bring them (issue #16, item 4): OBJ in millimetres, a sidecar of category and length.

For each category given, the first procedural tool of the default datasets (``procedural/<category>_00``, seed 0)
is turned, remeshed to edges of at most 2 mm and noised by 0.2 mm per axis, as ``benchmarks/bench_decomposition.py``
makes its scans; the clean tool is written too (``<category>_clean``), turned the same way. Each mesh gets a sidecar
with only ``category`` and ``length`` (its true length, m). Run from the repository root::

    python lab/results/decomposition/scan-checks/make_scans.py OUT_DIR fork,wrench,hammer,pliers
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[4] / "benchmarks"))

from osgd.kernels import pin_kernels

pin_kernels()

import numpy as np  # noqa: E402
from bench_decomposition import scans  # noqa: E402

from osgd.models import procedural  # noqa: E402
from osgd.models.parts import true_length  # noqa: E402
from osgd.models.stage import item_rng  # noqa: E402


def main(out: Path, categories: list[str]) -> None:
    """Write the clean and the scanned tool of each category, each with its sidecar, into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    for category in categories:
        generated = procedural.generate(category, item_rng(0, f"procedural/{category}_00"))
        variants = scans(generated.mesh, np.random.default_rng(1))
        for name, mesh in ((f"{category}_clean", variants["as built"][0]), (f"{category}_scan", variants["scan"][0])):
            length = float(true_length(mesh))
            in_millimetres = mesh.copy()
            in_millimetres.apply_scale(1000.0)  # as a CAD export or a scanner's
            in_millimetres.export(out / f"{name}.obj")
            (out / f"{name}.toml").write_text(f'category = "{category}"\nlength = {length:.6f}\n')
            print(f"{name}: {len(mesh.faces)} faces, length {length:.4f} m")


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2].split(","))
