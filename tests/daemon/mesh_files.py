"""Part files of other formats than STL, written by hand, for the tests of their reading."""

from __future__ import annotations

import io
import zipfile

import trimesh

CORE = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"


def three_mf(mesh: trimesh.Trimesh, unit: str | None, transforms: list[str]) -> bytes:
    """A 3MF written by hand: one object, a build item per transform (3MF's 3×4 row-major
    form), in ``unit`` (3MF's default, millimeter, when ``None``)."""
    verts = "".join(f'<vertex x="{x}" y="{y}" z="{z}"/>' for x, y, z in mesh.vertices)
    tris = "".join(f'<triangle v1="{a}" v2="{b}" v3="{c}"/>' for a, b, c in mesh.faces)
    items = "".join(f'<item objectid="1" transform="{t}"/>' for t in transforms)
    unit_attr = "" if unit is None else f' unit="{unit}"'
    model = (f'<?xml version="1.0" encoding="UTF-8"?><model{unit_attr} xmlns="{CORE}">'
             f'<resources><object id="1" type="model"><mesh><vertices>{verts}</vertices>'
             f"<triangles>{tris}</triangles></mesh></object></resources>"
             f"<build>{items}</build></model>")
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as archive:
        archive.writestr("[Content_Types].xml", "<Types/>")
        archive.writestr("3D/3dmodel.model", model)
    return buf.getvalue()


IDENTITY = "1 0 0 0 1 0 0 0 1 0 0 0"
