"""The plane refinement (least residual overhang in the parent) and the bounded cut."""

from __future__ import annotations

import io

import numpy as np
import pytest
import trimesh
from decompose_checks import check_decomposition

import slicer.decompose.plane_refine as refine
from kinematics.machine import MachineGeometry
from slicer.decompose.decomposition import DecomposeSettings, decompose
from slicer.decompose.planes import PieceContext, Plane, SearchSettings, evaluate
from slicer.decompose.split import split_solid
from slicer.mesh.samples import branched_pipe, pipe2, to_manifold, to_trimesh
from slicer.printhead import Printhead

GEO = MachineGeometry()
HEAD = Printhead.default()
STEEP = ((25.0, 0.0, 30.0),)  # one branch 30° above the horizontal


def _overhang_area(mesh: trimesh.Trimesh, direction: np.ndarray, base_z: float = 0.0
                   ) -> float:
    """Area of faces facing more than 47° below the horizontal of ``direction``, except the
    base on the platform (exact, from the faces: independent of the search's samples)."""
    down = mesh.face_normals @ direction < -np.cos(np.radians(refine.OVERHANG_DEG))
    on_base = np.abs(mesh.triangles_center[:, 2] - base_z) < 1e-3
    return float(mesh.area_faces[down & ~on_base].sum())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_refined_cut_leaves_the_trunk_far_less_overhang_on_a_steep_branch(seed):
    mesh = branched_pipe(STEEP)
    refined = decompose(mesh, DecomposeSettings(seed=seed), GEO, HEAD)
    paper = DecomposeSettings(seed=seed, search=SearchSettings(refine_steps=0))
    first = decompose(mesh, paper, GEO, HEAD)  # the paper's first feasible plane
    up = np.array([0.0, 0.0, 1.0])
    before = _overhang_area(first.subparts[0].mesh, up)
    after = _overhang_area(refined.subparts[0].mesh, up)
    assert len(refined.subparts) == len(first.subparts) == 2
    assert after < 0.5 * before, (before, after)
    check_decomposition(mesh, refined, HEAD, GEO.a_limits)


def test_refinement_never_raises_the_residual_of_the_first_plane():
    rng = np.random.default_rng(3)
    mesh = branched_pipe(STEEP)
    c = mesh.triangles_center
    child = (np.hypot(c[:, 0], c[:, 1]) > 10.3) & (c[:, 2] > 3.5)
    ctx = PieceContext(mesh, child, np.zeros((0, 3)), HEAD, GEO.a_limits, seed=0)
    axis = np.array([np.cos(np.radians(30)), 0.0, np.sin(np.radians(30))])
    found = evaluate(ctx, Plane(np.array([0.0, 0.0, 25.0]) + 20.0 * axis, axis))
    assert found.ok
    parent = refine.ParentFrame(np.array([0.0, 0.0, 1.0]), Plane(np.zeros(3), np.eye(3)[2]))
    out, _ = refine.refine_plane(ctx, found, parent, axis, DecomposeSettings().search, rng)
    assert out.ok and not out.tangled
    before = refine.residual_overhang(ctx, found.plane, found.child_faces, parent)
    after = refine.residual_overhang(ctx, out.plane, out.child_faces, parent)
    assert after <= before
    assert out.area <= 1.15 * found.area + 1e-9


def _stl_round_trip(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    buf = io.BytesIO(mesh.export(file_type="stl"))
    return trimesh.load(buf, file_type="stl")


def test_a_plane_crossing_other_material_leaves_both_parts_watertight():
    """The plane of a 45° branch tilted towards +Z also crosses the top of the main tube:
    that piece stays with the parent, which must come out as one clean solid (joining it
    back onto the lower half used to leave the touching cut faces inside as a seam)."""
    mesh = pipe2()
    normal = np.array([0.57, 0.089, 0.817])
    plane = Plane(np.array([13.39, -1.42, 46.57]), normal / np.linalg.norm(normal))
    c = mesh.triangles_center
    ctx = PieceContext(mesh, (c[:, 0] > 9.0) & (c[:, 2] > 20.0), np.zeros((0, 3)), HEAD,
                       GEO.a_limits)
    check = evaluate(ctx, plane)
    crossed = plane.signed(mesh.vertices[mesh.faces[~check.child_faces]]).max()
    assert crossed > 1.0  # the tube's top really is on the positive side
    solid = to_manifold(mesh)
    kid, rest = split_solid(solid, plane, mesh, check.child_faces)
    assert kid.volume() + rest.volume() == pytest.approx(solid.volume(), rel=1e-6)
    for part in (kid, rest):
        back = _stl_round_trip(to_trimesh(part))
        assert back.is_watertight and back.is_winding_consistent
    assert plane.signed(to_trimesh(kid).vertices).min() > -1e-6
    assert plane.signed(to_trimesh(rest).vertices).max() > 1.0  # the tube top is kept
