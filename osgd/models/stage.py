"""The models stage: every object that can enter a scene, at real size.

One work item per model, from any mix of three sources:

- ``procedural``: :mod:`osgd.models.procedural`, ``procedural_per_category``
  variants of each category (item ids ``procedural/hammer_03``);
- ``osgd``: the paper authors' models in the OSGD layout under ``osgd_dir``
  (item ids ``osgd/hammer_001``), see :mod:`osgd.models.osgd_import`;
- ``user``: meshes with a TOML sidecar under ``user_dir`` (item ids
  ``user/<file stem>``), see :mod:`osgd.models.user`.

Each model is validated and repaired (:mod:`osgd.models.validation`), scaled
to metres (OSGD models to a length drawn from the category's real-size range
with an rng seeded from the pipeline seed and the item id, so adding a model
never changes the others), decomposed into convex parts (cached,
:mod:`osgd.models.decomposition`) and given mass properties and friction
(:mod:`osgd.models.mass`, :mod:`osgd.models.categories`). A user's mesh is
scaled by its true length (the longest side of its oriented bounding box) and
the faces its sidecar's regions leave unclaimed get automatic parts
(:mod:`osgd.models.parts`); how its parts were found is recorded in
``provenance["parts"]``.

A model whose mesh is unusable (empty, flat, far off scale...) gives a note
and an empty shard; a user's mesh that is damaged or degenerate (repair
would drop more than ``max_repair_loss`` of its faces, no usable face, flat,
no volume) fails its item, naming the mesh file and the cause; a file that cannot be read (an OBJ trimesh cannot parse)
or a mistake in what a person wrote (a missing or invalid sidecar, a
malformed annotation file, a folder name that names no category, a source
file changed since planning) fails its item with an
:class:`osgd.errors.InputError` naming the file and the cause. Either way the
other models build, and so do the later stages, without it.
"""

from __future__ import annotations

import collections
import hashlib
import json
import logging
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pyarrow as pa
import trimesh
from pydantic import Field

from osgd.config import file_problem
from osgd.contract.schemas import MODELS, empty_table
from osgd.contract.shards import ShardRecord, file_sha256
from osgd.contract.taxonomy import CATEGORIES, UNKNOWN_PART, Taxonomy
from osgd.errors import InputError
from osgd.models import decomposition, osgd_import, parts, procedural, user
from osgd.models.categories import category_properties, draw_length
from osgd.models.decomposition import SCAN_MAX_FACES
from osgd.models.mass import clamp_mass, compound_mass_properties, mesh_mass_properties
from osgd.models.osgd_import import AnnotatedPair
from osgd.models.validation import DamagedMesh, ModelRejected, check_length, check_mesh
from osgd.stage import BuildResult, PlannedShard, Stage, StageParams, WorkItem, item_taxonomy, read_notes
from osgd.store import ShardStore

log = logging.getLogger(__name__)

Source = Literal["procedural", "osgd", "user"]


class ModelsStageParams(StageParams):
    """Parameters of the models stage (the ``[models]`` section of a pipeline config)."""

    sources: list[Source] = Field(
        default=["procedural"], description="Model sources to use, any of procedural, osgd, user."
    )
    procedural_per_category: int = Field(
        default=10, ge=0, le=1000, description="Procedural variants per category (the paper used 10 per category)."
    )
    osgd_dir: str | None = Field(
        default=None,
        json_schema_extra={"location": True},
        description="Folder in the OSGD layout (<name>/model/model_normalized.obj); empty: none.",
    )
    user_dir: str | None = Field(
        default=None,
        json_schema_extra={"location": True},
        description="Folder of users' meshes, each with a <stem>.toml sidecar; empty: none.",
    )
    max_repair_loss: float = Field(
        default=0.05,
        ge=0.0,
        le=1.0,
        json_schema_extra={"omit_default": True},
        description="Largest share of a user's mesh's faces that repair may drop (faces on non-finite vertices, "
        "zero-area faces), in [0, 1]; a mesh that would lose more fails its item. Default 0.05 (5 %).",
    )
    decomposition: Literal["auto", "fast", "thin", "fine", "hull", "scan"] = Field(
        default="auto",
        description="Convex decomposition preset (osgd.models.decomposition); auto: scan for users' meshes, "
        "else per category.",
    )
    scan_max_faces: int = Field(
        default=SCAN_MAX_FACES,
        ge=0,
        json_schema_extra={"omit_default": True},
        description="The scan preset: a repaired mesh with more faces is simplified to this many (quadric edge "
        "collapse) before coacd cuts it (coacd's time grows with the faces); 0: never simplified. The collision "
        "shape only: the stored mesh, its parts and grasps keep every face.",
    )


