from __future__ import annotations

import numpy as np
import pytest
import trimesh
from shared_models import MODELS

from slicer.mesh import samples
from slicer.mesh.errors import MeshError
from slicer.mesh.read import load_mesh
from slicer.planes2d import TOL


@pytest.fixture(scope="module")
def pipe_bytes(tmp_path_factory):
    path = tmp_path_factory.mktemp("stl") / "pipe2.stl"
    samples.pipe2().export(path)
    return path.read_bytes()


def _write(tmp_path, name, data):
    path = tmp_path / name
    path.write_bytes(data)
    return path


def _refused(path, **kw):
    with pytest.raises(MeshError) as exc:
        load_mesh(path, **kw)
    msg = str(exc.value)
    assert "\n" not in msg and str(path) in msg
    return msg


def test_binary_and_ascii_load_to_the_same_placed_solid(tmp_path, pipe_bytes):
    binary, _ = load_mesh(_write(tmp_path, "b.stl", pipe_bytes))
    ascii_path = tmp_path / "a.stl"
    samples.pipe2().export(ascii_path, file_type="stl_ascii")
    text, _ = load_mesh(ascii_path)
    for mesh in (binary, text):
        assert mesh.is_watertight
        assert mesh.bounds[0, 2] == pytest.approx(0.0, abs=1e-6)
    assert binary.volume == pytest.approx(text.volume, rel=1e-6)


def test_placement_finds_the_flat_base_of_a_tilted_part(tmp_path):
    mesh = samples.pipe2()
    rot = trimesh.transformations.rotation_matrix(1.1, [1.0, 0.3, 0.0])
    rot[:3, 3] = (40.0, -7.0, 12.0)
    mesh.apply_transform(rot)
    path = tmp_path / "tilted.stl"
    mesh.export(path)
    placed, placement = load_mesh(path)
    assert placement.base_area == pytest.approx(np.pi * 16.0**2, rel=0.01)
    assert placed.bounds[0, 2] == pytest.approx(0.0, abs=1e-6)
    down = placed.face_normals[:, 2] < -0.999
    on_z0 = np.abs(placed.triangles_center[:, 2]) < 1e-4
    base = placed.triangles_center[down & on_z0]
    w = placed.area_faces[down & on_z0]
    assert np.average(base[:, :2], axis=0, weights=w) == pytest.approx([0.0, 0.0], abs=1e-6)
    back = trimesh.transform_points(mesh.vertices, placement.matrix)
    # placed vertices are snapped to TOL.snap_grid: within half of it of the matrix's image
    assert np.allclose(np.sort(back, axis=0), np.sort(placed.vertices, axis=0),
                       atol=1e-6 + TOL.snap_grid)


def test_empty_file(tmp_path):
    assert "empty" in _refused(_write(tmp_path, "e.stl", b""))


