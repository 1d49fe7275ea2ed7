"""Automatic parts and true length for users' meshes: osgd/models/parts.py and the models stage."""

from __future__ import annotations

import json
import re
import warnings
from dataclasses import replace

import numpy as np
import pytest
import shapely
import trimesh

from osgd.contract.taxonomy import CATEGORIES, PART_INDEX, PARTS, UNKNOWN_PART
from osgd.grasps.labels import DEFAULT_RULES
from osgd.models import procedural
from osgd.models.parts import find_parts, parts_method, principal_frame, profiles, true_length
from osgd.models.stage import ModelsStage, item_rng
from osgd.stage import run_stage
from osgd.store import ShardStore

#: Share of the surface area whose automatic part must be the generator's.
AGREEMENT = 0.9


def _tool(category: str, index: int = 0) -> procedural.ProceduralModel:
    return procedural.generate(category, item_rng(0, f"procedural/{category}_{index:02d}"))


def _tilted(mesh: trimesh.Trimesh, seed: int) -> trimesh.Trimesh:
    """The mesh under a random rotation and a shift."""
    rng = np.random.default_rng(seed)
    transform = trimesh.transformations.random_rotation_matrix(rng.random(3))
    transform[:3, 3] = rng.uniform(-0.1, 0.1, 3)
    out = mesh.copy()
    out.apply_transform(transform)
    return out


def _scanned(mesh: trimesh.Trimesh, seed: int, max_edge: float = 0.003) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Remeshed to edges of at most ``max_edge``, every vertex moved by 0.2 mm noise, tilted: a scan's stand-in;
    and the face of ``mesh`` that each of its faces comes from."""
    vertices, faces, index = trimesh.remesh.subdivide_to_size(
        mesh.vertices, mesh.faces, max_edge=max_edge, max_iter=20, return_index=True
    )
    vertices = vertices + np.random.default_rng(seed).normal(0.0, 0.0002, vertices.shape)
    return _tilted(trimesh.Trimesh(vertices, faces, process=False), seed), index


def _remeshed(tool: procedural.ProceduralModel, seed: int) -> tuple[trimesh.Trimesh, np.ndarray]:
    """:func:`_scanned` at 3 mm edges, and each face's true part."""
    mesh, index = _scanned(tool.mesh, seed)
    return mesh, tool.face_parts[index]


def _agreement(mesh: trimesh.Trimesh, truth: np.ndarray, found: np.ndarray) -> float:
    return float(mesh.area_faces[truth == found].sum() / mesh.area_faces.sum())


@pytest.mark.parametrize("category", CATEGORIES)
def test_a_tilted_tool_gets_its_parts(category):
    tool = _tool(category)
    mesh = _tilted(tool.mesh, seed=CATEGORIES.index(category))
    found = find_parts(mesh, category)
    assert found.found and found.confidence >= 0.5
    assert _agreement(mesh, tool.face_parts, found.face_parts) >= AGREEMENT
    # The axis points from the handle to the working end, in the tilted mesh's frame.
    handle = mesh.triangles_center[tool.face_parts == PART_INDEX["handle"]].mean(axis=0)
    rest = mesh.triangles_center[tool.face_parts != PART_INDEX["handle"]].mean(axis=0)
    assert (rest - handle) @ found.axis > 0


@pytest.mark.parametrize("category", ["hammer", "fork", "toothbrush", "spatula", "pliers"])
def test_a_remeshed_noisy_tool_gets_its_parts(category):
    mesh, truth = _remeshed(_tool(category, 1), seed=7)
    found = find_parts(mesh, category)
    assert found.found
    assert _agreement(mesh, truth, found.face_parts) >= AGREEMENT


def test_every_automatic_part_is_one_the_label_rules_name():
    """Automatic parts only use parts that the grasps stage's rule of the category labels by."""
    for category in CATEGORIES:
        mesh = _tool(category).mesh
        used = {PARTS[part] for part in np.unique(find_parts(mesh, category).face_parts)}
        rule = DEFAULT_RULES[category]
        assert used <= {*rule.handle, *rule.working, "neck"}, (category, used)