@dataclass(frozen=True)
class ModelWorkItem(WorkItem):
    """A work item that also knows where its source files are.

    ``source_path`` is a location, left out of the shard key (only
    ``item_id``, ``payload`` and ``inputs`` enter it): the payload holds the
    sha256 of every file read from there instead, and the build checks them.
    """

    source_path: str = ""


def item_rng(seed: int, item_id: str) -> np.random.Generator:
    """The random generator of one model, from the pipeline seed and the item id only."""
    digest = hashlib.sha256(f"{seed}/{item_id}".encode()).digest()
    return np.random.default_rng([int.from_bytes(digest[index : index + 8], "little") for index in range(0, 32, 8)])


def _hashes(paths: Sequence[Path], base: Path) -> dict[str, str]:
    return {path.relative_to(base).as_posix(): file_sha256(path) for path in paths if path.is_file()}


def _unreadable(paths: Sequence[Path], base: Path) -> dict[str, str]:
    """The files among ``paths`` that are there but cannot be read (a symbolic link loop, a broken link, a FIFO,
    no permission, too big), relative to ``base``, with the cause; files that are not there are left to the build."""
    problems = {}
    for path in paths:
        if os.path.lexists(path):
            problem = file_problem(path)
            if problem is not None:
                problems[path.relative_to(base).as_posix()] = problem
    return problems


def _check_hashes(expected: Mapping[str, str], base: Path, item_id: str) -> None:
    for relative, digest in expected.items():
        path = base / relative
        actual = file_sha256(path) if path.is_file() else "missing"
        if actual != digest:
            raise InputError(path, f"changed since planning (item {item_id}); run the stage again")


def _folder_category(folder: Path) -> str | None:
    """The category an OSGD folder names; None for a bad name, which fails that item alone at build time."""
    try:
        return osgd_import.category_from_folder(folder.name)
    except ValueError:
        return None


@dataclass
class _SourceModel:
    """What a source gives before the common steps: source units, source frame."""

    name: str
    category: str
    mesh: trimesh.Trimesh
    face_parts: np.ndarray | None
    pairs: list[AnnotatedPair]
    provenance: dict[str, Any]
    notes: list[str] = field(default_factory=list)
    length: float | None = None  # real length wanted, m
    scale: float | None = None  # or the scale given
    # Users' meshes: length is the oriented box's longest side, and faces no region claims get automatic parts.
    user_mesh: bool = False


def _axis_aligned_length(mesh: trimesh.Trimesh) -> float:
    """The longest axis-aligned extent: the length of procedural tools (built along x) and OSGD models."""
    return float(mesh.extents.max())


def _user_parts(
    mesh: trimesh.Trimesh, category: str, face_parts: np.ndarray, taxonomy: Taxonomy
) -> tuple[np.ndarray, dict[str, Any]]:
    """A user's mesh's parts: its sidecar's, automatic parts on the faces no region claims.

    Returns the parts (F,) int8 and the ``parts`` record of the provenance (with a ``note`` when the
    automatic parts were not found).
    """
    unclaimed = face_parts == UNKNOWN_PART
    if not unclaimed.any():
        return face_parts, {"method": "sidecar", "confidence": 1.0}
    found = parts.find_parts(mesh, category, taxonomy)
    record: dict[str, Any] = {
        "method": "automatic" if unclaimed.all() else "sidecar+automatic",
        "confidence": found.confidence,
        "axis": [round(float(value), 6) for value in found.axis],
    }
    if not found.found:
        del record["axis"]
        record["method"] = "sidecar" if not unclaimed.all() else "none"
        record["note"] = found.note
        return face_parts, record
    return np.where(unclaimed, found.face_parts, face_parts).astype(np.int8), record


