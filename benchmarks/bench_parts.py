"""How well automatic parts (osgd.models.parts) agree with parts that are known.

Two references, each reported per category (docs/models.md, "Automatic parts"):

1. **Procedural tools** (osgd.models.procedural), whose faces carry the
   generator's own part labels: the automatic parts of each tool are
   compared with them, as the share of the surface area whose part agrees,
   on three versions of every tool: *as built* (the labels removed),
   *turned* (a random rotation and shift), and *scan* (turned, remeshed to
   edges of at most 2 mm and every vertex moved by Gaussian noise of 0.2 mm
   per axis, standing in for a scan).
2. **The paper authors' 75 models** (``../shared/osgd-models``), whose
   hand-made contact pairs carry their task (the file they came from: the
   category's task, or hand over). Each model is validated and scaled as the
   models stage does; each pair is labelled with the task its automatic parts
   give it: the 12 surface samples nearest to each of its two finger
   contacts vote (what the pads touch: the pair's centre lies inside the
   tool, where a screwdriver's shaft runs on inside its handle), each with
   the label ``osgd.grasps.labels.label_grasp`` gives a grasp touching its
   part (as ``holding_parts`` sees it) at the pair's place along the tool
   (``tool_axis``), clearances left out. Agreement is the share of pairs
   whose task is the file's. A pair that the authors put in both files (the
   same two contacts with both tasks: 80 of screwdriver_003's 116 pairs, 38
   of spoon_002's 56) is *ambiguous*: no label can agree with both copies,
   so these are counted apart and left out of the agreement.

Pictures of the worst cases go to ``--figures`` (PNG). Run from the
repository root::

    python benchmarks/bench_parts.py --count 10 --figures docs/figures
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path

from osgd.kernels import pin_kernels

pin_kernels()

import numpy as np  # noqa: E402
import trimesh  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

from osgd.contract.taxonomy import CATEGORIES  # noqa: E402
from osgd.grasps.labels import DEFAULT_RULES, holding_parts, label_grasp, tool_axis  # noqa: E402
from osgd.models import osgd_import, procedural  # noqa: E402
from osgd.models.categories import draw_length  # noqa: E402
from osgd.models.parts import AutomaticParts, find_parts  # noqa: E402
from osgd.models.pictures import draw_mesh, legend_handles, plt  # noqa: E402
from osgd.models.stage import item_rng  # noqa: E402
from osgd.models.validation import check_mesh  # noqa: E402

VARIANTS = ("as built", "turned", "scan")
#: Scan stand-in: longest edge after remeshing, and the noise per axis, m.
SCAN_EDGE, SCAN_NOISE = 0.002, 0.0002


def turned(mesh: trimesh.Trimesh, rng: np.random.Generator) -> trimesh.Trimesh:
    """The mesh under a random rotation and a shift of up to 10 cm."""
    transform = trimesh.transformations.random_rotation_matrix(rng.random(3))
    transform[:3, 3] = rng.uniform(-0.1, 0.1, 3)
    out = mesh.copy()
    out.apply_transform(transform)
    return out


def scanned(mesh: trimesh.Trimesh, parts: np.ndarray, rng: np.random.Generator) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Turned, remeshed to edges of at most :data:`SCAN_EDGE` and noised; the parts follow their faces."""
    vertices, faces, index = trimesh.remesh.subdivide_to_size(
        mesh.vertices, mesh.faces, max_edge=SCAN_EDGE, max_iter=20, return_index=True
    )
    vertices = vertices + rng.normal(0.0, SCAN_NOISE, vertices.shape)
    return turned(trimesh.Trimesh(vertices, faces, process=False), rng), parts[index]


def area_agreement(mesh: trimesh.Trimesh, truth: np.ndarray, found: np.ndarray) -> float:
    """Share of the surface area whose found part is the true one."""
    area = mesh.area_faces
    return float(area[truth == found].sum() / area.sum())


@dataclass
class Case:
    """One measured model, kept for the pictures of the worst cases."""

    name: str
    score: float
    mesh: trimesh.Trimesh
    truth: np.ndarray | None
    parts: AutomaticParts
    pairs: list | None = None
    agree: np.ndarray | None = None


def procedural_table(count: int, seed: int) -> tuple[dict, list[Case]]:
    """Per category and variant: the face-area agreements; and every case."""
    scores: dict[tuple[str, str], list[float]] = defaultdict(list)
    cases = []
    for category in CATEGORIES:
        for index in range(count):
            item = f"procedural/{category}_{index:02d}"
            generated = procedural.generate(category, item_rng(seed, item))
            rng = np.random.default_rng(index)
            versions = {
                "as built": (generated.mesh, generated.face_parts),
                "turned": (turned(generated.mesh, rng), generated.face_parts),
                "scan": scanned(generated.mesh, generated.face_parts, rng),
            }
            for variant, (mesh, truth) in versions.items():
                found = find_parts(mesh, category)
                score = area_agreement(mesh, truth, found.face_parts)
                scores[(category, variant)].append(score)
                cases.append(Case(f"{item} ({variant})", score, mesh, truth, found))
    return scores, cases


