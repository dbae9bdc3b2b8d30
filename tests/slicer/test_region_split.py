"""A stranded region cut in three: short hollow branches get a sub-part of their own.

A k-means patch that holds a short hollow branch's outer wall, its bore and the tube's wall
around the junction has no axis, and a cut in two cannot part the branch from the tube (its
wall and its bore fall in one half, joined only across the other). Before the three-way cut
such a branch stayed in the root and printed in the tube's layers, over air. Invariants of
the cut are checked on seeded regions of real meshes; the branch's own sub-part on generated
pipes, read back from STL as ``hostctl`` reads them, with the decomposition's constraints
re-checked by brute force.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from decompose_checks import check_decomposition, owners
from shared_models import MODELS

from kinematics.machine import MachineGeometry
from slicer.decompose.decomposition import DecomposeSettings, decompose
from slicer.decompose.partition import (
    MIN_REGION_SHARE,
    analysis_mesh,
    coarse_partition,
    split_disconnected,
    split_region_k,
)
from slicer.mesh.read import load_mesh
from slicer.mesh.samples import branched_pipe
from slicer.printhead import Printhead

HEAD = Printhead.default()
MACHINE = MachineGeometry()


def _read(mesh: trimesh.Trimesh, folder, name: str) -> trimesh.Trimesh:
    path = folder / f"{name}.stl"
    mesh.export(path)
    return load_mesh(path)[0]


def test_the_attempts_share_one_analysis_mesh_as_if_each_refined_its_own() -> None:
    """decompose refines the part once for all its attempts: the refined mesh is the same
    each time, each partition on the shared one is the one it makes for itself, and
    partitioning leaves it as it was."""
    mesh, _ = load_mesh(MODELS / "pipe3.stl")
    work = analysis_mesh(mesh)
    vertices, faces = work.vertices.copy(), work.faces.copy()
    for seed in (0, 1):
        shared, own = coarse_partition(mesh, None, seed, work), coarse_partition(mesh, None, seed)
        assert shared.mesh is work and np.array_equal(shared.labels, own.labels)
        assert np.array_equal(own.mesh.vertices, vertices)
    assert np.array_equal(work.vertices, vertices) and np.array_equal(work.faces, faces)


@pytest.mark.parametrize("model", ["pipe3.stl", "hard/arms3.stl", "hard/tee_low.stl"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_three_way_cut_parts_only_its_region_into_connected_pieces(model: str, seed: int
                                                                      ) -> None:
    mesh, _ = load_mesh(MODELS / model)
    part = coarse_partition(mesh, None, seed)
    m = part.mesh
    rng = np.random.default_rng(seed)
    cut_any = False
    for region in rng.choice(part.count, size=min(6, part.count), replace=False):
        cut = split_region_k(part, int(region), seed, 3)
        if cut is None:
            continue
        cut_any = True
        inside = part.labels == region
        assert (cut.labels[~inside] == part.labels[~inside]).all()  # no other region moved
        pieces = np.unique(cut.labels[inside])
        assert set(pieces) == {region, *range(part.count, cut.count)}
        # every piece one edge-connected patch, none below the smallest region's share
        assert split_disconnected(m, cut.labels).max() + 1 == cut.count
        areas = cut.areas()
        assert areas[pieces].min() >= MIN_REGION_SHARE * m.area
        assert areas[region] == areas[pieces].max()  # the largest keeps the index
        assert areas[pieces].sum() == pytest.approx(part.areas()[region])
    assert cut_any


BRANCHES = [(22.0, 20.0, 5.0, -19.0), (34.0, 20.0, 5.0, -19.0), (22.0, 20.0, 5.0, -10.0),
            (34.0, 20.0, 6.5, -10.0), (22.0, 20.0, 6.5, 12.0)]
"""(z, length, outer radius, elevation) of short hollow branches that stayed in the root
before the three-way cut (``branched_pipe``: a tube r = 10 on a disc base, walls 2 mm)."""


@pytest.mark.parametrize(("z", "length", "radius", "elevation"), BRANCHES)
def test_a_short_hollow_branch_is_a_sub_part_of_its_own(tmp_path, z: float, length: float,
                                                         radius: float, elevation: float
                                                         ) -> None:
    mesh = _read(branched_pipe(((z, 40.0, elevation),), branch_radius=radius,
                               branch_length=length), tmp_path, "pipe")
    dec = decompose(mesh, DecomposeSettings(), MACHINE, HEAD)
    assert len(dec.subparts) >= 2
    # the surface nearest the branch's end (its rim, 10 mm from the tube) is not the root's
    az, el = np.radians([40.0, elevation])
    axis = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    end = np.array([0.0, 0.0, z]) + length * axis
    root = next(s.index for s in dec.subparts if s.parent is None)
    assert owners(dec, [end]) != [root]
    check_decomposition(mesh, dec, HEAD, MACHINE.a_limits)