class ModelsStage(Stage):
    """Object models at real size with physical properties and convex parts."""

    name = "models"
    table = "models"
    version = 2
    inputs = ()
    Params = ModelsStageParams
    uses_taxonomy = True
    description = "Object models at real size with physical properties and convex parts."

    # -- planning ---------------------------------------------------------------------
    def plan(self, params: StageParams, seed: int, upstream: Mapping[str, Sequence[PlannedShard]]) -> list[WorkItem]:
        assert isinstance(params, ModelsStageParams)
        common: dict[str, Any] = {"seed": int(seed), "decomposition": params.decomposition}
        # The scan preset's repair and simplification are in the key of exactly the items that get the preset.
        scan = {"scan_repair": decomposition.SCAN_REPAIR_VERSION, "scan_max_faces": params.scan_max_faces}
        if params.decomposition == "scan":
            common.update(scan)
        items: list[WorkItem] = []
        if "procedural" in params.sources:
            for category in CATEGORIES:
                for index in range(params.procedural_per_category):
                    payload = {**common, "source": "procedural", "category": category, "index": index}
                    items.append(ModelWorkItem(f"procedural/{category}_{index:02d}", payload))
        if "osgd" in params.sources and params.osgd_dir:
            items += self._plan_osgd(Path(params.osgd_dir), common)
        if "user" in params.sources and params.user_dir:
            user_common = {**common, **(scan if params.decomposition == "auto" else {})}
            items += self._plan_user(Path(params.user_dir), user_common, params.max_repair_loss)
        return items

    @staticmethod
    def _plan_osgd(models_dir: Path, common: Mapping[str, Any]) -> list[WorkItem]:
        """One item per model folder; a folder whose files cannot be read is an item that fails, naming them."""
        broken = osgd_import.unreadable_model_folders(models_dir)
        items: list[WorkItem] = []
        for folder in sorted([*osgd_import.list_model_folders(models_dir), *broken], key=lambda path: path.name):
            payload = {**common, "source": "osgd", "category": _folder_category(folder)}
            files = osgd_import.source_files(folder) if folder not in broken else []
            problems = dict([broken[folder]]) if folder in broken else _unreadable(files, folder)
            if problems:
                payload["unreadable"] = problems
            else:
                payload["files"] = _hashes(files, folder)
            items.append(ModelWorkItem(f"osgd/{folder.name}", payload, source_path=str(folder)))
        return items

    @staticmethod
    def _plan_user(base: Path, common: Mapping[str, Any], max_repair_loss: float) -> list[WorkItem]:
        """One item per mesh file; a mesh whose files cannot be read is an item that fails, naming them."""
        items: list[WorkItem] = []
        for mesh_path in user.list_user_meshes(base):
            sidecar = user.sidecar_path(mesh_path)
            problems = _unreadable([mesh_path, sidecar], base)
            files = [mesh_path, sidecar, *([] if problems else user.named_files(sidecar))]
            problems = problems or _unreadable(files, base)
            payload = {**common, "source": "user", "mesh": mesh_path.name}
            if problems:
                payload["unreadable"] = problems
            else:
                payload.update({"files": _hashes(files, base), "automatic_parts": parts.VERSION,
                                "max_repair_loss": max_repair_loss})
            items.append(ModelWorkItem(f"user/{mesh_path.stem}", payload, source_path=str(base)))
        return items

    # -- building ---------------------------------------------------------------------
    def _read_source(self, item: WorkItem) -> _SourceModel:
        payload = item.payload
        source = payload["source"]
        if payload.get("unreadable"):
            relative, cause = next(iter(sorted(payload["unreadable"].items())))
            location = Path(getattr(item, "source_path", ""))
            raise InputError(location if relative == location.name else location / relative, cause)
        rng = item_rng(payload["seed"], item.item_id)
        if source == "procedural":
            generated = procedural.generate(payload["category"], rng)
            return _SourceModel(
                item.item_id,
                payload["category"],
                generated.mesh,
                generated.face_parts,
                [],
                {
                    "generator": "osgd.models.procedural",
                    "category": payload["category"],
                    "index": payload["index"],
                    "parameters": generated.parameters,
                },
                scale=1.0,
            )
        location = Path(getattr(item, "source_path", ""))
        _check_hashes(payload["files"], location, item.item_id)
        if source == "osgd":
            model = osgd_import.load_osgd_model(location)
            return _SourceModel(
                model.name,
                model.category,
                model.mesh,
                None,
                model.pairs,
                {"path": f"{location.name}/{osgd_import.MESH_PATH.as_posix()}", "files": payload["files"]},
                notes=model.notes,
                length=draw_length(model.category, rng),
            )
        if source == "user":
            mesh_path = location / payload["mesh"]
            sidecar_file = user.sidecar_path(mesh_path)
            taxonomy = item_taxonomy(item)
            sidecar = user.read_sidecar(sidecar_file, taxonomy)
            mesh, groups = user.load_user_mesh(mesh_path)
            face_parts = user.face_parts_from_regions(mesh, sidecar, groups, str(sidecar_file),
                                                     sidecar_file.parent, taxonomy)
            pairs, notes = user.read_grasp_files(sidecar, location, taxonomy)
            return _SourceModel(
                mesh_path.stem,
                sidecar.category,
                mesh,
                face_parts,
                pairs,
                {
                    "path": mesh_path.name,
                    "sidecar": sidecar.model_dump(mode="json", exclude_none=True),
                    "files": payload["files"],
                },
                notes=notes,
                length=sidecar.length,
                scale=sidecar.scale,
                user_mesh=True,
            )
        raise ValueError(f"item {item.item_id}: unknown source {source!r}")

    def build(self, item: WorkItem, store: ShardStore) -> BuildResult:
        try:
            model = self._read_source(item)
            row, notes, warnings = self._finish(model, item, store)
        except DamagedMesh as error:
            if item.payload["source"] != "user":
                return BuildResult(empty_table("models"), [f"skipped: {error}"])
            raise InputError(Path(getattr(item, "source_path", "")) / item.payload["mesh"], error.cause) from error
        except ModelRejected as error:
            return BuildResult(empty_table("models"), [f"skipped: {error}"])
        return BuildResult(pa.Table.from_pylist([row], schema=MODELS), notes, warnings)

    def _finish(
        self, model: _SourceModel, item: WorkItem, store: ShardStore
    ) -> tuple[dict[str, Any], list[str], list[str]]:
        """The row, its notes (kept, also in the provenance) and this build's warnings (a bad cache file)."""
        taxonomy = item_taxonomy(item)
        max_loss = item.payload.get("max_repair_loss") if model.user_mesh else None
        checked = check_mesh(model.mesh, model.face_parts, name=item.item_id, max_loss=max_loss)
        notes = [*model.notes, *checked.notes]
        mesh = checked.mesh
        measure = parts.true_length if model.user_mesh else _axis_aligned_length
        scale = model.scale if model.scale is not None else float(model.length) / measure(mesh)
        mesh.apply_scale(scale)
        length = measure(mesh)
        check_length(length, model.category, name=item.item_id, taxonomy=taxonomy)
        pairs = [pair.scaled(scale) for pair in model.pairs]
        face_parts, found = checked.face_parts, None
        if model.user_mesh:
            face_parts, found = _user_parts(mesh, model.category, face_parts, taxonomy)
            notes += [found["note"]] if found.get("note") else []

        preset = decomposition.resolve_preset(item.payload["decomposition"], model.category, model.user_mesh)
        cache = store.local_folder("cache/decompositions")
        compound = decomposition.decompose(mesh.vertices, mesh.faces, preset, cache,
                                           item.payload.get("scan_max_faces", SCAN_MAX_FACES))
        notes += compound.notes
        properties = category_properties(model.category, taxonomy)
        if checked.is_closed:
            mass = mesh_mass_properties(mesh, properties.density)
        else:
            mass = compound_mass_properties(
                [trimesh.Trimesh(v, f, process=False) for v, f in compound.parts], properties.density
            )
        if not mass.volume > 0:
            raise DamagedMesh(item.item_id, f"degenerate mesh: no volume ({mass.source}: {mass.volume:.3g} m^3)")
        density = properties.density
        estimated_mass = mass.mass
        mass, clamped = clamp_mass(mass, properties.mass_range)
        if clamped:
            notes.append(clamped)
            density *= mass.mass / estimated_mass

        vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
        faces = np.ascontiguousarray(mesh.faces, dtype=np.int32)
        model_id = hashlib.sha256(vertices.tobytes() + faces.tobytes() + model.category.encode()).hexdigest()[:16]
        provenance = {
            **model.provenance,
            "source": item.payload["source"],
            "item": item.item_id,
            "mass_from": mass.source,
            "volume": mass.volume,
            "notes": notes,
        }
        if found is not None:
            provenance["parts"] = {key: value for key, value in found.items() if key != "note"}
        row = {
            "model_id": model_id,
            "name": model.name if item.payload["source"] == "osgd" else item.item_id,
            "category": model.category,
            "source": item.payload["source"],
            "scale": float(scale),
            "length": length,
            "vertices": vertices.tolist(),
            "faces": faces.tolist(),
            "face_parts": face_parts.astype(int).tolist(),
            "convex_parts": [{"vertices": v.tolist(), "faces": f.astype(np.int32).tolist()} for v, f in compound.parts],
            "decomposition": decomposition.description_json(compound.description),
            "density": density,
            "mass": mass.mass,
            "center_of_mass": mass.center_of_mass.tolist(),
            "inertia": mass.inertia.reshape(-1).tolist(),
            "friction": list(properties.friction),
            "annotated_pairs": [pair.as_row() for pair in pairs],
            "provenance": json.dumps(provenance, sort_keys=True),
        }
        return row, notes, compound.warnings

    # -- reporting --------------------------------------------------------------------
    def summary(self, store: ShardStore, records: Sequence[ShardRecord]) -> str:
        """Models per category and source, how their parts were found, and which get no task labels."""
        counts: dict[tuple[str, str], int] = collections.Counter()
        methods: dict[str, int] = collections.Counter()
        unlabelled: list[str] = []
        skipped = noted = 0
        columns = ["name", "category", "source", "face_parts", "annotated_pairs", "provenance"]
        for record in records:
            noted += bool(read_notes(store, "models", record.key))
            if record.rows == 0:
                skipped += 1
                continue
            table = store.read("models", record.key, columns=columns)
            unlabelled += parts.without_task_labels(table)
            for category, source, provenance in zip(
                table["category"].to_pylist(), table["source"].to_pylist(), table["provenance"].to_pylist(),
                strict=True,
            ):
                counts[(category, source)] += 1
                methods[parts.parts_method(source, json.loads(provenance))[0]] += 1
        sources = sorted({source for _, source in counts})
        lines = ["models per category: " + ", ".join(sources)]
        for category in [*CATEGORIES, *sorted({category for category, _ in counts} - set(CATEGORIES))]:
            row = [counts.get((category, source), 0) for source in sources]
            if any(row):
                lines.append(f"  {category:<12}" + "".join(f"{count:>6}" for count in row))
        lines.append(f"  total {sum(counts.values())} models; {skipped} skipped; {noted} with notes")
        lines.append("  parts: " + ", ".join(f"{count} {method}" for method, count in sorted(methods.items())))
        if unlabelled:
            lines.append(
                f"  {len(unlabelled)} models without task labels (no parts found, no hand-made pairs; "
                f"their grasps get no task): {', '.join(sorted(unlabelled))}"
            )
        return "\n".join(lines)
