"""Skeleton curve: arc-length spline, MCF on straight and bent parts, fallbacks."""

from __future__ import annotations

import manifold3d as m3
import numpy as np
import pytest
import trimesh

from slicer.mesh.samples import to_trimesh
from slicer.paths.skeleton import fit_curve, line_curve, main_chain, skeleton_curve


def _bent_tube(bend_deg: float = 90.0, radius: float = 5.0, bend: float = 30.0,
               hollow: bool = False) -> trimesh.Trimesh:
    """A torus arc from the origin heading +Z, bending towards +X (optionally hollow)."""
    ring = m3.CrossSection.circle(radius, 48).translate((bend, 0.0))
    arc = m3.Manifold.revolve(ring, 48, bend_deg)
    if hollow:
        bore = m3.Manifold.revolve(m3.CrossSection.circle(radius - 1.5, 48)
                                   .translate((bend, 0.0)), 48, bend_deg + 10)
        arc = arc - bore
    # revolve is about +Z from +X to +Y; map it so it starts at the origin heading +Z
    mat = np.array([[-1.0, 0.0, 0.0, bend], [0.0, 0.0, 1.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
    return to_trimesh(arc.transform(mat))


def test_arc_length_round_trip() -> None:
    t = np.linspace(0, np.pi, 40)
    curve = fit_curve(np.column_stack([10 * np.cos(t), 10 * np.sin(t), 3 * t]))
    s = np.linspace(0, curve.length, 57)
    assert np.allclose(curve.s_of_u(curve.u_of_s(s)), s, atol=1e-9)
    p = curve.point(s)
    assert np.allclose(curve.project(p), s, atol=curve.length / 1000)
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    assert np.allclose(step, s[1] - s[0], rtol=2e-3)  # arc length, not the spline parameter
    assert np.allclose(np.linalg.norm(curve.tangent(s), axis=1), 1.0)


def test_vertical_line_fit_works_where_the_papers_fit_breaks() -> None:
    curve = line_curve([1.0, 2.0, 0.0], [0.0, 0.0, 1.0], 20.0)
    assert np.allclose(curve.point([0.0, 10.0, 25.0]), [[1, 2, 0], [1, 2, 10], [1, 2, 25]])
    assert np.allclose(curve.tangent([5.0]), [[0, 0, 1]])


def test_main_chain_is_the_longest_path_from_the_start() -> None:
    a, b, c, d = np.eye(3)[0] * 0, np.array([0, 0, 5.0]), np.array([0, 0, 10.0]), [2, 0, 5.0]
    edges = np.array([[a, b], [b, c], [b, d]], dtype=float)
    chain = main_chain(edges, [0.1, 0, -1])
    assert np.allclose(chain, [a, b, c])
    assert len(main_chain(np.zeros((0, 2, 3)), a)) == 0


def test_straight_cylinder_skeleton_is_its_axis() -> None:
    mesh = to_trimesh(m3.Manifold.cylinder(40.0, 6.0, 6.0, 48).translate((3.0, -2.0, 0.0)))
    curve = skeleton_curve(mesh, [3.0, -2.0, 0.0], [0.0, 0.0, 1.0])
    assert curve.source == "axis"
    s = np.linspace(0, curve.length, 9)
    assert np.allclose(curve.point(s)[:, :2], [3.0, -2.0], atol=1e-6)
    assert curve.length == pytest.approx(40.0, abs=1e-6)


@pytest.mark.parametrize("hollow", [False, True])
def test_bent_tube_skeleton_follows_the_bend(hollow: bool) -> None:
    mesh = _bent_tube(hollow=hollow)
    curve = skeleton_curve(mesh, [0.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    assert curve.source == "mcf"
    s = np.linspace(0.0, curve.length, 25)
    p = curve.point(s)
    # distance from the bend centre (30, *, 0) in the XZ plane stays near the bend radius
    r = np.hypot(p[:, 0] - 30.0, p[:, 2])
    assert np.abs(r[2:-2] - 30.0).max() < 3.0
    assert abs(p[:, 1]).max() < 1.0
    assert curve.tangent([curve.length])[0][0] > 0.8  # ends heading +X after the 90° bend
