"""A sub-part printed on another, its layers in a fixed direction where that overhangs less
than its skeleton's (slicer.paths.child_tilt)."""

from __future__ import annotations

import manifold3d as m3
import numpy as np
import pytest
import trimesh

from kinematics.machine import MachineGeometry
from slicer.decompose import Plane
from slicer.mesh import to_manifold, to_trimesh
from slicer.mesh.hard_samples import hard_variant
from slicer.paths import child_tilt
from slicer.paths.lean_costs import LEAN, hinge
from slicer.paths.skeleton import line_curve
from slicer.pipeline import slice_model
from slicer.replay.check import WALLS_HELD
from slicer.settings import ProcessSettings

UP = np.array([0.0, 0.0, 1.0])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _rod_with_a_wall(elevation: float) -> tuple[trimesh.Trimesh, Plane]:
    """A rod rising at ``elevation`` degrees from its base (the plane through the origin
    square to it) through a vertical slab facing back along -x, cut by the base: a branch's
    sub-part that took in a piece of the tube's wall. The rod wants layers square to it,
    the slab's inner face upright ones."""
    axis = np.array([np.cos(np.radians(elevation)), 0.0, np.sin(np.radians(elevation))])
    rod = trimesh.creation.cylinder(radius=4.0, height=50.0, sections=48)
    rod.apply_transform(trimesh.geometry.align_vectors(UP, axis))
    rod.apply_translation(20.0 * axis)
    slab = m3.Manifold.cube((2.0, 14.0, 20.0), center=True).translate((3.0, 0.0, 2.0))
    part = (to_manifold(rod) + slab).trim_by_plane(tuple(axis), 0.0)
    keep = to_trimesh(part)
    return keep, Plane(np.zeros(3), axis)


@pytest.mark.parametrize("seed", range(4))
def test_a_directions_price_is_the_hinged_area_of_each_face(seed: int) -> None:
    rng = np.random.default_rng(seed)
    mesh, base = _rod_with_a_wall(float(rng.uniform(15.0, 40.0)))
    dirs = _unit(rng.normal(size=(6, 3)))
    got = child_tilt.direction_prices(mesh, [base], dirs, LEAN)
    on_base = (np.abs(mesh.triangles_center @ base.normal) < 1e-6) & (
        mesh.face_normals @ base.normal < -0.99)
    for d, price in zip(dirs, got, strict=True):
        want = sum(a * float(hinge(np.array(float(n @ d)), LEAN.soft_deg, LEAN.hard_deg))
                   for n, a, cut in zip(mesh.face_normals, mesh.area_faces, on_base,
                                        strict=True) if not cut)
        assert price == pytest.approx(want, rel=1e-9, abs=1e-9)


def test_a_hinted_face_costs_its_weight_and_sooner() -> None:
    mesh, base = _rod_with_a_wall(30.0)
    d = _unit(np.array([[1.0, 0.0, 1.0]]))
    plain = child_tilt.direction_prices(mesh, [base], d, LEAN)[0]
    f = len(mesh.faces)
    doubled = child_tilt.direction_prices(mesh, [base], d, LEAN, (np.full(f, 2.0),
                                                                  np.zeros(f)))[0]
    stricter = child_tilt.direction_prices(mesh, [base], d, LEAN, (np.ones(f),
                                                                   np.full(f, 10.0)))[0]
    assert doubled == pytest.approx(2.0 * plain)
    assert stricter > plain


@pytest.mark.parametrize("elevation", [20.0, 28.0, 35.0])
def test_a_rod_with_a_wall_takes_a_direction_that_holds_both(elevation: float) -> None:
    mesh, base = _rod_with_a_wall(elevation)
    axis = np.array([np.cos(np.radians(elevation)), 0.0, np.sin(np.radians(elevation))])
    curve = line_curve(np.zeros(3), axis, 40.0)
    d = child_tilt.cheapest_direction(mesh, curve, base.normal, [base], LEAN)
    assert d is not None
    along = child_tilt.skeleton_price(mesh, curve, [base], LEAN)
    assert child_tilt.direction_prices(mesh, [base], d[None], LEAN)[0] <= \
        child_tilt.SHARE * along
    # the slab's inner face (-x) and the rod's underside are both held
    for n in (np.array([-1.0, 0.0, 0.0]), np.array([np.sin(np.radians(elevation)), 0.0,
                                                    -np.cos(np.radians(elevation))])):
        assert hinge(np.array(float(n @ d)), LEAN.soft_deg, LEAN.hard_deg) == 0.0


def test_a_plain_rod_keeps_its_skeleton() -> None:
    rod = trimesh.creation.cylinder(radius=4.0, height=30.0, sections=48)
    axis = _unit(np.array([1.0, 0.0, 0.6]))
    rod.apply_transform(trimesh.geometry.align_vectors(UP, axis))
    rod.apply_translation(15.0 * axis)
    base = Plane(np.zeros(3), axis)
    assert child_tilt.cheapest_direction(rod, line_curve(np.zeros(3), axis, 30.0), axis,
                                         [base], LEAN) is None


def test_a_branch_that_takes_in_the_tubes_rim_is_printed_support_free(tmp_path) -> None:
    """The sweep's pipe8 (branches at 27° and 32°, the upper one taking in the tube's rim):
    10–11 layers over air along its skeleton; the first leaning try holds every wall."""
    variant = hard_variant(8)
    assert variant.name == "pipe8_27_32"
    path = tmp_path / f"{variant.name}.stl"
    variant.mesh().export(path)
    res = slice_model(path, ProcessSettings(layer_height=0.2), MachineGeometry(),
                      allow_overhang=True, repair_rounds=1)
    rep = res.replay
    assert rep["unsupported_wall_layers"] == []
    assert float(rep["wall_supported"]) >= WALLS_HELD and rep["collisions"] == 0


def test_a_march_that_ends_short_of_the_sub_parts_far_end_is_not_taken() -> None:
    """A march stops at its first empty section; across a gap along a fixed normal the rest
    of the sub-part would never be printed, and the planner marches along the skeleton."""
    from types import SimpleNamespace

    from slicer.paths.planner import FAR_END, _reaches_the_end

    box = trimesh.creation.box(extents=(10.0, 10.0, 10.0))
    box.apply_translation((0.0, 0.0, 5.0))
    t = 0.2

    def last(z: float, normal: tuple[float, float, float]) -> list[SimpleNamespace]:
        n = _unit(np.asarray(normal, dtype=float))
        frame = np.vstack([np.zeros(3), np.zeros(3), n])
        return [SimpleNamespace(origin=np.array([0.0, 0.0, z]), frame=frame)]

    assert _reaches_the_end(box, last(10.0 - t, (0.0, 0.0, 1.0)), t)
    assert _reaches_the_end(box, last(10.0 - FAR_END * t + 1e-6, (0.0, 0.0, 1.0)), t)
    assert not _reaches_the_end(box, last(6.0, (0.0, 0.0, 1.0)), t)
    assert not _reaches_the_end(box, last(10.0 - t, (1.0, 0.0, 1.0)), t)  # a corner left
    assert not _reaches_the_end(box, [], t)
