"""Overhang of a decomposition, and what the decomposition does about it.

The measure (``slicer.decompose.overhang``) is checked against hand-computed areas on boxes and
a T; the decomposition against the QA's Γ bracket and mushroom (built here with manifold3d):
the Γ bracket's arm must not stay in the root for any seed, no sub-part may be degenerate, the
mushroom (no plane decomposition exists) must be refused naming the overhang and a point on the
part, and the sample pipes must keep today's result on the first attempt.
"""

from __future__ import annotations

import re

import manifold3d as m3
import numpy as np
import pytest
import trimesh

from kinematics.machine import MachineGeometry
from slicer.decompose.buildorder import root_region
from slicer.decompose.decomposition import DecomposeSettings, DecompositionError, decompose
from slicer.decompose.overhang import decomposition_overhang, subpart_overhang
from slicer.decompose.partition import coarse_partition
from slicer.decompose.planes import Plane
from slicer.mesh import samples
from slicer.mesh.checks import repair
from slicer.mesh.placement import place_on_platform
from slicer.planes2d import TOL
from slicer.printhead import Printhead

HEAD = Printhead.default()
MACHINE = MachineGeometry()
UP = np.array([0.0, 0.0, 1.0])
X = np.array([1.0, 0.0, 0.0])


def box(lo: tuple[float, float, float], size: tuple[float, float, float]) -> m3.Manifold:
    return m3.Manifold.cube(list(size)).translate(list(lo))


def gamma() -> trimesh.Trimesh:
    """The QA's Γ bracket: a 10×10×40 column with a 30×10×8 arm on top, placed."""
    solid = box((0, 0, 0), (10, 10, 40)) + box((0, 0, 32), (30, 10, 8))
    return place_on_platform(repair(samples.to_trimesh(solid)))[0]


def mushroom() -> trimesh.Trimesh:
    """The QA's mushroom: stem r 4 h 20, cap r 15 h 5 on top, placed."""
    solid = (m3.Manifold.cylinder(20, 4, 4, 48)
             + m3.Manifold.cylinder(5, 15, 15, 48).translate([0, 0, 20]))
    return place_on_platform(repair(samples.to_trimesh(solid)))[0]


def overhangs(dec) -> list[float]:
    """Overhang per sub-part, measured again here on the returned meshes."""
    return [o.area for o in decomposition_overhang(
        [s.mesh for s in dec.subparts], [s.parent for s in dec.subparts],
        [s.base_plane for s in dec.subparts], [s.build_direction for s in dec.subparts])]


def on_surface(mesh: trimesh.Trimesh, point: np.ndarray) -> float:
    """Distance from ``point`` to the surface of ``mesh`` (brute force, no spatial index)."""
    near = trimesh.triangles.closest_point(mesh.triangles, np.repeat([point], len(mesh.faces), 0))
    return float(np.linalg.norm(near - point, axis=1).min())


def named_point(message: str) -> np.ndarray:
    found = re.search(r"near \[([-\d.]+), ([-\d.]+), ([-\d.]+)\]", message)
    assert found, message
    return np.array([float(v) for v in found.groups()])


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


# --- the decomposition -----------------------------------------------------------------------

@pytest.fixture(scope="module")
def gamma_mesh() -> trimesh.Trimesh:
    return gamma()


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4, 5])
def test_gamma_bracket_arm_does_not_print_in_the_air(gamma_mesh, seed):
    """QA finding 1: seeds 0 and 1 kept the arm (200 mm² at 90°) in the root, 2/4/5 refused."""
    dec = decompose(gamma_mesh, DecomposeSettings(seed=seed), MACHINE, HEAD, None, np.eye(4))
    small = max(TOL.overhang_retry_abs, TOL.overhang_retry_rel * gamma_mesh.area)
    assert len(dec.subparts) == 2
    assert max(overhangs(dec)) <= small
    assert overhangs(dec) == pytest.approx([o.area for o in dec.overhang])
    total = sum(s.volume for s in dec.subparts)
    assert total == pytest.approx(gamma_mesh.volume, rel=1e-4)
    arm = dec.subparts[1]  # the arm beyond the column prints sideways, along ±X
    assert abs(arm.build_direction[0]) > 0.9
    assert arm.volume > 0.25 * (20 * 10 * 8)


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4, 5])
def test_no_degenerate_sub_part(gamma_mesh, seed):
    """QA finding 2: seed 0 cut a 6e-5 mm³ sliver (base 0.038 mm²) off the arm's tip."""
    dec = decompose(gamma_mesh, DecomposeSettings(seed=seed), MACHINE, HEAD, None, np.eye(4))
    volume = gamma_mesh.volume
    for s in dec.subparts[1:]:
        assert s.volume >= TOL.min_volume_share * volume
        assert s.base_area >= TOL.min_base_share * volume ** (2 / 3)


