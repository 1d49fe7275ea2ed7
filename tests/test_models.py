"""Tests of the models stage: procedural tools, OSGD import, sidecars, validation, decomposition."""

from __future__ import annotations

import collections
import dataclasses
import json

import numpy as np
import pytest
import trimesh
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from osgd.contract.schemas import MODELS, mesh_from_arrow
from osgd.contract.taxonomy import CATEGORIES, PART_INDEX, PARTS, UNKNOWN_PART
from osgd.grasps.geometry import convex_planes
from osgd.models import decomposition
from osgd.models.categories import CATEGORY_PROPERTIES
from osgd.models.osgd_import import blender_to_obj, list_model_folders, load_osgd_model, read_annotations
from osgd.models.procedural import MIN_THICKNESS, generate
from osgd.models.stage import ModelsStage, item_rng
from osgd.models.user import parse_sidecar, sidecar_to_toml
from osgd.models.validation import ModelRejected, check_length, check_mesh
from osgd.stage import run_stage
from osgd.store import ShardStore

#: Parts each procedural category must show (the grasps stage labels grasps by them).
EXPECTED_PARTS = {
    "knife": {"handle", "blade"},
    "screwdriver": {"handle", "shaft", "tip"},
    "spoon": {"handle", "bowl"},
    "fork": {"handle", "tines"},
    "wrench": {"handle", "jaws"},
    "hammer": {"handle", "head"},
    "pen": {"handle", "tip"},
    "toothbrush": {"handle", "head", "bristles"},
    "spatula": {"handle", "blade"},
    "pliers": {"handle", "jaws"},
}


# -- procedural ------------------------------------------------------------------------------


@pytest.mark.parametrize("category", CATEGORIES)
def test_procedural_tools_are_watertight_real_sized_and_labelled(category):
    low, high = CATEGORY_PROPERTIES[category].length_range
    for index in range(3):
        model = generate(category, np.random.default_rng([7, index]))
        mesh = model.mesh
        assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
        assert len(mesh.split(only_watertight=False)) == 1
        assert low - 1e-9 <= mesh.extents.max() <= high + 1e-9
        assert len(model.face_parts) == len(mesh.faces)
        assert (model.face_parts != UNKNOWN_PART).all()
        assert EXPECTED_PARTS[category] <= {PARTS[p] for p in np.unique(model.face_parts)}
        assert len(mesh.faces) < 5000
        # No part thinner than the minimum: the smallest extent of the whole tool bounds it.
        assert mesh.extents.min() >= MIN_THICKNESS * 0.95


def test_procedural_is_deterministic_and_seeds_differ():
    for category in CATEGORIES:
        first = generate(category, np.random.default_rng([3, 1]))
        again = generate(category, np.random.default_rng([3, 1]))
        other = generate(category, np.random.default_rng([3, 2]))
        assert np.array_equal(first.mesh.vertices, again.mesh.vertices)
        assert np.array_equal(first.face_parts, again.face_parts)
        assert first.parameters == again.parameters
        assert first.parameters != other.parameters
        assert first.mesh.vertices.shape != other.mesh.vertices.shape or not np.allclose(
            first.mesh.vertices, other.mesh.vertices
        )


def test_item_rng_depends_only_on_seed_and_item():
    assert item_rng(0, "osgd/hammer_001").random() == item_rng(0, "osgd/hammer_001").random()
    assert item_rng(0, "osgd/hammer_001").random() != item_rng(1, "osgd/hammer_001").random()
    assert item_rng(0, "osgd/hammer_001").random() != item_rng(0, "osgd/hammer_003").random()


# -- OSGD import -----------------------------------------------------------------------------


def test_blender_to_obj_mapping():
    assert np.allclose(blender_to_obj(np.array([[1.0, 2.0, 3.0]])), [[1.0, 3.0, -2.0]])


