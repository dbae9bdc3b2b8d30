"""The slicer's layout: stages in sub-packages that meet through their faces, and nothing of
the daemon imported by the slicer or the kinematics."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
STAGES = sorted(p.parent.name for p in (ROOT / "slicer").glob("*/__init__.py"))
PUBLIC_MODULES = {"slicer.gcode.markers"}  # imported by the daemon, without numpy


def _imports(path: Path) -> list[str]:
    """Every module ``path`` imports (``from a.b import c`` gives ``a.b.c`` and ``a.b``)."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            out += [node.module] + [f"{node.module}.{a.name}" for a in node.names]
    return out


def _module(path: Path) -> str:
    return ".".join(path.relative_to(ROOT).with_suffix("").parts)


@pytest.mark.parametrize("package", ["slicer", "kinematics"])
def test_the_geometry_never_imports_the_daemon(package: str) -> None:
    bad = [(_module(p), name) for p in sorted((ROOT / package).rglob("*.py"))
           for name in _imports(p) if name == "hostd" or name.startswith("hostd.")]
    assert bad == []


def test_stages_meet_through_their_faces() -> None:
    """A module of one stage takes another stage's names from its face (``slicer.paths``),
    never from one of its modules (``slicer.paths.layers``)."""
    assert set(STAGES) == {"decompose", "gcode", "mesh", "paths", "preview", "replay"}
    modules = {_module(p) for p in (ROOT / "slicer").rglob("*.py")}
    bad = []
    for path in sorted((ROOT / "slicer").rglob("*.py")):
        own = _module(path).split(".")[1] if path.parent != ROOT / "slicer" else None
        for name in _imports(path):
            parts = name.split(".")
            if (name in modules and len(parts) == 3 and parts[1] in STAGES
                    and parts[1] != own and name not in PUBLIC_MODULES):
                bad.append((_module(path), name))
    assert bad == []


def test_few_modules_stand_directly_in_the_slicer() -> None:
    assert len(list((ROOT / "slicer").glob("*.py"))) <= 12


@pytest.mark.parametrize("stage", STAGES)
def test_every_name_of_a_face_is_there(stage: str) -> None:
    face = importlib.import_module(f"slicer.{stage}")
    assert face.__doc__
    for name in face.__all__:
        value = getattr(face, name)
        if callable(value):  # a class or function of the stage's own modules
            assert value.__module__.startswith(f"slicer.{stage}."), name


def test_the_gcode_face_says_to_type_checkers_what_it_gives() -> None:
    """slicer.gcode imports its names on first use; its imports for type checkers (under
    ``TYPE_CHECKING``) must name the same names from the same modules."""
    import slicer.gcode as face

    tree = ast.parse((ROOT / "slicer" / "gcode" / "__init__.py").read_text())
    static = {a.name: node.module for node in ast.walk(tree)
              if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("slicer.")
              for a in node.names}
    assert static == {name: f"slicer.gcode.{module}"
                      for module, names in face._HOMES.items() for name in names}
    assert set(static) == set(face.__all__)
