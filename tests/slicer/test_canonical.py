"""The decomposition and the G-code are functions of the shape (QA finding 4).

The order of the faces and vertices in the file and the residue of a translation that the
placement undoes must not change the result. Variants are built in memory with trimesh
(float64): a copy written to a binary STL far from the origin is rounded to float32 there, a
different shape by up to 6e-5 mm, which no canonical order can undo.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from shared_models import MODELS

from kinematics.machine import MachineGeometry
from slicer.decompose.decomposition import DecomposeSettings, Decomposition, decompose
from slicer.mesh.checks import repair
from slicer.mesh.placement import canonical_mesh, place_on_platform
from slicer.mesh.read import read_stl
from slicer.pipeline import slice_model
from slicer.printhead import Printhead
from slicer.settings import ProcessSettings

HEAD = Printhead.default()
MACHINE = MachineGeometry()
SHIFT = np.array([1000.0, -500.0, 300.0])


def _shuffled(mesh: trimesh.Trimesh, seed: int) -> trimesh.Trimesh:
    """``mesh`` with its vertices and faces permuted and every face's corners rotated."""
    rng = np.random.default_rng(seed)
    pv = rng.permutation(len(mesh.vertices))
    new_index = np.argsort(pv)
    faces = new_index[mesh.faces[rng.permutation(len(mesh.faces))]]
    faces = np.roll(faces, 1, axis=1)  # same winding, another first corner
    return trimesh.Trimesh(mesh.vertices[pv], faces, process=False)


def _moved(mesh: trimesh.Trimesh, shift: np.ndarray) -> trimesh.Trimesh:
    return trimesh.Trimesh(mesh.vertices + shift, mesh.faces, process=False)


def _variants(name: str) -> dict[str, trimesh.Trimesh]:
    raw = read_stl(MODELS / f"{name}.stl")
    return {"original": raw, "shifted": _moved(raw, SHIFT),
            "shifted 1 µm": _moved(raw, np.array([1e-3, 0.0, 0.0])),
            "shuffled": _shuffled(raw, 5), "shifted and shuffled": _shuffled(_moved(raw, SHIFT), 6)}


def _same(a: Decomposition, b: Decomposition, what: str) -> None:
    assert len(a.subparts) == len(b.subparts), what
    for s, t in zip(a.subparts, b.subparts, strict=True):
        assert s.parent == t.parent, what
        assert abs(s.volume - t.volume) <= 1e-6 * s.volume, (what, s.volume, t.volume)
        cos = float(np.clip(np.dot(s.build_direction, t.build_direction), -1.0, 1.0))
        assert np.arccos(cos) <= 1e-6, (what, s.build_direction, t.build_direction)


@pytest.mark.parametrize("name", ["pipe2", "pipe3"])
def test_decomposition_ignores_face_order_and_placement(name: str) -> None:
    variants = _variants(name)
    results = {k: decompose(m, DecomposeSettings(), MACHINE, HEAD) for k, m in variants.items()}
    for what, dec in results.items():
        _same(results["original"], dec, f"{name} {what}")


def test_canonical_mesh_is_the_same_for_reordered_and_moved_copies() -> None:
    raw = read_stl(MODELS / "pipe2.stl")
    ref = place_on_platform(repair(raw))[0]
    for other in (_shuffled(raw, 1), _moved(raw, SHIFT), _shuffled(_moved(raw, -SHIFT), 2)):
        placed = place_on_platform(repair(other))[0]
        assert np.array_equal(placed.vertices, ref.vertices)
        assert np.array_equal(placed.faces, ref.faces)
    again = canonical_mesh(ref)  # idempotent: decompose canonicalises a placed mesh again
    assert np.array_equal(again.vertices, ref.vertices) and np.array_equal(again.faces, ref.faces)
    assert ref.is_watertight and ref.volume > 0


def test_gcode_of_a_translated_copy_is_the_same() -> None:
    raw = read_stl(MODELS / "pipe2.stl")
    a, b = (slice_model(m, ProcessSettings(), MACHINE, HEAD, check=False).lines
            for m in (raw, _shuffled(_moved(raw, SHIFT), 3)))
    assert len(a) == len(b)
    differ = [(x, y) for x, y in zip(a, b, strict=True) if x != y]
    # only the placement header (input frame -> platform frame) names where the file was
    assert all(x.startswith(";HOSTD_PLACEMENT") for x, _ in differ), differ[:3]
    assert len(differ) <= 1
