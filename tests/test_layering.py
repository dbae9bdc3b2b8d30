"""The layers of the source tree: who may import whom.

The domain (``hostd/jobs``, ``hostd/printer``, ``hostd/link``, and the bottom modules
``hostd/errors.py`` and ``hostd/events.py``) never imports the control socket or the command
line, which sit on top of it; ``slicer/`` and ``kinematics/`` import nothing of ``hostd``.
Every import counts, at module level or inside a function (a late import dodging a cycle is
still a dependency), ``TYPE_CHECKING`` blocks included: the modules' syntax trees are read,
nothing is imported.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOMAIN = ("hostd/jobs", "hostd/printer", "hostd/link", "hostd/errors.py", "hostd/events.py")
ABOVE_DOMAIN = ("hostd.control", "hostd.cli", "hostd.daemon", "hostd.main", "hostd.demo")
"""What the domain may not import: the control socket, the CLI and the daemon's wiring."""
PURE = ("slicer", "kinematics")
EMULATOR_SETTINGS = "hostd.sim.settings"
"""The one module of the emulator the link may import at module level (plain settings)."""


def modules(*where: str) -> list[Path]:
    """Every Python file under the given directories (or the files themselves)."""
    out: list[Path] = []
    for name in where:
        path = ROOT / name
        out += [path] if path.is_file() else sorted(path.rglob("*.py"))
    assert out, f"no modules under {where}"
    return out


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported(path: Path, top_level_only: bool = False) -> Iterator[tuple[int, str]]:
    """(line, dotted name) of every import in ``path`` (see :func:`imports_of`)."""
    return imports_of(path.read_text(), module_name(path), path.name == "__init__.py",
                      top_level_only)


def imports_of(source: str, module: str, is_package: bool = False,
               top_level_only: bool = False) -> Iterator[tuple[int, str]]:
    """(line, dotted name) of every import in the source of ``module``, relative ones
    resolved, ``from a import b`` as both ``a`` and ``a.b``; with ``top_level_only``, those
    that run when the module is imported (not those in a function)."""
    tree = ast.parse(source)
    nodes = _top_level(tree) if top_level_only else ast.walk(tree)
    package = module.split(".") if is_package else module.split(".")[:-1]
    for node in nodes:
        if isinstance(node, ast.Import):
            yield from ((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            name = ".".join([*base, *([node.module] if node.module else [])])
            yield node.lineno, name
            yield from ((node.lineno, f"{name}.{alias.name}") for alias in node.names)


def _top_level(tree: ast.Module) -> Iterator[ast.AST]:
    """The nodes that run at import time: everything outside function bodies and
    ``if TYPE_CHECKING:`` blocks."""
    todo: list[ast.AST] = [tree]
    while todo:
        node = todo.pop()
        yield node
        if isinstance(node, ast.If) and _names_type_checking(node.test):
            todo += node.orelse
            continue
        todo += [child for child in ast.iter_child_nodes(node)
                 if not isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda)]


def _names_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _within(name: str, packages: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in packages)


def _offences(paths: list[Path], forbidden: tuple[str, ...],
              top_level_only: bool = False) -> list[str]:
    return [f"{path.relative_to(ROOT)}:{line}: imports {name}"
            for path in paths for line, name in imported(path, top_level_only)
            if _within(name, forbidden)]


def test_the_domain_never_imports_the_control_socket_or_the_cli() -> None:
    assert _offences(modules(*DOMAIN), ABOVE_DOMAIN) == []


@pytest.mark.parametrize("package", PURE)
def test_the_slicer_and_kinematics_import_nothing_of_hostd(package: str) -> None:
    assert _offences(modules(package), ("hostd",)) == []


def test_the_link_loads_the_emulator_only_to_open_sim() -> None:
    """A printer's hostd never imports the firmware emulator: the link names it only inside
    the function that opens ``sim://`` and for type checking (its settings, plain values,
    aside)."""
    found = _offences(modules("hostd/link"), ("hostd.sim",), top_level_only=True)
    offences = [o for o in found
                if not o.endswith(EMULATOR_SETTINGS) and f"{EMULATOR_SETTINGS}." not in o]
    assert offences == []


def test_hostctl_imports_only_the_protocol_of_the_control_socket() -> None:
    """The client needs the error codes and the text checks, not the server's error table
    (which imports the whole domain): ``hostctl`` starts light."""
    light = ("hostd.control.codes", "hostd.control.text")
    offences = [o for o in _offences(modules("hostd/cli"), ("hostd.control",))
                if not any(o.endswith(f"imports {m}") or f"imports {m}." in o for m in light)]
    assert offences == []


def test_the_daemon_starts_without_the_emulator_loaded() -> None:
    """What the daemon imports to drive a printer leaves the emulator out (the ``hostd.sim``
    package itself imports none of its modules)."""
    probe = ("import sys, hostd.daemon; print(' '.join(sorted(m for m in sys.modules "
             "if m.startswith('hostd.sim.'))))")
    out = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout.split()
    assert out == [EMULATOR_SETTINGS]


SAMPLE = """
from __future__ import annotations
from typing import TYPE_CHECKING
from . import sibling
from ..control import rpc
if TYPE_CHECKING:
    from hostd.cli.main import main
def late() -> None:
    import hostd.daemon
"""


def test_the_walker_sees_every_kind_of_import() -> None:
    """A relative import, one under TYPE_CHECKING and a late one inside a function are all
    found; the last two do not run at import time."""
    every = {name for _, name in imports_of(SAMPLE, "hostd.jobs.sample")}
    top = {name for _, name in imports_of(SAMPLE, "hostd.jobs.sample", top_level_only=True)}
    assert {"hostd.jobs.sibling", "hostd.control.rpc", "hostd.cli.main.main",
            "hostd.daemon"} <= every
    assert every - top == {"hostd.daemon", "hostd.cli.main", "hostd.cli.main.main"}
    assert {name for _, name in imports_of(SAMPLE, "hostd.jobs", is_package=True)} >= {
        "hostd.jobs.sibling", "hostd.control.rpc"}