def test_a_shape_without_the_parts_is_left_unknown_with_a_reason():
    box = trimesh.creation.box(extents=[0.3, 0.03, 0.02])
    found = find_parts(box, "hammer")
    assert not found.found and (found.face_parts == UNKNOWN_PART).all()
    assert "hammer" in found.note and "no head wider than the handle" in found.note and "[[parts]]" in found.note


def _along_x(*pieces: tuple[str, float, float, float]) -> trimesh.Trimesh:
    """Round pieces along x, each (kind, start, end, radius), m: a "cylinder", or a "cone" from ``radius`` at
    ``start`` to a point at ``end``."""
    meshes = []
    for kind, start, end, radius in pieces:
        if kind == "cylinder":
            piece = trimesh.creation.cylinder(radius=radius, height=end - start, sections=24)
            piece.apply_translation([0.0, 0.0, (end - start) / 2])
        else:
            piece = trimesh.creation.cone(radius=radius, height=end - start, sections=24)
        piece.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0.0, 1.0, 0.0]))
        piece.apply_translation([start, 0.0, 0.0])
        meshes.append(piece)
    return trimesh.util.concatenate(meshes)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_pen_tip_is_the_cone_not_a_narrow_plug_at_the_back(seed):
    """pen_003 of the authors' models: a narrow plug at the back is narrower than the tip over the last 8 %."""
    pen = _along_x(("cylinder", 0.0, 0.015, 0.002), ("cylinder", 0.014, 0.132, 0.005), ("cone", 0.132, 0.142, 0.005))
    mesh = _tilted(pen, seed)
    found = find_parts(mesh, "pen")
    assert found.found, found.note
    tip_faces = found.face_parts == PART_INDEX["tip"]
    tip_end = mesh.triangles_center[pen.triangles_center[:, 0].argmax()]
    assert np.linalg.norm(mesh.triangles_center[tip_faces].mean(axis=0) - tip_end) < 0.01
    assert (tip_end - mesh.triangles_center.mean(axis=0)) @ found.axis > 0


@pytest.mark.parametrize("seed", [0, 1])
def test_a_slender_pen_whose_cone_rises_in_pixel_steps_has_its_tip_at_the_cone(seed):
    """A 6 mm pen whose cone is a fifth of its length (procedural pen_06 stretched): its profile rises two
    pixels every eight columns or so, so few columns grow; the steps are small against the rise."""
    pen = _along_x(("cylinder", 0.0, 0.13, 0.003), ("cone", 0.13, 0.165, 0.003))
    mesh = _tilted(pen, seed)
    found = find_parts(mesh, "pen")
    assert found.found, found.note
    along = pen.triangles_center[:, 0]
    assert along[found.face_parts == PART_INDEX["tip"]].min() > 0.12
    assert along[found.face_parts == PART_INDEX["handle"]].max() < 0.15


def test_a_plug_with_a_short_shoulder_is_not_a_taper():
    """A narrow plug at the back a sixth of the pen long that widens to the body over 1.5 mm in small steps:
    the tip is still the cone at the front."""
    outline = [(0.0, 0.0), (0.002, 0.0), (0.002, 0.025), (0.005, 0.0265), (0.005, 0.132), (0.0, 0.142)]
    pen = trimesh.creation.revolve(np.array(outline), sections=32)
    pen.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0.0, 1.0, 0.0]))
    found = find_parts(_tilted(pen, 2), "pen")
    assert found.found, found.note
    along = pen.triangles_center[:, 0]
    assert along[found.face_parts == PART_INDEX["tip"]].min() > 0.12
    assert along[found.face_parts == PART_INDEX["handle"]].max() < 0.14


