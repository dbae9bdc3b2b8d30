"""A part given upside down: which flat face it stands on (``slicer.decompose.bases``,
``slicer.mesh``).

The reference pipes of ``/work/shared/models`` are turned as a user might have exported them:
180° about X (the base disc on top, the tube's top rim down), 135° about Y (pipe2's branch end
facing straight down), 90° about X (lying on its side, no flat bottom), and pipe3 with its
150° branch pointing down. Standing as placed, the first two are refused and the last one
overhangs 765 mm²; each must stand on its base disc instead, decomposed into valid sub-parts,
and say why. A part that stands well keeps its placement at no cost.
"""

from __future__ import annotations

import re

import manifold3d as m3
import numpy as np
import pytest
import trimesh
from decompose_checks import check_decomposition
from shared_models import MODELS

from kinematics.machine import MachineGeometry
from slicer.decompose.bases import decompose_on_bases, direction_text
from slicer.decompose.decomposition import DecomposeSettings, DecompositionError, decompose
from slicer.mesh import samples
from slicer.mesh.placement import _faces_on_plane, flat_bases, moved
from slicer.mesh.read import load_mesh
from slicer.planes2d import TOL
from slicer.printhead import Printhead

HEAD = Printhead.default()
MACHINE = MachineGeometry()
DISC = 803.7  # mm²: the base disc of pipe2 and pipe3 (R 16, 48 segments)
DOWN = np.array([0.0, 0.0, -1.0])


def rotation(name: str) -> np.ndarray:
    """The 4×4 turn a file was exported with."""
    if name == "x180":
        return trimesh.transformations.rotation_matrix(np.pi, [1.0, 0.0, 0.0])
    if name == "x90":
        return trimesh.transformations.rotation_matrix(np.pi / 2.0, [1.0, 0.0, 0.0])
    if name == "y135":  # pipe2's branch (45° up along +X) points straight down
        return trimesh.transformations.rotation_matrix(np.radians(135.0), [0.0, 1.0, 0.0])
    if name == "branch2down":  # pipe3's second branch (45° up at azimuth 150°) points down
        az = np.radians(150.0)
        axis = np.array([np.cos(az), np.sin(az), 1.0]) / np.sqrt(2.0)
        return trimesh.geometry.align_vectors(axis, DOWN)
    raise ValueError(name)


def exported(tmp_path, model: str, turn: str) -> tuple[str, np.ndarray]:
    """``model`` written as an STL turned by ``turn``; (path, 4×4 turn)."""
    mesh = trimesh.load_mesh(MODELS / f"{model}.stl")
    matrix = rotation(turn)
    mesh.apply_transform(matrix)
    path = tmp_path / f"{model}_{turn}.stl"
    mesh.export(path)
    return str(path), matrix


def on_bases(path: str, settings: DecomposeSettings | None = None):
    """(placed mesh as loaded, decomposition, the mesh it stands as)."""
    mesh, placement = load_mesh(path)
    dec = decompose_on_bases(mesh, settings or DecomposeSettings(), MACHINE, HEAD, None,
                             placement.matrix)
    assert dec.base is not None
    return mesh, dec, mesh if dec.base.turn is None else moved(mesh, dec.base.turn)


# --- the flat faces ---------------------------------------------------------------------------