def test_truncated_binary(tmp_path, pipe_bytes):
    assert "truncated" in _refused(_write(tmp_path, "t.stl", pipe_bytes[:len(pipe_bytes) // 2]))


def test_header_only(tmp_path, pipe_bytes):
    assert "truncated" in _refused(_write(tmp_path, "h.stl", pipe_bytes[:84]))


def test_nan_vertex(tmp_path):
    text = samples.cylinder().export(file_type="stl_ascii")
    first = text.index("vertex") + len("vertex")
    end = text.index("\n", first)
    bad = text[:first] + " nan 0 0" + text[end:]
    assert "NaN" in _refused(_write(tmp_path, "n.stl", bad.encode()))


def test_not_watertight(tmp_path):
    mesh = samples.pipe2()
    open_mesh = trimesh.Trimesh(mesh.vertices, mesh.faces[:-5], process=False)
    path = tmp_path / "open.stl"
    open_mesh.export(path)
    assert "watertight" in _refused(path)


def test_too_big(tmp_path, pipe_bytes):
    msg = _refused(_write(tmp_path, "big.stl", pipe_bytes), build_volume=[30.0, 30.0, 30.0])
    assert "too big" in msg


def test_too_small(tmp_path):
    path = tmp_path / "small.stl"
    samples.cylinder(0.1, 0.2).export(path)
    assert "too small" in _refused(path, min_size=0.4)


def test_missing_file(tmp_path):
    assert "cannot read" in _refused(tmp_path / "nope.stl")


def test_trailing_bytes_after_a_binary_stl_are_ignored(tmp_path, pipe_bytes):
    whole, _ = load_mesh(_write(tmp_path, "b.stl", pipe_bytes))
    padded, _ = load_mesh(_write(tmp_path, "p.stl", pipe_bytes + b"\0\0padding"))
    assert np.array_equal(whole.vertices, padded.vertices)
    assert np.array_equal(whole.faces, padded.faces)


def test_an_ascii_name_in_another_encoding_loads(tmp_path):
    text = samples.cylinder().export(file_type="stl_ascii")
    latin = ("solid café\n" + text.split("\n", 1)[1]).encode("latin-1")
    utf8, _ = load_mesh(_write(tmp_path, "u.stl", text.encode()))
    named, _ = load_mesh(_write(tmp_path, "l.stl", latin))
    assert named.volume == pytest.approx(utf8.volume, rel=1e-9)


def test_an_ascii_stl_with_no_facets_has_no_triangles(tmp_path):
    assert "no triangles" in _refused(_write(tmp_path, "e.stl", b"solid x\nendsolid x\n"))


@pytest.mark.parametrize(("data", "told"), [
    (b"solid x\n", "ASCII STL with no facets and no endsolid (empty, or cut short after "
                   "line 1: 'solid x')"),
    (b"solid x\n\n  \n", "ASCII STL with no facets and no endsolid (empty, or cut short after "
                         "line 1: 'solid x')"),
    (b"solid x\n" + b"   \n" * 2000 + b"facet normal 0 0 1\n",  # the first facet far down
     "truncated ASCII STL: no endsolid after line 2002: 'facet normal 0 0 1'"),
])
def test_text_that_begins_with_solid_is_told_what_it_lacks(tmp_path, data, told):
    """Text from ``solid`` on is an ASCII STL (no binary STL is printable text: its
    triangle count would be over 500 million): refused for what it lacks, not as text that
    does not begin with 'solid'."""
    assert _refused(_write(tmp_path, "s.stl", data)).endswith(f"s.stl: {told}")


@pytest.mark.parametrize(("nth", "bad"), [(0, "vertx 1 2 3"), (9, "vertex 1.0 abc 3.0"),
                                          (40, "vertex 1 2")])
def test_a_syntax_error_names_its_line(tmp_path, nth, bad):
    lines = samples.cylinder().export(file_type="stl_ascii").splitlines()
    line = [i for i, text in enumerate(lines, 1) if "vertex" in text][nth]
    lines[line - 1] = "      " + bad
    msg = _refused(_write(tmp_path, "s.stl", "\n".join(lines).encode()))
    assert f"(line {line}: {bad!r})" in msg


def test_text_that_is_not_stl_is_named_so(tmp_path):
    text = b"Dear printer,\nplease make me a vase.\n" * 20
    assert "not an STL file" in _refused(_write(tmp_path, "letter.stl", text))


def test_an_obj_named_stl_is_read_as_the_obj_it_is(tmp_path):
    """Its content says OBJ (issue 36): its own faults are named, not an STL reader's."""
    obj = b"v 1 2 3\nv 2 3 4\nv 3 4 5\nf 1 2 3\n" * 20
    assert _refused(_write(tmp_path, "obj.stl", obj)).endswith(
        "obj.stl: all triangles are degenerate")


def test_infinite_coordinates_are_one_line_and_no_numpy_warning(tmp_path, recwarn):
    mesh = samples.cylinder()
    vertices = mesh.vertices.copy()
    vertices[3] = [np.inf, 0.0, -np.inf]
    path = tmp_path / "inf.stl"
    trimesh.Trimesh(vertices, mesh.faces, process=False).export(path)
    recwarn.clear()  # the export's own
    assert "infinite" in _refused(path)
    assert [w for w in recwarn if issubclass(w.category, RuntimeWarning)] == []


def _manifold_stl(tmp_path, name, solid):
    out = solid.to_mesh()
    path = tmp_path / name
    trimesh.Trimesh(out.vert_properties[:, :3], out.tri_verts).export(path)
    return path


def test_an_internal_cavity_is_named_as_such_in_the_files_coordinates(tmp_path):
    m3 = pytest.importorskip("manifold3d")
    cube = m3.Manifold.cube([20.0, 20.0, 20.0], True)
    hollow = (cube - m3.Manifold.cube([10.0, 10.0, 10.0], True)).translate([40.0, 7.0, 10.0])
    msg = _refused(_manifold_stl(tmp_path, "cavity.stl", hollow))
    assert "internal cavity (1e+03 mm³ near [40.0, 7.0, 10.0] mm)" in msg


def test_separate_bodies_are_located_in_the_files_coordinates(tmp_path):
    m3 = pytest.importorskip("manifold3d")
    two = m3.Manifold.cube([10.0, 10.0, 10.0]) + m3.Manifold.cube([4.0, 4.0, 4.0]).translate(
        [30.0, 0.0, 0.0])
    msg = _refused(_manifold_stl(tmp_path, "two.stl", two))
    assert "2 separate bodies (the smallest, 64 mm³ near [32.0, 2.0, 2.0] mm" in msg


def test_bodies_touching_along_an_edge_are_named_so(tmp_path):
    a = trimesh.creation.box([10.0, 10.0, 10.0])
    b = trimesh.creation.box([10.0, 10.0, 10.0])
    b.apply_translation([10.0, 10.0, 0.0])  # the two share one vertical edge
    path = tmp_path / "edge.stl"
    trimesh.util.concatenate([a, b]).export(path)
    msg = _refused(path)
    assert "not watertight after repair: 1 edge shared by more than two triangles" in msg
    assert "open edge" not in msg


def test_a_mesh_with_holes_counts_its_open_edges(tmp_path):
    mesh = samples.cylinder()
    path = tmp_path / "open.stl"
    trimesh.Trimesh(mesh.vertices, mesh.faces[:-1], process=False).export(path)
    assert "not watertight after repair: 3 open edges" in _refused(path)


@pytest.mark.parametrize("where", ["/dev/zero", "{tmp}"])
def test_what_is_not_a_regular_file_is_not_read(tmp_path, where):
    path = where.format(tmp=tmp_path)
    with pytest.raises(MeshError, match=r"not a regular file$"):
        load_mesh(path)


def test_a_part_too_small_to_stand_says_its_size(tmp_path):
    path = tmp_path / "tiny.stl"
    trimesh.creation.box([0.5, 0.5, 0.5]).export(path)
    msg = _refused(path)
    assert "no flat base of 1 mm² to stand on" in msg and "the part is 0.5 × 0.5 × 0.5 mm" in msg


def _boxes(*boxes: tuple[tuple[float, float, float], tuple[float, float, float]]
           ) -> trimesh.Trimesh:
    """Boxes of (extents, centre), concatenated without a union (as exporters write them)."""
    meshes = []
    for extents, centre in boxes:
        box = trimesh.creation.box(extents)
        box.apply_translation(centre)
        meshes.append(box)
    return trimesh.util.concatenate(meshes)


#: A 20 mm cube on z = 0 and a 10 × 10 × 30 mm post through its +x half: the post's bottom and
#: +x side lie in the cube's faces; they share 10 × 10 × 20 mm.
CUBE = ((20.0, 20.0, 20.0), (0.0, 0.0, 10.0))
POST = ((10.0, 10.0, 30.0), (5.0, 0.0, 15.0))
UNION_VOLUME = 20.0**3 + 10.0 * 10.0 * 30.0 - 10.0 * 10.0 * 20.0


@pytest.mark.parametrize("file_type", ["stl", "stl_ascii"])
def test_overlapping_shells_load_as_their_union(tmp_path, file_type):
    path = tmp_path / "overlap.stl"
    _boxes(CUBE, POST).export(path, file_type=file_type)
    mesh, placement = load_mesh(path)
    assert placement.merged_shells == 2
    assert mesh.is_watertight and mesh.body_count == 1
    assert mesh.volume == pytest.approx(UNION_VOLUME, rel=1e-9)
    assert mesh.extents == pytest.approx([20.0, 20.0, 30.0])
    assert placement.base_area == pytest.approx(400.0)


def test_a_shell_inside_another_is_absorbed(tmp_path):
    path = tmp_path / "nested.stl"
    _boxes(((30.0, 30.0, 30.0), (0.0, 0.0, 15.0)), ((10.0, 10.0, 10.0), (2.0, 3.0, 15.0))
           ).export(path)
    mesh, placement = load_mesh(path)
    assert placement.merged_shells == 2
    assert mesh.volume == pytest.approx(30.0**3, rel=1e-9)
    assert mesh.extents == pytest.approx([30.0, 30.0, 30.0])
    assert len(mesh.faces) == 12  # the outer box's own triangles: the inner one is gone


def test_shells_that_stay_apart_are_refused_as_separate_bodies(tmp_path):
    apart = ((4.0, 4.0, 4.0), (32.0, 2.0, 2.0))
    two, three = tmp_path / "two.stl", tmp_path / "three.stl"
    _boxes(CUBE, apart).export(two)
    _boxes(CUBE, POST, apart).export(three)
    assert ("the part is 2 separate bodies (the smallest, 64 mm³ near [32.0, 2.0, 2.0] mm, is "
            "not joined to the rest); one connected solid is needed") in _refused(two)
    # the cube and the post merge; the small box is still not joined to them
    msg = _refused(three)
    assert "the part is 2 separate bodies (the smallest, 64 mm³ near [32.0, 2.0, 2.0] mm" in msg


def test_an_inward_shell_inside_another_is_still_a_cavity(tmp_path):
    outer = trimesh.creation.box([30.0, 30.0, 30.0])
    inner = trimesh.creation.box([10.0, 10.0, 10.0])
    inner.invert()
    path = tmp_path / "cavity.stl"
    trimesh.util.concatenate([outer, inner]).export(path)
    assert "internal cavity (1e+03 mm³ near [0.0, 0.0, 0.0] mm)" in _refused(path)


BUILD_VOLUME = np.array([500.0, 500.0, 700.0])  # the default machine's travel


def test_pipe2_exported_in_inches_is_refused_with_the_hint(tmp_path):
    mesh = trimesh.load_mesh(MODELS / "pipe2.stl")
    mesh.apply_scale(1.0 / 25.4)
    path = tmp_path / "pipe2_inch.stl"
    mesh.export(path)
    msg = _refused(path, build_volume=BUILD_VOLUME, min_size=0.4)
    assert msg == (f"{path}: too thin to print: the part is 1.72 × 1.26 × 2.36 mm and nowhere "
                   "0.2 mm thick (half the 0.4 mm nozzle); was it exported in inches? ×25.4 it "
                   "would be 43.6 × 32.0 × 60.0 mm (STL files are read in millimetres)")


@pytest.mark.parametrize("thickness", [0.15, 0.35])
def test_the_inch_hint_needs_a_part_thinner_than_half_the_nozzle(tmp_path, thickness):
    plate = tmp_path / "plate.stl"
    trimesh.creation.box([5.0, 5.0, thickness]).export(plate)
    if thickness < 0.2:
        assert "exported in inches" in _refused(plate, build_volume=BUILD_VOLUME)
    else:
        load_mesh(plate, build_volume=BUILD_VOLUME)
    # ×25.4 too big for the machine: no hint, whatever the thickness
    placed, _ = load_mesh(plate, build_volume=BUILD_VOLUME / 30.0)
    assert placed.extents[2] == pytest.approx(thickness)


def test_a_2mm_cube_gets_no_inch_hint(tmp_path):
    path = tmp_path / "cube.stl"
    trimesh.creation.box([2.0, 2.0, 2.0]).export(path)
    mesh, _ = load_mesh(path, build_volume=BUILD_VOLUME)
    assert mesh.volume == pytest.approx(8.0)


def test_a_cut_ascii_stl_is_refused_naming_its_last_line(tmp_path):
    lines = samples.cylinder().export(file_type="stl_ascii").splitlines()
    cut = lines[:len(lines) // 2]
    msg = _refused(_write(tmp_path, "c.stl", "\n".join(cut).encode()))
    assert f"truncated ASCII STL: no endsolid after line {len(cut)}: {cut[-1].strip()!r}" in msg


def test_facets_after_the_last_endsolid_are_not_dropped_silently(tmp_path):
    """trimesh reads the facets up to the last ``endsolid``: a second solid cut short would
    be lost without a word."""
    text = samples.cylinder().export(file_type="stl_ascii")
    rest = "solid more\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n"
    msg = _refused(_write(tmp_path, "m.stl", (text + rest).encode()))
    assert f"no endsolid after line {len(text.splitlines()) + 4}: 'vertex 0 0 0'" in msg


def test_a_non_finite_ascii_vertex_is_named_by_its_line_not_a_nan_normal(tmp_path):
    """Some exporters write a NaN normal for a degenerate facet: the normals are recomputed,
    so the line named is the first non-finite vertex."""
    lines = samples.cylinder().export(file_type="stl_ascii").splitlines()
    vertex = [i for i, text in enumerate(lines) if "vertex" in text]
    normal = [i for i, text in enumerate(lines) if "normal" in text]
    lines[normal[0]] = "facet normal nan nan nan"
    lines[vertex[7]] = "vertex 1 inf 2"
    msg = _refused(_write(tmp_path, "n.stl", "\n".join(lines).encode()))
    assert msg.endswith(f"1 triangle corners have NaN or infinite coordinates (the first at "
                        f"line {vertex[7] + 1}: 'vertex 1 inf 2')")