def test_a_capped_pen_has_its_tip_under_the_cap():
    """pen_005 of the authors' models: neither end tapers; the writing tip lies under the wider cap."""
    pen = _along_x(("cylinder", 0.0, 0.085, 0.004), ("cylinder", 0.08, 0.14, 0.0055))
    found = find_parts(pen, "pen")
    assert found.found, found.note
    centres = pen.triangles_center[:, 0]
    assert centres[found.face_parts == PART_INDEX["tip"]].min() > 0.075
    assert centres[found.face_parts == PART_INDEX["handle"]].max() < 0.085
    assert found.axis[0] > 0.99


def test_a_capped_pen_whose_cap_ends_in_a_long_rounded_rim_has_its_tip_under_the_cap():
    """The cap's end narrows over its last 5 mm (3.6 % of the length), narrower than the back there: the cap
    still runs back from its widest column."""
    pen = _along_x(("cylinder", 0.0, 0.085, 0.004), ("cylinder", 0.08, 0.135, 0.0055), ("cone", 0.135, 0.14, 0.0055))
    found = find_parts(_tilted(pen, 1), "pen")
    assert found.found, found.note
    centres = pen.triangles_center[:, 0]
    assert centres[found.face_parts == PART_INDEX["tip"]].min() > 0.075
    assert centres[found.face_parts == PART_INDEX["handle"]].max() < 0.085


@pytest.mark.parametrize("turn", [0.0, 30.0, 55.0])
def test_the_least_width_of_each_section_does_not_depend_on_the_turn_about_the_axis(turn):
    """A 120 x 12 x 8 mm bar turned about its axis and read in a fixed frame: every section's least width is
    8 mm (to the nearest pixel), though its twelve faces span the whole length and, turned, the frame's width
    and thickness both read more."""
    bar = trimesh.creation.box([0.12, 0.012, 0.008])
    bar.apply_transform(trimesh.transformations.rotation_matrix(np.radians(turn), [1.0, 0.0, 0.0]))
    fixed = replace(principal_frame(bar), axes=np.eye(3))
    seen = profiles(bar, fixed, least_width=True)
    inner = slice(2, seen.columns - 2)
    assert np.ptp(seen.least_width[inner]) == 0  # in whole pixels: a constant section reads constant
    assert abs(seen.least_width[inner][0] - 0.008) <= seen.pixel / 2
    if turn:
        assert np.minimum(seen.width, seen.thickness)[inner].min() > 0.010


def test_the_least_width_reads_the_same_in_the_frame_turned_a_quarter():
    mesh, _ = _remeshed(_tool("pen", 3), seed=4)
    frame = principal_frame(mesh)
    principal = profiles(mesh, frame, least_width=True).least_width
    assert np.array_equal(principal, profiles(mesh, frame.turned(), least_width=True).least_width)


def test_an_edge_along_a_column_border_leaves_no_column_empty():
    """A collar beginning exactly on a border between columns (a CAD mesh of round sizes, lying along its
    axis): its ring of edges lies on the border, which they cross nowhere; every column keeps its width."""
    pen = _along_x(("cylinder", 0.0, 0.050125, 0.004), ("cylinder", 0.050125, 0.1, 0.006))
    frame = replace(principal_frame(pen), axes=np.eye(3))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        seen = profiles(pen, frame, least_width=True)
    inner = seen.least_width[2:-2]
    assert inner.min() >= 0.008 - seen.pixel
    assert np.count_nonzero(np.diff(inner) != 0) == 1  # one step, at the collar