@pytest.mark.parametrize("model", ["pipe2", "pipe3", "cylinder"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_flat_bases_are_the_hull_planes_regions_found_one_by_one(model, seed):
    """The vectorised search agrees with the face-by-face test of every hull plane."""
    mesh = trimesh.load_mesh(MODELS / f"{model}.stl")
    mesh.apply_transform(trimesh.transformations.random_rotation_matrix(
        np.random.default_rng(seed).random(3)))
    found = flat_bases(mesh)
    ranked = np.round([b.area for b in found], 6)  # equal to 1e-6 mm²: in the hull's order
    assert (np.diff(ranked) <= 0).all()
    for b in found:  # each region is what the face-by-face test finds on its plane
        faces, area = _faces_on_plane(mesh, b.normal)
        assert set(faces.tolist()) == set(b.faces.tolist())
        assert b.area == pytest.approx(area, rel=1e-9)
    normals = np.array([b.normal for b in found])
    areas = np.array([b.area for b in found])
    for normal in mesh.convex_hull.face_normals:  # no hull triangle's plane holds more: a
        area = _faces_on_plane(mesh, normal)[1]  # triangle of a facet may tilt by 0.005°,
        if area >= 1.0:  # 1 µm across a branch end, and hold part of the facet's region
            near = normals @ normal >= np.cos(np.radians(1.0))
            assert areas[near].max() >= area * (1.0 - 1e-9)
    if model != "cylinder":  # the base disc is the largest, wherever it faces
        assert found[0].area == pytest.approx(DISC, abs=0.1)
        assert found[0].normal @ (mesh.face_normals[found[0].faces].mean(axis=0)) > 0.999


# --- turned over ------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def turned(tmp_path_factory):
    """The cases the part as placed fails: {name: (file turn, loaded, decomposition, mesh)}."""
    out = {}
    for model, turn in [("pipe2", "x180"), ("pipe2", "y135"), ("pipe3", "branch2down")]:
        path, matrix = exported(tmp_path_factory.mktemp("flip"), model, turn)
        out[f"{model}_{turn}"] = (matrix, *on_bases(path))
    return out


@pytest.mark.parametrize("name", ["pipe2_x180", "pipe2_y135", "pipe3_branch2down"])
def test_a_part_exported_upside_down_stands_on_its_base_disc(turned, name):
    matrix, _, dec, mesh = turned[name]
    base = dec.base
    disc_in_file = matrix[:3, :3] @ DOWN  # the disc faced -Z before the file was turned
    assert base.turn is not None and base.area == pytest.approx(DISC, abs=0.1)
    assert base.normal @ disc_in_file > 0.9999
    assert dec.placement[:3, :3] @ base.normal == pytest.approx(DOWN, abs=1e-9)
    # the sub-parts are the part in the frame the placement gives: the file's mesh moved
    file_mesh = trimesh.load_mesh(MODELS / f"{name.split('_')[0]}.stl")
    file_mesh.apply_transform(matrix)
    bounds = np.vstack([s.mesh.bounds for s in dec.subparts])
    placed = trimesh.transform_points(file_mesh.vertices, dec.placement)
    assert bounds.min(axis=0) == pytest.approx(placed.min(axis=0), abs=1e-4)
    assert bounds.max(axis=0) == pytest.approx(placed.max(axis=0), abs=1e-4)
    assert bounds.min(axis=0)[2] == pytest.approx(0.0, abs=1e-6)
    check_decomposition(mesh, dec, HEAD, MACHINE.a_limits)
    assert dec.overhang_area <= max(TOL.overhang_retry_abs, TOL.overhang_retry_rel * mesh.area)
    assert len(base.tried) == 2 and base.tried[1].startswith(f"{base.area:.0f} mm² face")
    assert dec.to_json()["base"]["turned"] is True


@pytest.mark.parametrize(("name", "small", "degrees", "as_placed"), [
    ("pipe2_x180", 113, 180, r"was refused: sub-part \d overhangs \d+ mm²"),
    ("pipe2_y135", 75, 135, r"was refused: sub-part \d overhangs \d+ mm²"),
    ("pipe3_branch2down", 75, 135, r"overhangs 7\d\d mm² \(here 0 mm²\)$"),
])
def test_the_note_says_why_it_was_turned(turned, name, small, degrees, as_placed):
    base = turned[name][2].base
    assert "\n" not in base.note
    start = (f"turned to stand on its 804 mm² face (normal {direction_text(base.normal)} in "
             f"the file), {degrees}° from the file's orientation: standing as placed, on its "
             f"{small} mm² face (normal -Z in the file), it ")
    assert base.note.startswith(start), base.note
    assert re.search(as_placed, base.note[len(start):]), base.note


def test_the_file_turned_by_180_about_x_says_plus_z(turned):
    assert turned["pipe2_x180"][2].base.note.startswith(
        "turned to stand on its 804 mm² face (normal +Z in the file), 180°")


@pytest.mark.parametrize(("model", "turn"), [("pipe2", None), ("pipe3", "x90")])
def test_a_part_standing_well_keeps_its_placement_and_its_result(tmp_path, model, turn):
    """Upright, and on its side (no flat bottom: the loader already stands it on the disc),
    the result is decompose()'s first attempt, with nothing to say and no other face tried."""
    path = str(MODELS / f"{model}.stl") if turn is None else exported(tmp_path, model, turn)[0]
    loaded, placement = load_mesh(path)
    plain = decompose(loaded, DecomposeSettings(), MACHINE, HEAD, None, placement.matrix)
    dec = decompose_on_bases(loaded, DecomposeSettings(), MACHINE, HEAD, None,
                             placement.matrix)
    assert dec.base is not None
    assert dec.base.turn is None and dec.base.note is None and len(dec.base.tried) == 1
    assert dec.base.area == pytest.approx(DISC, abs=0.1) and len(plain.attempts) == 1
    assert [s.volume for s in dec.subparts] == [s.volume for s in plain.subparts]
    assert np.array_equal(dec.placement, plain.placement) and "other_bases" not in dec.timings


def test_refused_on_every_face_is_one_line_naming_each(tmp_path):
    """A spool (stem r 4, caps r 15 at mid-height and on top) overhangs by a cap either way."""
    solid = (m3.Manifold.cylinder(30, 4, 4, 48)
             + m3.Manifold.cylinder(5, 15, 15, 48).translate([0, 0, 10])
             + m3.Manifold.cylinder(5, 15, 15, 48).translate([0, 0, 25]))
    path = tmp_path / "spool.stl"
    samples.to_trimesh(solid).export(path)
    with pytest.raises(DecompositionError) as err:
        on_bases(str(path))
    message = str(err.value)
    assert "\n" not in message
    assert re.match(r"sub-part 0 overhangs \d+ mm² .*, standing as placed on its 50 mm² face "
                    r"\(normal -Z in the file\); on its 70\d mm² face \(normal \+Z in the "
                    r"file\) it is refused too: sub-part 0 overhangs \d+ mm²", message), message


def test_a_fixed_root_pins_the_placement_and_names_the_larger_face(tmp_path):
    path, _ = exported(tmp_path, "pipe2", "x180")
    with pytest.raises(DecompositionError) as err:
        on_bases(path, DecomposeSettings(root=0))
    message = str(err.value)
    assert "\n" not in message
    assert message.endswith(
        "; the part stands on a 113 mm² face; its largest flat face (804 mm², normal +Z in the "
        "file) is 7.1× larger and may decompose: turn the part to stand on it, or leave the "
        "root region automatic (no --root) so the slicer tries it"), message


def test_a_part_on_a_small_foot_keeps_it_with_a_warning(tmp_path):
    """The Γ bracket decomposes standing on its column (100 mm²); its side is 560 mm²."""
    solid = m3.Manifold.cube([10, 10, 40]) + m3.Manifold.cube([30, 10, 8]).translate([0, 0, 32])
    path = tmp_path / "gamma.stl"
    samples.to_trimesh(solid).export(path)
    loaded, dec, _ = on_bases(str(path))
    plain = decompose(loaded, DecomposeSettings(), MACHINE, HEAD, None, np.eye(4))
    assert dec.base.turn is None and len(dec.base.tried) == 1
    assert [s.volume for s in dec.subparts] == [s.volume for s in plain.subparts]
    assert dec.base.note == (
        "the part stands on a 100 mm² face; its largest flat face (560 mm², normal -Y in the "
        "file) is 5.6× larger: turn the part to stand on it for a steadier print")


def test_the_choice_depends_on_the_shape_not_the_face_order(tmp_path):
    """The mushroom (stem r 4 down, cap r 15 on top) is refused standing on its stem and
    stands on its cap; a copy with its faces shuffled gives the same placement and parts."""
    solid = (m3.Manifold.cylinder(20, 4, 4, 48)
             + m3.Manifold.cylinder(5, 15, 15, 48).translate([0, 0, 20]))
    mesh = samples.to_trimesh(solid)
    order = np.random.default_rng(7).permutation(len(mesh.faces))
    shuffled = trimesh.Trimesh(mesh.vertices, mesh.faces[order], process=False)
    results = []
    for name, part in (("a", mesh), ("b", shuffled)):
        path = tmp_path / f"{name}.stl"
        part.export(path)
        results.append(on_bases(str(path))[1])
    a, b = results
    assert a.base.turn is not None and a.base.note.startswith(
        "turned to stand on its 705 mm² face (normal +Z in the file), 180°")
    # the matrix's translation keeps a 1e-16 residue of the summation order (as before);
    # the meshes it gives are snapped to the grid, so the sub-parts are the same
    assert np.allclose(a.placement, b.placement, rtol=0.0, atol=1e-12)
    assert a.base.note == b.base.note and a.base.tried == b.base.tried
    for x, y in zip(a.subparts, b.subparts, strict=True):
        assert np.array_equal(x.mesh.vertices, y.mesh.vertices)


# --- the rule ---------------------------------------------------------------------------------

def _outcome(area: float, normal, overhang: float | None):
    """A face tried, with a decomposition overhanging ``overhang`` mm² (None: refused)."""
    from slicer.decompose.bases import _Outcome
    from slicer.decompose.decomposition import Decomposition
    from slicer.decompose.overhang import Overhang
    from slicer.mesh.placement import FlatBase

    result = None if overhang is None else Decomposition(
        np.eye(4), [], [], 1.0, {}, 1, 1, overhang=[Overhang(0, overhang, None)])
    n = np.asarray(normal, dtype=float)
    return _Outcome(FlatBase(n, area, np.zeros(0, dtype=np.int64)), n, None, result,
                    "" if result else "no plane")


@pytest.mark.parametrize(("own", "others", "kept"), [
    (40.0, [35.5], 0),  # better by less than the retry threshold (5 mm²): as placed
    (40.0, [35.0], 0),  # by exactly the threshold: as placed
    (40.0, [34.9], 1),
    (40.0, [34.9, 10.0], 2),  # the least overhang of the others
    (40.0, [None, 10.0], 2),
    (None, [None, 60.0], 2),  # refused as placed: any face that decomposes
    (None, [20.0, 20.0], 1),  # equal overhang: the larger face (tried first)
    (40.0, [None, None], 0),
])
def test_another_face_wins_only_when_it_overhangs_clearly_less(own, others, kept):
    from slicer.decompose.bases import _best

    surface = trimesh.creation.box([5.0, 5.0, 5.0])  # 150 mm²: retry threshold max(5, 1.5)
    tried = [_outcome(50.0, [0, 0, -1], own)] + [
        _outcome(800.0 - 100.0 * i, [0, 0, 1], o) for i, o in enumerate(others)]
    assert _best(tried, surface) is tried[kept]


def test_a_part_kept_as_placed_after_trying_says_what_was_tried():
    from slicer.decompose.bases import _stayed_note
    from slicer.mesh.placement import FlatBase

    first = _outcome(50.0, [0, 0, -1], 40.0)
    other = _outcome(800.0, [0, 0, 1], None)
    note = _stayed_note(first, [other], [FlatBase(np.array([0.0, 0.0, 1.0]), 800.0,
                                                  np.zeros(0, dtype=np.int64))], np.eye(3))
    assert note == ("the part stands on a 50 mm² face; its largest flat face (800 mm², normal "
                    "+Z in the file) is 16.0× larger; tried standing on 800 mm² face (normal +Z "
                    "in the file): refused: no plane; it stands as placed (overhang 40 mm²)")
