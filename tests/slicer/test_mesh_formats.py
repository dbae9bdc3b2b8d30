"""3MF and OBJ input (issue 36, item 4): every build item with its transform, units honoured,
and formats hostd does not read refused as such, never with an STL reader's words."""

from __future__ import annotations

import io
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "daemon"))
from mesh_files import IDENTITY, three_mf

from slicer.mesh import MeshError, load_mesh, parse_mesh, sniff_format
from slicer.mesh.samples import cylinder


def test_every_3mf_build_item_is_read_with_its_transform_in_the_models_unit():
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    data = three_mf(box, "inch", [IDENTITY, "1 0 0 0 1 0 0 0 1 3 0 0"])
    mesh, fmt = parse_mesh(data, "two.3mf")
    assert fmt == "3mf" and len(mesh.faces) == 2 * len(box.faces)
    np.testing.assert_allclose(mesh.bounds, [[-12.7, -12.7, -12.7], [88.9, 12.7, 12.7]])


@pytest.mark.parametrize(("unit", "scale"), [(None, 1.0), ("millimeter", 1.0),
                                             ("centimeter", 10.0), ("micron", 0.001)])
def test_3mf_units_become_millimetres(unit, scale):
    mesh, _ = parse_mesh(three_mf(trimesh.creation.box((2.0, 2.0, 2.0)), unit, [IDENTITY]),
                         "box.3mf")
    np.testing.assert_allclose(mesh.extents, [2.0 * scale] * 3)


def test_a_3mf_sent_as_stl_is_read_as_3mf_not_refused_as_a_truncated_stl():
    """The regression of issue 36: ``--kind stl`` on a 3MF said "truncated binary STL:
    header declares 942491220 triangles"."""
    data = three_mf(trimesh.creation.box((5.0, 5.0, 5.0)), None, [IDENTITY])
    mesh, fmt = parse_mesh(data, "part.stl", "stl")
    assert fmt == "3mf" and len(mesh.faces) == 12


def test_obj_is_read_by_its_content_and_loads_as_a_part(tmp_path):
    part = cylinder(radius=8.0, height=20.0)
    text = trimesh.exchange.obj.export_obj(part)
    assert sniff_format(text.encode()) == "obj"
    path = tmp_path / "part.obj"
    path.write_text(text)
    placed, _ = load_mesh(path)
    assert placed.is_watertight
    np.testing.assert_allclose(placed.extents, part.extents, atol=1e-6)


def test_a_3mf_file_loads_as_a_part(tmp_path):
    path = tmp_path / "part.3mf"
    path.write_bytes(three_mf(cylinder(radius=8.0, height=20.0), None, [IDENTITY]))
    placed, _ = load_mesh(path)
    assert placed.is_watertight and placed.bounds[0][2] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize(("data", "named"), [
    (b"ply\nformat ascii 1.0\nelement vertex 3\n", "PLY"),
    (b"ISO-10303-21;\nHEADER;\n", "STEP"),
    (b"glTF\x02\x00\x00\x00" + bytes(40), "glTF (GLB)"),
    (b"<?xml version='1.0'?>\n<amf unit='millimeter'></amf>", "AMF"),
    (b"PK\x03\x04" + bytes(60), "ZIP archive (no 3D/3dmodel.model: not 3MF)"),
])
def test_formats_hostd_does_not_read_are_named_in_one_line(data, named):
    with pytest.raises(MeshError) as err:
        parse_mesh(data, "part.stl", "stl")
    assert str(err.value) == (f"part.stl: unsupported format: {named} (hostd reads STL, 3MF "
                              "and OBJ)")


def test_a_broken_3mf_is_one_line_naming_the_file():
    data = three_mf(trimesh.creation.box((1.0, 1.0, 1.0)), None, [IDENTITY])
    broken = data.replace(b"<build>", b"<build><item objectid=")  # not XML any more
    with pytest.raises(MeshError) as err:
        parse_mesh(broken, "bad.3mf")
    assert str(err.value).startswith("bad.3mf: ") and "\n" not in str(err.value)


def test_plain_stl_reading_is_unchanged():
    buf = io.BytesIO()
    trimesh.creation.box((3.0, 3.0, 3.0)).export(buf, file_type="stl")
    mesh, fmt = parse_mesh(buf.getvalue(), "box.stl", "obj")  # the content wins
    assert fmt == "stl" and len(mesh.faces) == 12