@pytest.mark.parametrize("seed", [0, 1])
def test_a_capped_pen_with_a_flat_body_has_its_tip_under_the_cap_whatever_its_clip_turns_the_frame_to(seed):
    """A 12 x 9 mm flat body under a round cap 12.6 mm across whose broad clip lies 40 degrees about the axis
    from the body's flat side: the surface faces turn the frame's thickness axis some 25 degrees off the body's
    thin side, where the body reads wider than the cap. The least width of each section shows the cap 1.4 times
    the body whatever the frame's turn."""
    body = trimesh.creation.box([0.085, 0.012, 0.009])
    body.apply_translation([0.0425, 0.0, 0.0])
    clip = trimesh.creation.box([0.05, 0.008, 0.0015])
    clip.apply_translation([0.11, 0.0, 0.0071])
    clip.apply_transform(trimesh.transformations.rotation_matrix(np.radians(40.0), [1.0, 0.0, 0.0]))
    pen = trimesh.util.concatenate([body, _along_x(("cylinder", 0.08, 0.14, 0.0063)), clip])
    mesh, _ = _scanned(pen, seed, max_edge=0.002)
    found = find_parts(mesh, "pen")
    assert found.found, found.note
    along = (mesh.triangles_center - mesh.triangles_center.mean(axis=0)) @ found.axis
    tip = found.face_parts == PART_INDEX["tip"]
    assert along[tip].min() > along.min() + 0.07
    assert along[~tip].max() < along.min() + 0.09


def _spoon_with_a_long_neck(length: float) -> tuple[trimesh.Trimesh, np.ndarray]:
    """A flat handle narrowest at a third of its length that widens slowly to an elliptic bowl at 0.62 of it
    (spoon_004 of the authors' models), and each face's true part."""
    bowl_start = 0.62 * length
    outline = shapely.Polygon([(0.0, -0.009), (length / 3, -0.0025), (bowl_start + 0.004, -0.0045),
                               (bowl_start + 0.004, 0.0045), (length / 3, 0.0025), (0.0, 0.009)])
    handle = trimesh.creation.extrude_polygon(outline, 0.004)
    bowl = trimesh.creation.icosphere(subdivisions=3)
    bowl.apply_scale([(length - bowl_start) / 2, 0.02, 0.008])
    bowl.apply_translation([(length + bowl_start) / 2, 0.0, 0.002])
    truth = np.concatenate([np.full(len(handle.faces), PART_INDEX["handle"]),
                            np.full(len(bowl.faces), PART_INDEX["bowl"])])
    return trimesh.util.concatenate([handle, bowl]), truth


def test_a_spoon_whose_neck_narrows_early_has_its_bowl_where_the_width_rises_to_it():
    """The narrowest point of the handle is at a third of the length; the bowl, at 0.62, is found there."""
    spoon, truth = _spoon_with_a_long_neck(0.18)
    mesh = _tilted(spoon, seed=3)
    found = find_parts(mesh, "spoon")
    assert found.found, found.note
    along = spoon.triangles_center[:, 0]
    assert along[found.face_parts == PART_INDEX["bowl"]].min() > 0.58 * 0.18
    assert _agreement(mesh, truth, found.face_parts) >= 0.95


def test_a_fork_whose_neck_is_barely_narrower_than_its_head_has_its_tines_from_the_plate():
    """A neck that widens from 9.2 to 10.7 mm over 25 mm onto the plate the tines stand on: 94 % of the head's
    width is reached 7 mm before the plate; the tines begin where the rise levels off."""
    plate_start, end = 0.145, 0.19
    outline = shapely.Polygon([(0.0, -0.0068), (0.12, -0.0046), (plate_start, -0.00535), (end, -0.00535),
                               (end, 0.00535), (plate_start, 0.00535), (0.12, 0.0046), (0.0, 0.0068)])
    flat = trimesh.creation.extrude_polygon(outline.difference(shapely.box(0.155, -0.0012, end + 0.001, 0.0012)),
                                            0.004)
    fork = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(flat.vertices, flat.faces, max_edge=0.001))
    found = find_parts(_tilted(fork, seed=4), "fork")
    assert found.found, found.note
    along = fork.triangles_center[:, 0]
    assert plate_start - 0.002 < along[found.face_parts == PART_INDEX["tines"]].min() < plate_start + 0.002
    assert along[found.face_parts == PART_INDEX["neck"]].max() < plate_start


