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

Both are then measured as *held-out data* (docs/models.md, "Agreement on
held-out models and stress cases"):

3. **A fixed split of the authors' models** into a *tuned* half and a
   *held-out* half, per category (:func:`half`): a change of the rules is
   made looking at the tuned half alone and judged on the held-out half.
4. **Stress cases** (``benchmarks/parts_stress.py``), each in a random pose:
   every authors' model and procedural tool scaled non-uniformly, remeshed,
   decimated, noised and holed (and all of it at once, *scan*); the
   authors' pliers seen edge-on (thickened across their thin axis); procedural
   pliers closed, open and edge-on, knives with a long blade or a long
   handle, spoons with a shallow or a deep bowl. The authors' pairs move with
   their mesh; the generator's labels follow their faces.

The default run is short (3 procedural tools per category, stress cases on
2 tools per category and one generic case per authors' model in turn, plus
the authors' pliers edge-on: 4-5 minutes on 2 cores, 9 under load);
``--full`` runs 10 tools and every case of every model (8 per authors'
model; more than 30 minutes on 2 cores shared with other jobs), and
``--stress-categories`` limits the stress cases to some categories. Pictures of the worst cases go to
``--figures`` (PNG), the figures as JSON to ``--json``. Run from the
repository root::

    python benchmarks/bench_parts.py --full --workers 2 --json lab/results/parts/heldout.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import multiprocessing
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
from osgd.models.validation import ModelRejected, check_mesh  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import parts_stress  # noqa: E402

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
    ambiguous: np.ndarray | None = None


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


def half(name: str, names: list[str]) -> str:
    """``"held-out"`` or ``"tuned"``: the fixed split of the authors' models of one category.

    The models of a category are ranked by the sha256 of their folder name (``hammer_001``); the first
    ``len(names) // 2`` are held out, the others (one more where the count is odd) are the tuned half.
    """
    ranked = sorted(names, key=lambda other: hashlib.sha256(other.encode()).hexdigest())
    return "held-out" if ranked.index(name) < len(names) // 2 else "tuned"


def model_halves(models_dir: Path) -> dict[str, str]:
    """The half (:func:`half`) of every authors' model, by folder name."""
    folders = [folder.name for folder in osgd_import.list_model_folders(models_dir)]
    by_category: dict[str, list[str]] = defaultdict(list)
    for name in folders:
        by_category[name.rsplit("_", 1)[0]].append(name)
    return {name: half(name, by_category[name.rsplit("_", 1)[0]]) for name in folders}


def load_authors(folder: Path, seed: int) -> tuple[str, trimesh.Trimesh, list, np.ndarray]:
    """An authors' model validated and scaled as the models stage does: category, mesh (m), pairs (m), and
    which pairs are ambiguous (:func:`ambiguous_pairs`)."""
    model = osgd_import.load_osgd_model(folder)
    checked = check_mesh(model.mesh, name=folder.name)
    scale = draw_length(model.category, item_rng(seed, f"osgd/{folder.name}")) / float(checked.mesh.extents.max())
    mesh = checked.mesh.copy()
    mesh.apply_scale(scale)
    return model.category, mesh, [pair.scaled(scale) for pair in model.pairs], ambiguous_pairs(model.pairs)


def osgd_table(models_dir: Path, seed: int) -> tuple[dict, list[Case], dict]:
    """Per (category, "task", "hand over" or "ambiguous"): [agreeing, all] pairs; the cases; the models with no
    parts found. Ambiguous pairs (:func:`ambiguous_pairs`) are counted apart and left out of a case's score."""
    counts: dict[tuple[str, str], list[int]] = defaultdict(lambda: [0, 0])
    missed: dict[str, list[str]] = defaultdict(list)
    cases = []
    for folder in osgd_import.list_model_folders(models_dir):
        category, mesh, pairs, ambiguous = load_authors(folder, seed)
        found = find_parts(mesh, category)
        if not found.found:
            missed[category].append(folder.name)
        tasks = pair_tasks(mesh, category, found.face_parts, pairs)
        agree = np.array([task == pair.task for task, pair in zip(tasks, pairs, strict=True)])
        for pair, ok, both in zip(pairs, agree, ambiguous, strict=True):
            kind = "ambiguous" if both else "hand over" if pair.task == "hand over" else "task"
            counts[(category, kind)][0] += int(ok)
            counts[(category, kind)][1] += 1
        score = float(agree[~ambiguous].mean()) if (~ambiguous).any() else float("nan")
        cases.append(Case(folder.name, score, mesh, None, found, pairs, agree, ambiguous))
    return counts, cases, missed


# -- stress cases ----------------------------------------------------------------------------------------


def _record(kind: str, name: str, category: str, variant: str, agree: int, total: int, found, **extra) -> dict:
    """One measured case: ``agree`` of ``total`` pairs (authors') or area shares x 1e6 (procedural)."""
    return {"kind": kind, "name": name, "category": category, "variant": variant, "agree": int(agree),
            "total": int(total), "score": agree / total if total else float("nan"),
            "confidence": float(found.confidence) if found is not None else 0.0,
            "found": bool(found.found) if found is not None else False, **extra}


def authors_stress(job: tuple[Path, int, str, tuple[str, ...]]) -> list[dict]:
    """The stress cases of one authors' model: per case, its pairs given the task of their file (ambiguous left
    out) on the changed mesh, after the models stage's validation."""
    folder, seed, model_half, variants = job
    category, mesh, pairs, ambiguous = load_authors(folder, seed)
    pairs = [pair for pair, both in zip(pairs, ambiguous, strict=True) if not both]
    changes = {**parts_stress.GENERIC, **{name: (lambda m, r, f=f: f(m)) for name, f in
                                            parts_stress.AUTHORS_EXTRA.get(category, {}).items()}}
    records = []
    for variant in variants:
        if variant not in changes:
            continue
        rng = parts_stress.case_rng(folder.name, variant)
        change = parts_stress.posed(changes[variant](mesh, rng), rng)
        try:
            checked = check_mesh(change.mesh, name=folder.name)
        except ModelRejected:
            records.append(_record("authors", folder.name, category, variant, 0, len(pairs), None, half=model_half))
            continue
        moved = [type(pair)(pair.task, *change.points(np.stack([pair.contact_a, pair.contact_b])), pair.file)
                 for pair in pairs]
        found = find_parts(checked.mesh, category)
        tasks = pair_tasks(checked.mesh, category, found.face_parts, moved)
        agree = sum(task == pair.task for task, pair in zip(tasks, moved, strict=True))
        records.append(_record("authors", folder.name, category, variant, agree, len(moved), found, half=model_half))
    return records


def procedural_stress(job: tuple[str, int, int, tuple[str, ...]]) -> list[dict]:
    """The stress cases of one procedural tool: the face-area agreement with the generator's parts (following
    their faces), after the models stage's validation."""
    category, index, seed, variants = job
    item = f"procedural/{category}_{index:02d}"
    generated = procedural.generate(category, item_rng(seed, item))
    changes = {**parts_stress.GENERIC, **{name: (lambda m, r, f=f: f(m, generated.face_parts)) for name, f in
                                            parts_stress.PROCEDURAL.get(category, {}).items()}}
    records = []
    for variant in variants:
        if variant not in changes:
            continue
        rng = parts_stress.case_rng(item, variant)
        change = parts_stress.posed(changes[variant](generated.mesh, rng), rng)
        checked = check_mesh(change.mesh, generated.face_parts[change.origin], name=item)
        found = find_parts(checked.mesh, category)
        score = area_agreement(checked.mesh, checked.face_parts, found.face_parts)
        records.append(_record("procedural", item, category, variant, round(score * 1e6), 10**6, found))
    return records


def stress_jobs(
    models_dir: Path | None, halves: dict[str, str], seed: int, count: int, full: bool
) -> tuple[list, list]:
    """The jobs of :func:`authors_stress` and :func:`procedural_stress`.

    Full: every case of every authors' model, ``count`` procedural tools per category with every case. Quick:
    one generic case per authors' model (in turn) and its category's own cases on pliers; ``count`` tools.
    """
    generic = tuple(parts_stress.GENERIC)
    authors = []
    if models_dir is not None:
        for number, folder in enumerate(osgd_import.list_model_folders(models_dir)):
            extra = tuple(parts_stress.AUTHORS_EXTRA.get(folder.name.rsplit("_", 1)[0], {}))
            variants = (*generic, *extra) if full else (generic[number % len(generic)], *extra)
            authors.append((folder, seed, halves[folder.name], variants))
    tools = [(category, index, seed, (*generic, *parts_stress.PROCEDURAL.get(category, {})))
             for category in CATEGORIES for index in range(count)]
    return authors, tools


def run_jobs(function, jobs: list, workers: int) -> list[dict]:
    """``function`` over ``jobs`` (in ``workers`` processes when more than one), flattened in job order."""
    if workers > 1:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            results = pool.map(function, jobs, chunksize=1)
    else:
        results = [function(job) for job in jobs]
    return [record for result in results for record in result]


def _pooled(records: list[dict]) -> str:
    """Share of agreeing pairs (authors') or mean area agreement (procedural), with the lowest case."""
    if not records:
        return "-"
    if records[0]["kind"] == "authors":
        share = sum(r["agree"] for r in records) / max(sum(r["total"] for r in records), 1)
    else:
        share = float(np.mean([r["score"] for r in records]))
    return f"{share:.1%} ({min(r['score'] for r in records):.0%})"


def pooled_share(records: list[dict]) -> float | None:
    """The figure of :func:`_pooled` as a number (None without records)."""
    if not records:
        return None
    if records[0]["kind"] == "authors":
        return sum(r["agree"] for r in records) / max(sum(r["total"] for r in records), 1)
    return float(np.mean([r["score"] for r in records]))


def halves_records(cases: list[Case], halves: dict[str, str]) -> list[dict]:
    """The authors' models as they are (:func:`osgd_table`'s cases) as records of :func:`_record`."""
    records = []
    for case in cases:
        kept = ~case.ambiguous
        records.append(_record("authors", case.name, case.name.rsplit("_", 1)[0], "as is",
                               int(case.agree[kept].sum()), int(kept.sum()), case.parts, half=halves[case.name]))
    return records


def print_halves(records: list[dict]) -> dict:
    """Table: the authors' models as they are, tuned half and held-out half apart; returns its figures."""
    print("\nauthors' models, tuned half and held-out half (benchmarks/bench_parts.py::half): pairs given the task "
          "of their file, ambiguous pairs left out (lowest model)")
    print("| category | tuned: models | tuned | held-out: models | held-out | parts not found (held-out) |")
    print("| --- | ---: | ---: | ---: | ---: | --- |")
    figures = {}
    for category in (*CATEGORIES, None):
        chosen = [r for r in records if category is None or r["category"] == category]
        tuned = [r for r in chosen if r["half"] == "tuned"]
        held = [r for r in chosen if r["half"] == "held-out"]
        missed = ", ".join(r["name"] for r in held if not r["found"]) or "-"
        print(f"| {category or 'all'} | {len(tuned)} | {_pooled(tuned)} | {len(held)} | {_pooled(held)} | {missed} |")
        figures[category or "all"] = {"tuned": pooled_share(tuned), "held-out": pooled_share(held),
                                      "tuned_models": len(tuned), "held_out_models": len(held)}
    return figures


def print_stress(records: list[dict], title: str, by_half: bool) -> dict:
    """Table: per category, the stress cases pooled (by half for the authors') and per case; the worst cases."""
    variants = list(dict.fromkeys(r["variant"] for r in records))
    generic = [v for v in variants if v in parts_stress.GENERIC]
    own = [v for v in variants if v not in parts_stress.GENERIC]
    print(f"\n{title}")
    heads = (["tuned", "held-out"] if by_half else ["all cases"]) + generic + (["own cases"] if own else [])
    print("| category | " + " | ".join(heads) + " |")
    print("| --- |" + " ---: |" * len(heads))
    figures = {}
    for category in (*CATEGORIES, None):
        chosen = [r for r in records if category is None or r["category"] == category]
        groups = ([[r for r in chosen if r["half"] == h] for h in ("tuned", "held-out")] if by_half else [chosen])
        groups += [[r for r in chosen if r["variant"] == v] for v in generic]
        if own:
            groups.append([r for r in chosen if r["variant"] in own])
        print(f"| {category or 'all'} | " + " | ".join(_pooled(group) for group in groups) + " |")
        figures[category or "all"] = dict(zip(heads, (pooled_share(group) for group in groups), strict=True))
    for variant in own:
        chosen = [r for r in records if r["variant"] == variant]
        category = chosen[0]["category"]
        print(f"  {category}, {variant}: {_pooled(chosen)} over {len(chosen)} cases")
        figures[f"{category}, {variant}"] = pooled_share(chosen)
    worst = sorted(records, key=lambda r: r["score"])[:12]
    print("  lowest: " + ", ".join(f"{r['name']} ({r['variant']}) {r['score']:.0%} "
                                   f"(confidence {r['confidence']:.2f})" for r in worst))
    return figures


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


def main(argv: list[str] | None = None) -> int:  # noqa: PLR0915
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=None,
                        help="procedural tools per category (default 3; 10 with --full)")
    parser.add_argument("--stress-count", type=int, default=None,
                        help="procedural tools per category in the stress cases (default 2; 10 with --full)")
    parser.add_argument("--full", action="store_true", help="every stress case on every model (about 12 min)")
    parser.add_argument("--workers", type=int, default=1, help="processes for the stress cases")
    parser.add_argument("--seed", type=int, default=0, help="pipeline seed of the tools and of the OSGD lengths")
    parser.add_argument("--osgd-dir", type=Path, default=Path("../shared/osgd-models"))
    parser.add_argument("--figures", type=Path, default=None, help="folder for pictures of the worst cases")
    parser.add_argument("--json", type=Path, default=None, help="write the figures and every case here (JSON)")
    parser.add_argument("--skip-procedural", action="store_true")
    parser.add_argument("--skip-stress", action="store_true")
    parser.add_argument("--stress-categories", default="", help="comma-separated: stress cases of these alone")
    parser.add_argument("--sheet", type=Path, default=None, help="PNG of every authors' model with its pairs")
    args = parser.parse_args(argv)
    logging.getLogger("trimesh").setLevel(logging.ERROR)  # "only got N/20000 samples" on thin meshes
    count = args.count if args.count is not None else (10 if args.full else 3)
    stress_count = args.stress_count if args.stress_count is not None else (10 if args.full else 2)
    start = time.perf_counter()
    procedural_cases: list[Case] = []
    osgd_cases: list[Case] = []
    report: dict = {"command": " ".join(["python benchmarks/bench_parts.py", *(argv or sys.argv[1:])]),
                    "procedural_count": count, "stress_count": stress_count, "full": args.full}
    if not args.skip_procedural:
        scores, procedural_cases = procedural_table(count, args.seed)
        print_procedural(scores)
        report["procedural"] = {f"{c}, {v}": float(np.mean(ss)) for (c, v), ss in scores.items()}
    halves: dict[str, str] = {}
    records: list[dict] = []
    models_dir = args.osgd_dir if args.osgd_dir.is_dir() else None
    if models_dir is not None:
        halves = model_halves(models_dir)
        counts, osgd_cases, missed = osgd_table(models_dir, args.seed)
        print_osgd(counts, missed, osgd_cases)
        records += halves_records(osgd_cases, halves)
        report["halves"] = print_halves(records)
    else:
        print(f"\n{args.osgd_dir}: not there, the authors' models are left out")
    if not args.skip_stress:
        authors_jobs, tool_jobs = stress_jobs(models_dir, halves, args.seed, stress_count, args.full)
        if args.stress_categories:
            chosen = set(args.stress_categories.split(","))
            authors_jobs = [job for job in authors_jobs if job[0].name.rsplit("_", 1)[0] in chosen]
            tool_jobs = [job for job in tool_jobs if job[0] in chosen]
        authors = run_jobs(authors_stress, authors_jobs, args.workers)
        if authors:
            report["authors_stress"] = print_stress(
                authors, "stress cases of the authors' models (each in a random pose): pairs given the task of "
                "their file, pooled (lowest case)", by_half=True)
        tools = [] if args.skip_procedural else run_jobs(procedural_stress, tool_jobs, args.workers)
        if tools:
            report["procedural_stress"] = print_stress(
                tools, "stress cases of the procedural tools (each in a random pose): face-area agreement with the "
                "generator's parts, mean (lowest case)", by_half=False)
        records += authors + tools
    if args.figures:
        for line in worst_figures(procedural_cases, osgd_cases, args.figures):
            print(line)
    if args.sheet and osgd_cases:
        print(draw_cases(sorted(osgd_cases, key=lambda case: case.name), args.sheet, columns=8))
    seconds = time.perf_counter() - start
    print(f"\n{seconds:.0f} s")
    if args.json:
        report.update(seconds=round(seconds, 1), cases=records)
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=1, default=float) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
