"""The authors' capped pen_005, scanned (the bench's *scan* stress case) at the draws where the pen's rule of
8cc0d46 found no parts (seeds 1 and 3): the automatic parts with the ends compared by their least width.

    python lab/results/parts/robust/least-width/draw_pen005.py   # writes docs/figures/parts-pen005-scan.png
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[4] / "benchmarks"))

import bench_parts  # noqa: E402
import parts_stress  # noqa: E402

from osgd.models.parts import find_parts  # noqa: E402
from osgd.models.validation import check_mesh  # noqa: E402


def main() -> None:
    folder = HERE.parents[5] / "shared" / "osgd-models" / "pen_005"
    cases = []
    for seed in (1, 3):
        category, mesh, _, _ = bench_parts.load_authors(folder, seed)
        rng = parts_stress.case_rng(folder.name, "scan")
        scanned = check_mesh(parts_stress.posed(parts_stress.scan(mesh, rng), rng).mesh, name=folder.name).mesh
        found = find_parts(scanned, category)
        records = json.loads((HERE / f"pen-seed{seed}.json").read_text())["cases"]
        agree = next(r["score"] for r in records if r["name"] == "pen_005" and r["variant"] == "scan")
        cases.append(bench_parts.Case(f"pen_005 scan, seed {seed}, pairs agree", agree, scanned, None, found))
    out = HERE.parents[4] / "docs" / "figures" / "parts-pen005-scan.png"
    print(bench_parts.draw_cases(cases, out, columns=2, panel=(5.0, 1.5)))


if __name__ == "__main__":
    main()