def pair_tasks(mesh: trimesh.Trimesh, category: str, face_parts: np.ndarray, pairs: list) -> list[str]:
    """The task the parts near each pair's contacts, and its place along the tool, give it (module text)."""
    points, faces = trimesh.sample.sample_surface_even(mesh, 20000, seed=0)
    tree = cKDTree(points)
    rule = DEFAULT_RULES[category]
    axis = tool_axis(mesh, face_parts, rule)
    parts = holding_parts(face_parts[faces], points, axis, rule)
    tasks = []
    for pair in pairs:
        centre = (pair.contact_a + pair.contact_b) / 2
        _, nearest = tree.query(np.stack([pair.contact_a, pair.contact_b]), k=12)
        position = None if axis is None else float(axis.position(centre[None])[0])
        votes = Counter(label_grasp(category, rule, np.array([part]), {}, position) for part in parts[nearest.ravel()])
        tasks.append(max(sorted(votes), key=votes.get))
    return tasks


def ambiguous_pairs(pairs: list) -> np.ndarray:
    """(N,) bool: the pairs whose two contacts (either order, to 1e-6 model units) also carry another task."""
    keys = [tuple(sorted(tuple(np.round(contact, 6)) for contact in (pair.contact_a, pair.contact_b)))
            for pair in pairs]
    tasks: dict[tuple, set[str]] = defaultdict(set)
    for key, pair in zip(keys, pairs, strict=True):
        tasks[key].add(pair.task)
    return np.array([len(tasks[key]) > 1 for key in keys], dtype=bool)


def osgd_table(models_dir: Path, seed: int) -> tuple[dict, list[Case], dict]:
    """Per (category, "task", "hand over" or "ambiguous"): [agreeing, all] pairs; the cases; the models with no
    parts found. Ambiguous pairs (:func:`ambiguous_pairs`) are counted apart and left out of a case's score."""
    counts: dict[tuple[str, str], list[int]] = defaultdict(lambda: [0, 0])
    missed: dict[str, list[str]] = defaultdict(list)
    cases = []
    for folder in osgd_import.list_model_folders(models_dir):
        model = osgd_import.load_osgd_model(folder)
        checked = check_mesh(model.mesh, name=folder.name)
        scale = draw_length(model.category, item_rng(seed, f"osgd/{folder.name}")) / float(checked.mesh.extents.max())
        mesh = checked.mesh.copy()
        mesh.apply_scale(scale)
        ambiguous = ambiguous_pairs(model.pairs)
        pairs = [pair.scaled(scale) for pair in model.pairs]
        found = find_parts(mesh, model.category)
        if not found.found:
            missed[model.category].append(folder.name)
        tasks = pair_tasks(mesh, model.category, found.face_parts, pairs)
        agree = np.array([task == pair.task for task, pair in zip(tasks, pairs, strict=True)])
        for pair, ok, both in zip(pairs, agree, ambiguous, strict=True):
            kind = "ambiguous" if both else "hand over" if pair.task == "hand over" else "task"
            counts[(model.category, kind)][0] += int(ok)
            counts[(model.category, kind)][1] += 1
        score = float(agree[~ambiguous].mean()) if (~ambiguous).any() else float("nan")
        cases.append(Case(folder.name, score, mesh, None, found, pairs, agree))
    return counts, cases, missed


def draw_case(axes, case: Case, parts: np.ndarray | None = None, title: str = "") -> None:
    """One model coloured by part (its automatic parts by default), with its pairs: green agree, red do not."""
    view = draw_mesh(axes, case.mesh.vertices, case.mesh.faces, case.parts.face_parts if parts is None else parts)
    for pair, agree in zip(case.pairs or [], case.agree if case.agree is not None else [], strict=False):
        ends = view.project(np.array([pair.contact_a, pair.contact_b]))
        axes.plot(ends[:, 0], ends[:, 1], color="green" if agree else "red", linewidth=1.2)
        centre = "white" if pair.task == "hand over" else "black"
        axes.plot(*ends.mean(axis=0), marker="o", markersize=2.5, color=centre)
    axes.set_title(title or f"{case.name}: {case.score:.0%}, confidence {case.parts.confidence:.2f}", fontsize=7)