def test_a_knife_with_a_long_blade_and_a_short_handle_has_its_blade_from_the_bolster():
    """A blade of 0.7 of the length (0.2 mm thinner than the handle's 16 mm) from a round handle of 0.3."""
    handle = _along_x(("cylinder", 0.0, 0.075, 0.008))
    blade = trimesh.creation.box(extents=[0.175, 0.03, 0.002])
    blade.apply_translation([0.075 + 0.175 / 2, 0.0, 0.0])
    knife = trimesh.util.concatenate([handle, blade])
    truth = np.concatenate([np.full(len(handle.faces), PART_INDEX["handle"]),
                            np.full(len(blade.faces), PART_INDEX["blade"])])
    mesh = _tilted(knife, seed=5)
    found = find_parts(mesh, "knife")
    assert found.found, found.note
    along = knife.triangles_center[:, 0]
    assert along[found.face_parts == PART_INDEX["blade"]].min() > 0.07
    assert along[found.face_parts == PART_INDEX["handle"]].max() < 0.08
    assert _agreement(mesh, truth, found.face_parts) >= 0.95


def test_a_pen_with_no_tip_and_no_cap_is_left_unknown():
    found = find_parts(_along_x(("cylinder", 0.0, 0.14, 0.005)), "pen")
    assert not found.found and "neither end tapers" in found.note


def test_true_length_of_a_diagonal_mesh():
    """A stick lying diagonally: its axis-aligned extent is short of its length (a scale from it oversizes it)."""
    turn = trimesh.transformations.euler_matrix(0.0, np.radians(20.0), np.radians(40.0))
    stick = trimesh.creation.box(extents=[0.2, 0.03, 0.02], transform=turn)
    assert stick.extents.max() < 0.17
    assert true_length(stick) == pytest.approx(0.2, rel=1e-3)
    assert abs(principal_frame(stick).axes[0] @ turn[:3, 0]) == pytest.approx(1.0, abs=1e-4)


# -- the models stage -------------------------------------------------------------------------------------


def _build_user(tmp_path, meshes: dict[str, tuple[trimesh.Trimesh, str]], files: dict[str, np.ndarray] | None = None,
                suffix: str = ".stl"):
    """Run the models stage on users' meshes (file stem -> (mesh, sidecar text)), with ``files`` (name -> array,
    saved as .npy) beside them; the rows by stem."""
    user_dir = tmp_path / "mine"
    user_dir.mkdir()
    for name, array in (files or {}).items():
        np.save(user_dir / name, array)
    for stem, (mesh, sidecar) in meshes.items():
        mesh.export(user_dir / f"{stem}{suffix}")
        (user_dir / f"{stem}.toml").write_text(sidecar)
    stage = ModelsStage()
    params = stage.Params(sources=["user"], user_dir=str(user_dir), decomposition="hull")
    store = ShardStore(tmp_path / "data")
    report = run_stage(stage, stage.planned(params, 0, {}), store)
    assert report.ok, report.failures
    rows = {}
    for record in report.records:
        table = store.read("models", record.key)
        rows[record.item_id.removeprefix("user/")] = table.to_pylist()[0] if table.num_rows else None
    return rows, report, stage.summary(store, report.records)