def _pair_crosses(mesh: trimesh.Trimesh, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether each segment a-b crosses the surface or passes within 1 % of the object's length of it.

    The annotation points are finger positions off the surface (REFERENCE
    section 2); a segment across a thin blade can slip between ray-triangle
    tests, so passing that close also counts.
    """
    direction = b - a
    span = np.linalg.norm(direction, axis=1)
    hits = np.zeros(len(a), dtype=bool)
    locations, index, _ = mesh.ray.intersects_location(a, direction / span[:, None], multiple_hits=True)
    hits[index[np.linalg.norm(locations - a[index], axis=1) <= span[index]]] = True
    surface = np.vstack([mesh.sample(20000, seed=0), mesh.vertices])
    steps = np.linspace(0.0, 1.0, 21)
    samples = a[:, None, :] + steps[None, :, None] * direction[:, None, :]
    distance, _ = cKDTree(surface).query(samples.reshape(-1, 3))
    near = distance.reshape(len(a), -1).min(axis=1) <= 0.01 * mesh.extents.max()
    return hits | near


def test_osgd_models_read_with_every_category_and_mapped_pairs(osgd_models_dir):
    folders = list_model_folders(osgd_models_dir)
    crossing = collections.defaultdict(list)
    crossing_unmapped = collections.defaultdict(list)
    for folder in folders:
        model = load_osgd_model(folder)
        assert len(model.mesh.faces) > 0 and model.pairs
        a = np.array([pair.contact_a for pair in model.pairs])
        b = np.array([pair.contact_b for pair in model.pairs])
        crossing[model.category].extend(_pair_crosses(model.mesh, a, b))
        if folder.name.endswith(("_000", "_001")):
            # Undo the mapping: the points as stored, read as OBJ coordinates.
            raw_a = np.column_stack([a[:, 0], -a[:, 2], a[:, 1]])
            raw_b = np.column_stack([b[:, 0], -b[:, 2], b[:, 1]])
            crossing_unmapped[model.category].extend(_pair_crosses(model.mesh, raw_a, raw_b))
    assert set(crossing) == set(CATEGORIES)
    for category, flags in crossing.items():
        assert np.mean(flags) >= 0.85, (category, np.mean(flags))
    mapped_total = np.mean([np.mean(crossing[c]) for c in crossing_unmapped])
    unmapped_total = np.mean([np.mean(flags) for flags in crossing_unmapped.values()])
    assert unmapped_total < mapped_total - 0.1


@given(st.floats(1e-4, 10.0), st.floats(1e-3, 1.0), st.floats(1.0, 5.0))
def test_clamp_mass_keeps_the_centre_and_scales_the_inertia(mass, low, spread):
    from osgd.models.mass import MassProperties, clamp_mass  # noqa: PLC0415

    high = low * spread
    inertia = np.diag([1.0, 2.0, 3.0]) * mass
    body = MassProperties(mass, np.array([0.1, 0.0, -0.2]), inertia, 1e-4, "convex_parts")
    clamped, note = clamp_mass(body, (low, high))
    assert low <= clamped.mass <= high
    assert (note is None) == (low <= mass <= high)
    np.testing.assert_allclose(clamped.center_of_mass, body.center_of_mass)
    np.testing.assert_allclose(clamped.inertia, inertia * clamped.mass / mass)


def test_odd_annotation_row_count_drops_the_last_point(tmp_path):
    folder = tmp_path / "wrench_900"
    (folder / "annotations").mkdir(parents=True)
    np.save(folder / "annotations" / "hand_over.npy", np.arange(21, dtype=float).reshape(7, 3))
    pairs, notes = read_annotations(folder)
    assert len(pairs) == 3
    assert all(pair.task == "hand over" and pair.file == "annotations/hand_over.npy" for pair in pairs)
    assert any("odd number" in note for note in notes)


def test_osgd_stage_builds_real_sized_models(tmp_path, osgd_models_dir):
    stage = ModelsStage()
    params = stage.Params(sources=["osgd"], osgd_dir=str(osgd_models_dir), decomposition="hull")
    shards = stage.planned(params, 5, {})
    assert {shard.item.item_id.split("/")[1].split("_")[0] for shard in shards} == set(CATEGORIES)
    chosen = [shard for shard in shards
              if shard.item.item_id in ("osgd/wrench_004", "osgd/spatula_001", "osgd/pliers_007")]
    store = ShardStore(tmp_path)
    report = run_stage(stage, chosen, store)
    assert report.ok and report.built == 3
    rows = store.read_many("models", [record.key for record in report.records]).to_pylist()
    for row in rows:
        low, high = CATEGORY_PROPERTIES[row["category"]].length_range
        assert low <= row["length"] <= high
        vertices, _ = mesh_from_arrow(row["vertices"], row["faces"])
        assert np.isclose(np.ptp(vertices, axis=0).max(), row["length"])
        assert row["annotated_pairs"]
        mass_low, mass_high = CATEGORY_PROPERTIES[row["category"]].mass_range
        assert mass_low <= row["mass"] <= mass_high
        contacts = np.array([pair["contact_a"] for pair in row["annotated_pairs"]])
        # The pairs were scaled with the mesh: they lie around it, not a unit-sized cloud.
        assert np.ptp(contacts, axis=0).max() < 1.5 * row["length"]
    assert any("odd number" in note for note in report.notes["osgd/wrench_004"])
    # Its bulky handles would weigh kilograms of steel: clamped, with a note.
    assert any("clamped" in note for note in report.notes["osgd/pliers_007"])
    # Moving the folder changes no key: the location is not part of it.
    moved = tmp_path / "moved"
    moved.symlink_to(osgd_models_dir)
    moved_keys = {
        s.item.item_id: s.key for s in stage.planned(params.model_copy(update={"osgd_dir": str(moved)}), 5, {})
    }
    assert all(moved_keys[s.item.item_id] == s.key for s in shards)


# -- users' meshes ---------------------------------------------------------------------------

SIDECAR_EXAMPLE = """
category = "hammer"
length = 0.3
default_part = "handle"

[[parts]]
part = "neck"
half_space = { point = [60.0, 0.0, 0.0], normal = [1.0, 0.0, 0.0] }

[[parts]]
part = "head"
box = { min = [80.0, -60.0, -20.0], max = [120.0, 60.0, 20.0] }

[[grasps]]
file = "mallet_grasps.npy"
task = "hammer"
"""


def test_sidecar_round_trips():
    sidecar = parse_sidecar(SIDECAR_EXAMPLE)
    assert parse_sidecar(sidecar_to_toml(sidecar)) == sidecar
    with pytest.raises(ValueError, match="exactly one of length"):
        parse_sidecar('category = "hammer"\nlength = 0.3\nscale = 0.001\n', "x.toml")
    with pytest.raises(ValueError, match=r"x\.toml.*unknown category"):
        parse_sidecar('category = "drill"\nlength = 0.3\n', "x.toml")


def _mallet_mm() -> trimesh.Trimesh:
    """A 200 mm handle along x with a head at x = 100 mm, in millimetres."""
    handle = trimesh.creation.box(
        extents=[200, 24, 16], transform=trimesh.transformations.translation_matrix([0, 0, 0])
    )
    head = trimesh.creation.box(
        extents=[30, 100, 30], transform=trimesh.transformations.translation_matrix([100, 0, 0])
    )
    mallet = trimesh.boolean.union([handle, head], engine="manifold")
    # Small faces, so that face centroids follow the regions closely.
    vertices, faces = trimesh.remesh.subdivide_to_size(mallet.vertices, mallet.faces, max_edge=10.0)
    return trimesh.Trimesh(vertices, faces)


def test_user_mesh_with_sidecar_builds(tmp_path):
    user_dir = tmp_path / "mine"
    user_dir.mkdir()
    _mallet_mm().export(user_dir / "mallet.stl")
    (user_dir / "mallet.toml").write_text(SIDECAR_EXAMPLE)
    np.save(user_dir / "mallet_grasps.npy", np.array([[-50.0, 0, -10], [-50.0, 0, 10]]))
    (user_dir / "broken.stl").write_bytes(b"")
    (user_dir / "broken.toml").write_text('category = "knife"\nlength = 0.2\n')
    stage = ModelsStage()
    params = stage.Params(sources=["user"], user_dir=str(user_dir), decomposition="hull")
    store = ShardStore(tmp_path / "data")
    report = run_stage(stage, stage.planned(params, 0, {}), store)
    assert report.ok, report.failures
    by_item = {record.item_id: record for record in report.records}
    assert by_item["user/broken"].rows == 0 and "skipped" in report.notes["user/broken"][0]
    row = store.read("models", by_item["user/mallet"].key).to_pylist()[0]
    assert row["source"] == "user" and np.isclose(row["length"], 0.3)
    assert np.isclose(row["scale"], 0.3 / 215.0)
    parts = set(row["face_parts"])
    assert {PART_INDEX["handle"], PART_INDEX["head"], PART_INDEX["neck"]} <= parts
    pair = row["annotated_pairs"][0]
    assert pair["task"] == "hammer" and np.allclose(pair["contact_a"], np.array([-50.0, 0, -10]) * row["scale"])


def test_user_mesh_without_sidecar_fails_naming_the_file(tmp_path):
    _mallet_mm().export(tmp_path / "lonely.stl")
    stage = ModelsStage()
    params = stage.Params(sources=["user"], user_dir=str(tmp_path), decomposition="hull")
    report = run_stage(stage, stage.planned(params, 0, {}), ShardStore(tmp_path / "data"))
    assert len(report.failures) == 1 and "lonely.toml" in report.failures[0].error


# -- validation and repair -------------------------------------------------------------------


def test_empty_mesh_is_rejected():
    with pytest.raises(ModelRejected, match="empty"):
        check_mesh(trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int)), name="empty.stl")


def test_nan_vertex_faces_are_dropped():
    box = trimesh.creation.box(extents=[0.2, 0.03, 0.02])
    vertices = np.vstack([box.vertices, [[np.nan, 0.0, 0.0]]])
    faces = np.vstack([box.faces, [[0, 1, len(vertices) - 1]]])
    checked = check_mesh(trimesh.Trimesh(vertices, faces, process=False), name="nan.stl")
    assert np.isfinite(checked.mesh.vertices).all() and len(checked.mesh.faces) == len(box.faces)
    assert checked.is_closed and any("non-finite" in note for note in checked.notes)


def test_open_surface_is_noted_and_kept():
    box = trimesh.creation.box(extents=[0.2, 0.03, 0.02])
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    # Remove a band of faces: a hole too large for fill_holes to close.
    keep = np.abs(sphere.triangles_center[:, 2]) > 0.01
    opened = trimesh.Trimesh(sphere.vertices, sphere.faces[keep], process=False)
    checked = check_mesh(opened, name="open.obj")
    assert not checked.is_closed and any("open surface" in note for note in checked.notes)
    # A single missing triangle is a small hole: closed again.
    holed = trimesh.Trimesh(box.vertices, box.faces[1:], process=False)
    repaired = check_mesh(holed, name="holed.obj")
    assert repaired.is_closed and any("closed small holes" in note for note in repaired.notes)


def test_two_separate_bodies_keep_the_largest():
    big = trimesh.creation.box(extents=[0.2, 0.03, 0.02])
    small = trimesh.creation.box(
        extents=[0.02, 0.02, 0.02], transform=trimesh.transformations.translation_matrix([0, 0.5, 0])
    )
    checked = check_mesh(trimesh.util.concatenate([big, small]), name="two.stl")
    assert np.allclose(checked.mesh.extents, [0.2, 0.03, 0.02])
    assert any("2 separate bodies" in note for note in checked.notes)
    # Bodies that touch are one object (a handle pushed into a head): both kept.
    head = trimesh.creation.box(
        extents=[0.03, 0.1, 0.03], transform=trimesh.transformations.translation_matrix([0.1, 0, 0])
    )
    joined = check_mesh(trimesh.util.concatenate([big, head]), name="hammer.stl")
    assert len(joined.mesh.faces) == 24 and not any("separate" in note for note in joined.notes)


def test_inside_out_mesh_is_fixed():
    box = trimesh.creation.box(extents=[0.2, 0.03, 0.02])
    inverted = trimesh.Trimesh(box.vertices, box.faces[:, ::-1], process=False)
    checked = check_mesh(inverted, name="inverted.stl")
    assert checked.mesh.volume > 0 and any("inside out" in note for note in checked.notes)


def test_far_off_scale_and_flat_meshes_are_rejected():
    with pytest.raises(ModelRejected, match="far off scale"):
        check_length(1000.0, "hammer", name="km.stl")
    check_length(0.3, "hammer")
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 3, 2]], process=False)
    with pytest.raises(ModelRejected, match="flat"):
        check_mesh(flat, name="flat.stl")


def test_kilometre_user_mesh_gives_an_empty_shard(tmp_path):
    trimesh.creation.box(extents=[1000.0, 30.0, 20.0]).export(tmp_path / "long.stl")
    (tmp_path / "long.toml").write_text('category = "knife"\nscale = 1.0\n')
    stage = ModelsStage()
    params = stage.Params(sources=["user"], user_dir=str(tmp_path), decomposition="hull")
    report = run_stage(stage, stage.planned(params, 0, {}), ShardStore(tmp_path / "data"))
    assert report.ok and report.records[0].rows == 0
    assert "far off scale" in report.notes["user/long"][0]


# -- decomposition ---------------------------------------------------------------------------


def test_cache_key_changes_with_every_coacd_parameter():
    box = trimesh.creation.box(extents=[0.2, 0.03, 0.02])
    base = decomposition.CoacdParameters()
    keys = {decomposition.cache_key(box.vertices, box.faces, base)}
    for item in dataclasses.fields(base):
        value = getattr(base, item.name)
        if isinstance(value, bool):
            changed = not value
        elif isinstance(value, int | float):
            changed = value + 1
        else:
            changed = value + "_other"
        keys.add(decomposition.cache_key(box.vertices, box.faces, dataclasses.replace(base, **{item.name: changed})))
    assert len(keys) == len(dataclasses.fields(base)) + 1
    moved = box.vertices + 1e-6
    assert decomposition.cache_key(moved, box.faces, base) not in keys
    assert decomposition.cache_key(box.vertices, box.faces, None) not in keys


def test_thin_preset_keeps_fork_tines_apart_and_caches(tmp_path):
    fork = generate("fork", np.random.default_rng([0, 4]))
    fast = decomposition.decompose(fork.mesh.vertices, fork.mesh.faces, "fast", tmp_path)
    thin = decomposition.decompose(fork.mesh.vertices, fork.mesh.faces, "thin", tmp_path)
    assert len(thin.parts) > len(fast.parts) and not thin.cached
    for part_vertices, part_faces in thin.parts:
        assert trimesh.Trimesh(part_vertices, part_faces).is_convex
    again = decomposition.decompose(fork.mesh.vertices, fork.mesh.faces, "thin", tmp_path)
    assert again.cached and all(np.array_equal(a[0], b[0]) for a, b in zip(again.parts, thin.parts, strict=True))
    assert json.loads(decomposition.description_json(thin.description))["parameters"]["threshold"] == 0.02
    assert decomposition.resolve_preset("auto", "fork") == "thin"
    assert decomposition.resolve_preset("auto", "hammer") == "fast"
    assert decomposition.resolve_preset("auto", "fork", user_mesh=True) == "scan"


def test_repair_closes_holes_and_merges_split_vertices():
    box = trimesh.creation.box(extents=[0.1, 0.05, 0.02])
    split_vertices = box.vertices[box.faces].reshape(-1, 3)  # every face with its own three vertices
    split_faces = np.arange(len(split_vertices)).reshape(-1, 3)
    for vertices, faces, holes in ((box.vertices, box.faces[1:], 1), (split_vertices, split_faces[2:], 1),
                                   (box.vertices, box.faces, 0)):
        repaired = decomposition.repair_for_decomposition(vertices, faces)
        closed = trimesh.Trimesh(repaired.vertices, repaired.faces, process=False)
        assert repaired.watertight and closed.is_watertight and closed.is_winding_consistent
        assert repaired.holes_closed == holes
        assert closed.volume == pytest.approx(0.1 * 0.05 * 0.02, rel=1e-9)  # the fans face outwards


def _scanned_comb(rng: np.random.Generator, edge: float = 0.005) -> tuple[trimesh.Trimesh, np.ndarray]:
    """An 18 cm comb (a fork's tines: 3 mm wide, 3 mm apart) as a scan: remeshed to ``edge`` (m), noised by
    0.2 mm, 2 % of its faces gone; and a point in each gap between the tines."""
    from shapely.geometry import box  # noqa: PLC0415 - trimesh's extrusion needs shapely
    from shapely.ops import unary_union  # noqa: PLC0415

    outline = unary_union([box(0, 0, 0.12, 0.021)] + [box(0.11, 0.006 * i, 0.18, 0.006 * i + 0.003) for i in range(4)])
    solid = trimesh.creation.extrude_polygon(outline, 0.004)
    vertices, faces = trimesh.remesh.subdivide_to_size(solid.vertices, solid.faces, max_edge=edge, max_iter=20)
    vertices = vertices + rng.normal(0.0, 0.0002, vertices.shape)
    faces = faces[rng.random(len(faces)) > 0.02]
    gaps = np.array([[0.15, 0.006 * i + 0.0045, 0.002] for i in range(3)])
    return trimesh.Trimesh(vertices, faces, process=False), gaps


def _covered(point: np.ndarray, parts: list[tuple[np.ndarray, np.ndarray]]) -> bool:
    """Whether some convex part holds the point."""
    return any(np.all(normals @ point <= offsets + 1e-6) for normals, offsets in convex_planes(parts))


def test_scan_preset_repairs_a_scan_and_keeps_the_gaps_between_tines(tmp_path):
    scan, gaps = _scanned_comb(np.random.default_rng(3))
    assert not scan.is_watertight
    result = decomposition.decompose(scan.vertices, scan.faces, "scan", tmp_path)
    description = json.loads(decomposition.description_json(result.description))
    assert description["repair"]["watertight"] and description["repair"]["holes_closed"] > 0
    assert description["parameters"]["preprocess_mode"] == "off" and not result.notes
    assert not any(_covered(gap, result.parts) for gap in gaps)
    assert decomposition.decompose(scan.vertices, scan.faces, "scan", tmp_path).cached
    # the preset procedural tools get fills every gap: one hull
    assert all(_covered(gap, decomposition.decompose(scan.vertices, scan.faces, "fast").parts) for gap in gaps)


def test_scan_preset_simplifies_a_dense_scan_and_keeps_the_gaps_between_tines(tmp_path):
    scan, gaps = _scanned_comb(np.random.default_rng(3), edge=0.0012)
    assert len(scan.faces) > 4 * 2000
    simple = decomposition.decompose(scan.vertices, scan.faces, "scan", tmp_path, scan_max_faces=2000)
    simplified = json.loads(decomposition.description_json(simple.description))["repair"]["simplified"]
    assert simplified["faces_before"] > 4 * 2000 and 1900 <= simplified["faces"] <= 2000
    for max_faces in (0, len(scan.faces)):  # nothing to collapse
        kept = decomposition.simplify_for_decomposition(scan.vertices, scan.faces, max_faces)
        assert kept[0] is scan.vertices and kept[1] is scan.faces and kept[2] == {}
    assert not any(_covered(gap, simple.parts) for gap in gaps) and not simple.notes
    # the simplified compound still holds the comb: its back and each tine's middle
    assert all(_covered(point, simple.parts) for point in ([0.06, 0.0105, 0.002], *[[0.15, 0.006 * i + 0.0015, 0.002]
                                                                                   for i in range(4)]))
    assert decomposition.decompose(scan.vertices, scan.faces, "scan", tmp_path, scan_max_faces=2000).cached


def test_scan_max_faces_is_in_the_key_of_the_items_that_get_the_scan_preset(tmp_path):
    (tmp_path / "fork.stl").write_bytes(trimesh.creation.box(extents=[0.2, 0.02, 0.01]).export(file_type="stl"))
    (tmp_path / "fork.toml").write_text('category = "fork"\nlength = 0.2\n')
    stage = ModelsStage()

    def keys(**values):
        params = stage.Params(sources=["procedural", "user"], procedural_per_category=1, user_dir=str(tmp_path),
                              **values)
        return {shard.item.item_id: shard.key for shard in stage.planned(params, 0, {})}

    default, other = keys(), keys(scan_max_faces=3000)
    assert default["user/fork"] != other["user/fork"]
    assert all(default[item] == other[item] for item in default if item.startswith("procedural/"))
    scan_everywhere, scan_other = keys(decomposition="scan"), keys(decomposition="scan", scan_max_faces=3000)
    assert scan_everywhere["procedural/fork_00"] != scan_other["procedural/fork_00"]
    assert keys(decomposition="fast")["user/fork"] == keys(decomposition="fast", scan_max_faces=3000)["user/fork"]


# -- the stage -------------------------------------------------------------------------------


def test_procedural_stage_rows_are_complete_and_deterministic(tmp_path):
    stage = ModelsStage()
    params = stage.Params(procedural_per_category=1, decomposition="hull")
    shards = [
        s for s in stage.planned(params, 11, {}) if s.item.item_id in ("procedural/hammer_00", "procedural/spoon_00")
    ]
    first, second = ShardStore(tmp_path / "a"), ShardStore(tmp_path / "b")
    run_stage(stage, shards, first)
    run_stage(stage, shards, second)
    for shard in shards:
        assert first.shard_path("models", shard.key).read_bytes() == second.shard_path("models", shard.key).read_bytes()
    table = first.read_many("models", [shard.key for shard in shards])
    assert table.schema.equals(MODELS, check_metadata=False)
    for row in table.to_pylist():
        vertices, faces = mesh_from_arrow(row["vertices"], row["faces"])
        mesh = trimesh.Trimesh(vertices, faces)
        density = CATEGORY_PROPERTIES[row["category"]].density
        assert np.isclose(row["mass"], mesh.volume * density)
        assert np.allclose(row["center_of_mass"], mesh.center_mass)
        inertia = np.array(row["inertia"]).reshape(3, 3)
        assert np.allclose(inertia, inertia.T) and (np.linalg.eigvalsh(inertia) > 0).all()
        assert row["friction"][1] == row["friction"][2] == 0.01
        assert len(row["model_id"]) == 16 and len(row["face_parts"]) == len(faces)
        assert row["convex_parts"] and json.loads(row["decomposition"])["method"] == "convex_hull"
    text = stage.summary(first, [first.verify("models", shard.key) for shard in shards])
    assert "hammer" in text and "2 models" in text
    # Adding models elsewhere does not change these keys.
    more = {
        s.item.item_id: s.key for s in stage.planned(params.model_copy(update={"procedural_per_category": 3}), 11, {})
    }
    assert all(more[s.item.item_id] == s.key for s in shards)


def test_pictures_are_written(tmp_path):
    from osgd.models.pictures import show_model, show_models  # noqa: PLC0415

    stage = ModelsStage()
    params = stage.Params(procedural_per_category=1, decomposition="hull")
    shards = [s for s in stage.planned(params, 0, {}) if s.item.item_id.endswith(("fork_00", "pliers_00"))]
    store = ShardStore(tmp_path)
    run_stage(stage, shards, store)
    model_id = store.read("models", shards[0].key)["model_id"][0].as_py()
    show_model(store, model_id, tmp_path / "one.png")
    show_models(store, tmp_path / "all.png")
    assert (tmp_path / "one.png").stat().st_size > 5000 and (tmp_path / "all.png").stat().st_size > 5000
    name = store.read("models", shards[0].key)["name"][0].as_py()
    show_model(store, name, tmp_path / "by-name.png")  # the item name the notes and summaries show
    assert (tmp_path / "by-name.png").read_bytes() == (tmp_path / "one.png").read_bytes()
    with pytest.raises(KeyError, match="no model") as missing:
        show_model(store, "0" * 16, tmp_path / "none.png")
    assert name in str(missing.value)  # the error lists models that are there


# -- caches that cannot lie, errors a person can act on --------------------------


def _box_mesh(length: float) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=[length, 0.03, 0.02])


def _flip_a_byte(path, offset: int) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("damage", ["truncated", "flipped", "altered", "another mesh's file", "older format"])
def test_a_bad_cached_decomposition_is_recomputed_with_a_warning(tmp_path, damage):
    box, other = _box_mesh(0.2), _box_mesh(0.25)
    fresh = decomposition.decompose(box.vertices, box.faces, "hull", tmp_path)
    (path,) = tmp_path.glob("*.npz")
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif damage == "flipped":  # inside the first part's vertices
        _flip_a_byte(path, path.read_bytes().index(b"vertices_0") + 200)
    elif damage == "altered":  # a valid archive with its own key, and other numbers
        with np.load(path) as data:
            arrays = {name: data[name] for name in data.files}
        arrays["vertices_0"] = arrays["vertices_0"] * 1.01
        np.savez(path, **arrays)
    elif damage == "another mesh's file":
        decomposition.decompose(other.vertices, other.faces, "hull", tmp_path / "other")
        path.write_bytes(next((tmp_path / "other").glob("*.npz")).read_bytes())
    else:
        np.savez(path, count=np.array(1), vertices_0=other.vertices, faces_0=other.faces)
    again = decomposition.decompose(box.vertices, box.faces, "hull", tmp_path)
    assert not again.cached and len(again.warnings) == 1
    assert str(path) in again.warnings[0] and "recomputed" in again.warnings[0]
    assert all(np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
               for a, b in zip(again.parts, fresh.parts, strict=True))
    # The file was rewritten: the next call trusts it.
    third = decomposition.decompose(box.vertices, box.faces, "hull", tmp_path)
    assert third.cached and not third.warnings


def test_a_corrupt_cache_does_not_fail_the_models_stage_nor_change_its_shard(tmp_path):
    stage = ModelsStage()
    params = stage.Params(procedural_per_category=1, decomposition="hull")
    shards = [s for s in stage.planned(params, 0, {}) if s.item.item_id == "procedural/hammer_00"]
    store = ShardStore(tmp_path)
    first = run_stage(stage, shards, store)
    shard_bytes = store.shard_path("models", shards[0].key).read_bytes()
    (cached,) = (tmp_path / "cache" / "decompositions").glob("*.npz")
    cached.write_bytes(cached.read_bytes()[:100])
    again = run_stage(stage, shards, store, force=True)
    assert first.ok and again.ok and again.built == 1
    assert "recomputed" in again.warnings["procedural/hammer_00"][0]
    # The warning is about this build, not the model: it is neither a kept note nor in the shard.
    assert "procedural/hammer_00" not in again.notes
    assert store.shard_path("models", shards[0].key).read_bytes() == shard_bytes


@pytest.mark.parametrize(("text", "expected"), [
    ('category = "drill"\nlength = 0.3\n', "category = 'drill': unknown category 'drill'; expected one of ['knife'"),
    ('category = "knife"\nlength = -0.2\n', "length = -0.2: Input should be greater than 0"),
    ('category = "knife"\nlength = 0.2\nscale = 0.001\n',
     "give exactly one of length (real longest extent, m) and scale (mesh units to metres)"),
    ('category = "knife"\nlenght = 0.2\n', "lenght = 0.2: unknown key; see docs/models.md"),
])
def test_sidecar_mistakes_are_one_line_naming_file_key_and_value(tmp_path, text, expected):
    from osgd.models.user import SidecarError, read_sidecar  # noqa: PLC0415

    path = tmp_path / "tool.toml"
    path.write_text(text)
    with pytest.raises(SidecarError) as error:
        read_sidecar(path)
    assert error.value.file == str(path) and expected in error.value.cause
    assert str(error.value).startswith(f"{path}: ") and "\n" not in str(error.value)


def test_malformed_osgd_inputs_name_the_file(tmp_path):
    from osgd.errors import InputError  # noqa: PLC0415

    folder = tmp_path / "hammer_007"
    (folder / "model").mkdir(parents=True)
    (folder / "model" / "model_normalized.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n")
    with pytest.raises(InputError, match=r"model_normalized\.obj: trimesh cannot read it \(IndexError"):
        load_osgd_model(folder)
    (folder / "model" / "model_normalized.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (folder / "annotations").mkdir()
    (folder / "annotations" / "hammer.npy").write_bytes(b"not numpy")
    with pytest.raises(InputError, match=r"hammer\.npy: not a NumPy \.npy array"):
        load_osgd_model(folder)
    (folder / "annotations" / "hammer.npy").unlink()
    np.save(folder / "annotations" / "hammering.npy", np.zeros((2, 3)))
    with pytest.raises(InputError, match=r"hammering\.npy: annotation file stem 'hammering' names no task"):
        load_osgd_model(folder)
    wrong = tmp_path / "drill_001"
    folder.rename(wrong)
    with pytest.raises(InputError, match=r"drill_001: model folder 'drill_001' is not <category>_<number>"):
        load_osgd_model(wrong)
