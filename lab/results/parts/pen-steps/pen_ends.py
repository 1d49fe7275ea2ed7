"""The ends of the pens, per stress case: the columns from the end to 90 % of the body's size (stop), the share
of them that grow, and the largest step over the rise (lab entry 2026-12-03-pen-taper-in-steps).

Procedural pens of seed 0 (A: the tip end, B: the back) and the authors' pens as they are (A: the low end of
the axis, B: the high end) and in every generic stress case (tip and back). Run from the repository root:

    python lab/results/parts/pen-steps/pen_ends.py > lab/results/parts/pen-steps/pen_ends.txt
"""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, "benchmarks")
import parts_stress
from bench_parts import check_mesh, find_parts, item_rng, load_authors, model_halves, procedural

from osgd.models import parts

MODELS = Path("../shared/osgd-models")


def ends(mesh) -> list[tuple[int, float, float]]:
    """(stop, share of growing columns, largest step over the rise) of the low end and of the high end."""
    profiles = parts.profiles(mesh)
    size = parts._pen_size(profiles)
    body = parts._median(size, profiles.at(0.2, 0.8))
    out = []
    for values in (size, size[::-1]):
        quarter = max(len(values) // 4, 1)
        reached = np.flatnonzero(values[:quarter] >= 0.9 * body)
        stop = int(reached[0]) if len(reached) else quarter
        steps = np.diff(values[: stop + 1])
        rise = max(values[stop] - values[0], 1e-9)
        largest = steps.max() / rise if len(steps) else 0.0
        out.append((stop, np.count_nonzero(steps > 0) / max(stop, 1), largest))
    return out


def line(label: str, end: tuple[int, float, float]) -> str:
    stop, grow, jump = end
    return f"{label} stop {stop} grow {grow:.2f} jump {jump:.2f}"


def procedural_pens() -> None:
    for index in range(10):
        item = f"procedural/pen_{index:02d}"
        generated = procedural.generate("pen", item_rng(0, item))
        for variant, change in parts_stress.GENERIC.items():
            rng = parts_stress.case_rng(item, variant)
            moved = parts_stress.posed(change(generated.mesh, rng), rng)
            checked = check_mesh(moved.mesh, generated.face_parts[moved.origin], name=item)
            profiles = parts.profiles(checked.mesh)
            tip_low = np.mean(profiles.t[checked.face_parts == parts.PART_INDEX["tip"]]) < profiles.columns / 2
            low, high = ends(checked.mesh)
            tip, back = (low, high) if tip_low else (high, low)
            print(item, variant, line("A", tip), "|", line("B", back))


def authors_pens() -> None:
    halves = model_halves(MODELS)
    folders = sorted(MODELS.glob("pen_*"))
    for folder in folders:
        _, mesh, _, _ = load_authors(folder, 0)
        low, high = ends(mesh)
        print(f"{folder.name}/{halves[folder.name]}", "as-is", line("A", low), "|", line("B", high))
    print("---- authors stress")
    for folder in folders:
        _, mesh, _, _ = load_authors(folder, 0)
        tip_point = mesh.vertices[np.argmax(mesh.vertices @ find_parts(mesh, "pen").axis)]
        for variant, change in parts_stress.GENERIC.items():
            rng = parts_stress.case_rng(folder.name, variant)
            moved = parts_stress.posed(change(mesh, rng), rng)
            checked = check_mesh(moved.mesh, name=folder.name)
            frame = parts.profiles(checked.mesh).frame
            tip_high = frame.coordinates(moved.points(tip_point[None]))[0, 0] > 0
            low, high = ends(checked.mesh)
            tip, back = (high, low) if tip_high else (low, high)
            print(folder.name, halves[folder.name], variant, line("tip", tip), "|", line("back", back))


if __name__ == "__main__":
    procedural_pens()
    authors_pens()