def _in_millimetres(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    out = mesh.copy()
    out.apply_scale(1000.0)
    return out


def test_a_user_mesh_with_only_category_and_length_gets_parts_and_its_true_length(tmp_path):
    tool = _tool("hammer", 2)
    mesh = _in_millimetres(_tilted(tool.mesh, seed=22))
    rows, _, summary = _build_user(tmp_path, {"scan": (mesh, 'category = "hammer"\nlength = 0.3\n')})
    row = rows["scan"]
    assert row["length"] == pytest.approx(0.3, rel=1e-9)
    stored = trimesh.Trimesh(np.array(row["vertices"]), np.array(row["faces"]), process=False)
    assert true_length(stored) == pytest.approx(0.3, rel=0.01)
    assert row["scale"] == pytest.approx(0.3 / true_length(mesh), rel=1e-6)
    provenance = json.loads(row["provenance"])
    assert provenance["parts"]["method"] == "automatic" and provenance["parts"]["confidence"] >= 0.5
    assert parts_method("user", provenance)[0] == "automatic"
    assert {PART_INDEX["handle"], PART_INDEX["head"]} <= set(row["face_parts"])
    assert "parts: 1 automatic" in summary and "without task labels" not in summary


def test_sidecar_regions_win_and_automatic_parts_fill_the_rest(tmp_path):
    tool = _tool("knife", 1)
    # A region that claims the blade's tip as "handle", against the geometry: the sidecar wins there.
    sidecar = (
        'category = "knife"\nscale = 1.0\n\n[[parts]]\npart = "handle"\n'
        "half_space = { point = [0.06, 0.0, 0.0], normal = [1.0, 0.0, 0.0] }\n"
    )
    rows, _, _ = _build_user(tmp_path, {"knife": (tool.mesh, sidecar)})
    row = rows["knife"]
    centres = trimesh.Trimesh(np.array(row["vertices"]), np.array(row["faces"]), process=False).triangles_center
    face_parts = np.array(row["face_parts"])
    claimed = centres[:, 0] >= 0.06
    assert claimed.any() and (face_parts[claimed] == PART_INDEX["handle"]).all()
    assert {PART_INDEX["handle"], PART_INDEX["blade"]} <= set(face_parts[~claimed])
    assert json.loads(row["provenance"])["parts"]["method"] == "sidecar+automatic"


def _stored_centres_and_parts(row: dict) -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.Trimesh(np.array(row["vertices"]), np.array(row["faces"]), process=False)
    return mesh.triangles_center, np.array(row["face_parts"])


def test_a_part_label_file_gives_each_face_its_part_and_regions_still_win(tmp_path):
    """Labels against the geometry (the handle end labelled head), so that only the file can explain them; a
    region claims the last centimetre; unlabelled faces (-1) get automatic parts."""
    mesh = _tool("hammer", 2).mesh
    x = mesh.triangles_center[:, 0]
    middle = float(np.median(x))
    labels = np.where(x < middle, 1, 0)  # 0: handle, 1: head
    labels[np.abs(x - middle) < 0.01] = -1
    sidecar = ('category = "hammer"\nscale = 1.0\n\n[part_labels]\nfile = "hammer.parts.npy"\n'
               'names = ["handle", "head"]\n\n[[parts]]\npart = "neck"\n'
               f"half_space = {{ point = [{x.max() - 0.01}, 0.0, 0.0], normal = [1.0, 0.0, 0.0] }}\n")
    rows, _, _ = _build_user(tmp_path, {"hammer": (mesh, sidecar)}, {"hammer.parts.npy": labels})
    centres, face_parts = _stored_centres_and_parts(rows["hammer"])
    region = centres[:, 0] >= x.max() - 0.01
    low, high = centres[:, 0] < middle - 0.012, (centres[:, 0] > middle + 0.012) & ~region
    assert (face_parts[low] == PART_INDEX["head"]).all() and (face_parts[high] == PART_INDEX["handle"]).all()
    assert region.any() and (face_parts[region] == PART_INDEX["neck"]).all()
    assert json.loads(rows["hammer"]["provenance"])["parts"]["method"] == "sidecar+automatic"


def test_part_labels_per_vertex_give_a_face_the_part_of_two_of_its_corners(tmp_path):
    mesh = _tool("screwdriver", 1).mesh
    labels = np.where(mesh.vertices[:, 0] > float(np.median(mesh.vertices[:, 0])), 0, 1)  # 0: shaft, 1: handle
    sidecar = ('category = "screwdriver"\nscale = 1.0\n\n[part_labels]\nfile = "s.npy"\n'
               'names = ["shaft", "handle"]\nper = "vertex"\n')
    rows, _, _ = _build_user(tmp_path, {"s": (mesh, sidecar)}, {"s.npy": labels}, suffix=".ply")
    corners = labels[mesh.faces]
    expected = np.where(corners.sum(axis=1) >= 2, PART_INDEX["handle"], PART_INDEX["shaft"])
    _, face_parts = _stored_centres_and_parts(rows["s"])
    assert len(face_parts) == len(mesh.faces) and (face_parts == expected).all()
    assert json.loads(rows["s"]["provenance"])["parts"]["method"] == "sidecar"


@pytest.mark.parametrize(("labels", "expected"), [
    (np.zeros(5, dtype=np.int64), r"s\.npy: expected \d+ integers, one per face of the mesh as trimesh reads it, got "
                                  r"an array of shape \(5,\)"),
    (None, r"s\.npy: label 2 of face 0: expected -1 \(unknown\) or 0-1, an index into names"),
])
def test_a_part_label_file_that_does_not_fit_fails_its_item_naming_it(tmp_path, labels, expected):
    mesh = _tool("knife", 0).mesh
    labels = np.full(len(mesh.faces), 2) if labels is None else labels
    sidecar = 'category = "knife"\nscale = 1.0\n\n[part_labels]\nfile = "s.npy"\nnames = ["handle", "blade"]\n'
    user_dir = tmp_path / "mine"
    user_dir.mkdir()
    np.save(user_dir / "s.npy", labels)
    mesh.export(user_dir / "s.stl")
    (user_dir / "s.toml").write_text(sidecar)
    stage = ModelsStage()
    params = stage.Params(sources=["user"], user_dir=str(user_dir), decomposition="hull")
    report = run_stage(stage, stage.planned(params, 0, {}), ShardStore(tmp_path / "data"))
    assert len(report.failures) == 1 and re.search(expected, report.failures[0].error), report.failures[0].error
    # the label file is part of the item's key: another file, another key
    first = stage.planned(params, 0, {})[0].key
    np.save(user_dir / "s.npy", np.zeros(len(mesh.faces), dtype=np.int64))
    assert stage.planned(params, 0, {})[0].key != first


def test_a_user_mesh_whose_parts_cannot_be_found_gets_a_note_and_is_counted(tmp_path):
    brick = _in_millimetres(trimesh.creation.box(extents=[0.25, 0.04, 0.03]))
    rows, report, summary = _build_user(tmp_path, {"brick": (brick, 'category = "hammer"\nlength = 0.25\n')})
    assert (np.array(rows["brick"]["face_parts"]) == UNKNOWN_PART).all()
    note = " ".join(report.notes["user/brick"])
    assert "automatic parts" in note and "no task" in note and "[[parts]]" in note
    assert json.loads(rows["brick"]["provenance"])["parts"]["method"] == "none"
    assert "1 models without task labels" in summary and "user/brick" in summary


def test_a_pliers_seen_edge_on_gets_its_arms():
    """Thick arms (their side walls outweigh their faces) make the principal frame see the pliers from its edge:
    the arms' gap lies along the thickness. The turned cross-section still shows the two arms."""
    tool = _tool("pliers")
    thick = tool.mesh.copy()
    thick.apply_scale([1.0, 1.0, 2.0])  # arms twice as thick, across z
    edge_on = thick.copy()
    edge_on.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1.0, 0.0, 0.0]))  # thin axis: width
    mesh = _tilted(edge_on, seed=3)
    frame = principal_frame(mesh)
    assert frame.extents[1] < frame.extents[2]  # the principal frame's width is the pliers' thickness
    found = find_parts(mesh, "pliers")
    assert found.found and found.confidence >= 0.5
    assert _agreement(mesh, tool.face_parts, found.face_parts) >= AGREEMENT
    handle = mesh.triangles_center[tool.face_parts == PART_INDEX["handle"]].mean(axis=0)
    jaws = mesh.triangles_center[tool.face_parts == PART_INDEX["jaws"]].mean(axis=0)
    assert (jaws - handle) @ found.axis > 0