def draw_cases(
    cases: list[Case], out: Path, columns: int = 3, truth: bool = False, panel: tuple[float, float] = (3.2, 2.2)
) -> str:
    """A grid of cases (with the true parts beside the automatic ones when ``truth``)."""
    panels = [(case, None, "") for case in cases]
    if truth:
        panels = [panel for case in cases for panel in (
            (case, case.truth, f"{case.name}: generator's parts"),
            (case, None, f"automatic: {case.score:.1%} of the area agrees"),
        )]
    rows = -(-len(panels) // columns)
    size = (panel[0] * columns, panel[1] * rows + 0.5)
    figure, grid = plt.subplots(rows, columns, figsize=size, dpi=100, squeeze=False)
    for axes, (case, parts, title) in zip(grid.flat, panels, strict=False):
        draw_case(axes, case, parts, title)
    for axes in grid.flat[len(panels):]:
        axes.axis("off")
    seen = {int(p) for case, parts, _ in panels for p in np.unique(case.parts.face_parts if parts is None else parts)}
    figure.legend(handles=legend_handles(seen), loc="lower center", ncol=11, fontsize=7)
    figure.tight_layout(rect=(0, 0.4 / size[1], 1, 1))
    figure.savefig(out)
    plt.close(figure)
    return f"wrote {out}"


def worst_figures(procedural_cases: list[Case], osgd_cases: list[Case], folder: Path) -> list[str]:
    """Pictures of the worst cases: the 4 lowest procedural tools and the 6 lowest authors' models."""
    folder.mkdir(parents=True, exist_ok=True)
    lines = []
    if procedural_cases:
        worst = sorted(procedural_cases, key=lambda case: case.score)[:4]
        lines.append(draw_cases(worst, folder / "parts-worst-procedural.png", columns=2, truth=True, panel=(6.0, 1.6)))
    if osgd_cases:
        worst = sorted((case for case in osgd_cases if not np.isnan(case.score)), key=lambda case: case.score)[:6]
        lines.append(draw_cases(worst, folder / "parts-worst-osgd.png", columns=2, panel=(6.0, 2.6)))
    return lines


def print_procedural(scores: dict) -> None:
    print("\nprocedural tools: face-area agreement with the generator's parts, mean (lowest)")
    print("| category | " + " | ".join(VARIANTS) + " |")
    print("| --- |" + " ---: |" * len(VARIANTS))
    for category in CATEGORIES:
        cells = [f"{np.mean(scores[(category, v)]):.1%} ({np.min(scores[(category, v)]):.1%})" for v in VARIANTS]
        print(f"| {category} | " + " | ".join(cells) + " |")
    overall = [f"{np.mean([s for (c, v), ss in scores.items() if v == var for s in ss]):.1%}" for var in VARIANTS]
    print("| all | " + " | ".join(overall) + " |")


def print_osgd(counts: dict, missed: dict, cases: list[Case]) -> None:
    print("\nauthors' models: pairs given the task of their file by the automatic parts, per category")
    print("| category | models | pairs | agree | category-task pairs | hand-over pairs | ambiguous (left out) "
          "| parts not found |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |")

    def share(agree: int, total: int) -> str:
        return f"{agree / total:.1%} of {total}" if total else "-"

    for category in (*CATEGORIES, None):
        keys = [(c, k) for c in ([category] if category else CATEGORIES) for k in ("task", "hand over")]
        agree = sum(counts[key][0] for key in keys)
        total = sum(counts[key][1] for key in keys)
        task = [sum(counts[key][i] for key in keys if key[1] == "task") for i in (0, 1)]
        hand = [sum(counts[key][i] for key in keys if key[1] == "hand over") for i in (0, 1)]
        ambiguous = sum(counts[(c, "ambiguous")][1] for c in ([category] if category else CATEGORIES))
        models = sum(1 for case in cases if category is None or case.name.rsplit("_", 1)[0] == category)
        not_found = ", ".join(missed[category]) if category else str(sum(len(v) for v in missed.values()))
        print(f"| {category or 'all'} | {models} | {total} | {agree / max(total, 1):.1%} | {share(*task)} | "
              f"{share(*hand)} | {ambiguous or '-'} | {not_found or '-'} |")
    print("\nper model: agreement, confidence")
    print(", ".join(f"{case.name} {case.score:.0%} ({case.parts.confidence:.2f})" for case in cases))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=10, help="procedural tools per category")
    parser.add_argument("--seed", type=int, default=0, help="pipeline seed of the tools and of the OSGD lengths")
    parser.add_argument("--osgd-dir", type=Path, default=Path("../shared/osgd-models"))
    parser.add_argument("--figures", type=Path, default=None, help="folder for pictures of the worst cases")
    parser.add_argument("--skip-procedural", action="store_true")
    parser.add_argument("--sheet", type=Path, default=None, help="PNG of every authors' model with its pairs")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    procedural_cases: list[Case] = []
    osgd_cases: list[Case] = []
    if not args.skip_procedural:
        scores, procedural_cases = procedural_table(args.count, args.seed)
        print_procedural(scores)
    if args.osgd_dir.is_dir():
        counts, osgd_cases, missed = osgd_table(args.osgd_dir, args.seed)
        print_osgd(counts, missed, osgd_cases)
    else:
        print(f"\n{args.osgd_dir}: not there, the authors' models are left out")
    if args.figures:
        for line in worst_figures(procedural_cases, osgd_cases, args.figures):
            print(line)
    if args.sheet and osgd_cases:
        print(draw_cases(sorted(osgd_cases, key=lambda case: case.name), args.sheet, columns=8))
    print(f"\n{time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