def test_degenerate_cut_is_merged_back_not_kept(gamma_mesh):
    """Seed 0's own partition (no retries with a fixed root): the sliver is not a sub-part."""
    part = coarse_partition(gamma_mesh, None, 0)
    settings = DecomposeSettings(seed=0, root=root_region(part))
    with pytest.raises(DecompositionError, match="overhangs 200 mm²"):
        decompose(gamma_mesh, settings, MACHINE, HEAD, None, np.eye(4))


def test_refusal_names_a_point_on_the_part(gamma_mesh):
    """QA finding 2: seed 2's refusal named [25.6, 2.2, 18.3], a point in empty space."""
    part = coarse_partition(gamma_mesh, None, 2)
    settings = DecomposeSettings(seed=2, root=root_region(part))
    with pytest.raises(DecompositionError) as err:
        decompose(gamma_mesh, settings, MACHINE, HEAD, None, np.eye(4))
    assert on_surface(gamma_mesh, named_point(str(err.value))) < 0.1


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4, 5])
def test_mushroom_is_refused_naming_the_overhang_or_its_cap_is_cut_off(seed):
    """QA finding 1: seed 3 printed the cap's 655 mm² underside in the air. Now the cap's
    underside is either named in a refusal (more overhang than the limit left on the stem),
    or the cap is cut into sub-parts printed sideways and the stem keeps less than the
    limit (seed 4, since a group hung on a sibling moves to the junction)."""
    mesh = mushroom()
    limit = max(TOL.overhang_refuse_abs, TOL.overhang_refuse_rel * mesh.area)
    try:
        dec = decompose(mesh, DecomposeSettings(seed=seed), MACHINE, HEAD, None, np.eye(4))
    except DecompositionError as err:
        message = str(err)
        assert "\n" not in message
        found = re.search(r"sub-part 0 overhangs (\d+) mm²", message)
        assert found and float(found.group(1)) > limit, message
        point = named_point(message)
        assert on_surface(mesh, point) < 0.1
        assert point[2] == pytest.approx(20.0, abs=0.1)  # the cap's underside
        return
    from decompose_checks import check_decomposition

    check_decomposition(mesh, dec, HEAD, MACHINE.a_limits)
    assert len(dec.subparts) > 1
    assert max(o.area for o in dec.overhang) <= limit


# Results of the first attempt (sub-part volumes, mm³): the sample pipes pass first time.
# Since the canonical mesh order (QA finding 4) they are those of the shape itself; before:
# pipe2 0: 9523.72, 550.42; 3: 9525.3, 548.83; pipe3 0: 10310.47, 459.43, 525.4;
# 3: 10217.15, 641.69, 436.46.
KNOWN = {("pipe2", 0): [9397.13, 677.0], ("pipe2", 3): [9882.14, 191.99],
         ("pipe3", 0): [10294.31, 488.61, 512.38], ("pipe3", 3): [10650.05, 401.62, 243.63],
         ("cylinder", 0): [18836.1]}


@pytest.mark.parametrize(("name", "seed"), sorted(KNOWN))
def test_shared_models_pass_on_the_first_attempt_unchanged(name, seed):
    from shared_models import MODELS

    from slicer.mesh.read import load_mesh

    mesh, placement = load_mesh(MODELS / f"{name}.stl")
    dec = decompose(mesh, DecomposeSettings(seed=seed), MACHINE, HEAD, None, placement.matrix)
    assert dec.seed == seed and len(dec.attempts) == 1
    assert [s.volume for s in dec.subparts] == pytest.approx(KNOWN[name, seed], abs=0.01)
    assert dec.overhang_area == pytest.approx(0.0, abs=0.1)
    assert dec.to_json()["seed"] == seed
