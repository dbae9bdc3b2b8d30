"""The benchmarks' finer meshes: the same solid with the face count asked for."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import trimesh

_SPEC = importlib.util.spec_from_file_location(
    "bench_harness", Path(__file__).resolve().parents[2] / "bench" / "harness.py")
assert _SPEC is not None and _SPEC.loader is not None
harness = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(harness)
HARD, finer, split_edges = harness.HARD, harness.finer, harness.split_edges


def _same_solid(fine: trimesh.Trimesh, mesh: trimesh.Trimesh) -> None:
    assert fine.is_watertight and fine.is_winding_consistent
    assert fine.volume == pytest.approx(mesh.volume, rel=1e-9)
    assert fine.area == pytest.approx(mesh.area, rel=1e-9)
    assert np.allclose(fine.bounds, mesh.bounds)


@pytest.mark.parametrize("seed", range(4))
def test_random_hulls_get_the_faces_asked_for_and_keep_their_solid(seed):
    rng = np.random.default_rng(seed)
    mesh = trimesh.convex.convex_hull(rng.normal(0.0, 10.0, (40, 3)))
    target = int(rng.integers(len(mesh.faces) + 1, 30 * len(mesh.faces)))
    fine = finer(mesh, target)
    assert target <= len(fine.faces) <= target + 1
    _same_solid(fine, mesh)


def test_split_edges_takes_the_longest_edges_two_faces_each():
    mesh = trimesh.creation.box([10.0, 1.0, 1.0])
    split = split_edges(mesh, 4)
    assert len(split.faces) == len(mesh.faces) + 8
    new = split.vertices[len(mesh.vertices):]
    assert np.allclose(np.abs(new[:, 0]), 0.0)  # midpoints of the 10 mm edges
    _same_solid(split, mesh)


@pytest.mark.skipif(not (HARD / "tee_low.stl").is_file(), reason="no shared/models/hard")
def test_a_hard_model_doubled_is_the_same_part():
    mesh = trimesh.load(HARD / "tee_low.stl", force="mesh")
    fine = finer(mesh, 10_000)
    double = finer(fine, 2 * len(fine.faces))
    assert len(fine.faces) == 10_000 and len(double.faces) == 20_000
    _same_solid(fine, mesh)
    _same_solid(double, mesh)
