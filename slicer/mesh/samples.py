"""Parametric sample parts built with manifold3d booleans (millimetres, +Z up, base on z = 0).

The shapes mirror the paper's test pieces: a plain cylinder (the control: one sub-part), and a
hollow vertical tube on a flat disc base with hollow straight branches (two- and three-branched
pipes) or a curved branch. Every generator returns a watertight :class:`trimesh.Trimesh`.

Examples
--------
>>> mesh = pipe2()
>>> mesh.is_watertight
True
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import manifold3d as m3
import numpy as np
import trimesh

SEGMENTS = 48  # facets around a circle


def to_trimesh(solid: m3.Manifold) -> trimesh.Trimesh:
    """A manifold3d solid as a trimesh (float64 vertices, outward winding)."""
    mesh = solid.to_mesh64()
    verts = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(mesh.tri_verts, dtype=np.int64)
    # manifold3d shares vertices except across property seams (e.g. a cut face), which it
    # lists in its merge vectors; trimesh's merge could weld distinct close ones, so use those.
    merge_from = np.asarray(mesh.merge_from_vert, dtype=np.int64)
    if len(merge_from):
        remap = np.arange(len(verts))
        remap[merge_from] = np.asarray(mesh.merge_to_vert, dtype=np.int64)
        used, faces = np.unique(remap[faces], return_inverse=True)
        verts, faces = verts[used], faces.reshape(-1, 3)
    return trimesh.Trimesh(verts, faces, process=False)


def to_manifold(mesh: trimesh.Trimesh) -> m3.Manifold:
    """A watertight trimesh as a manifold3d solid."""
    return m3.Manifold(m3.Mesh64(np.array(mesh.vertices, dtype=np.float64, order="C"),
                                 np.array(mesh.faces, dtype=np.uint64, order="C")))


def _frame(direction: np.ndarray) -> np.ndarray:
    """(4, 4) rotation taking +Z onto the unit ``direction``."""
    z = np.array([0.0, 0.0, 1.0])
    return trimesh.geometry.align_vectors(z, direction)


def _rod(start: np.ndarray, direction: np.ndarray, length: float, radius: float,
         segments: int) -> m3.Manifold:
    """A cylinder of ``radius`` from ``start`` along the unit ``direction`` for ``length``."""
    rod = m3.Manifold.cylinder(length, radius, radius, segments)
    mat = _frame(direction)
    mat[:3, 3] = start
    return rod.transform(mat[:3, :4])


def branch_direction(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit vector at ``azimuth`` about +Z and ``elevation`` above the horizontal, (3,) float."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def cylinder(radius: float = 10.0, height: float = 60.0, segments: int = SEGMENTS
             ) -> trimesh.Trimesh:
    """A solid upright cylinder standing on z = 0."""
    return to_trimesh(m3.Manifold.cylinder(height, radius, radius, segments))


def bored_block(size: float = 12.0, height: float = 10.0, bore_radius: float = 2.5,
                segments: int = 24) -> trimesh.Trimesh:
    """A ``size`` × ``size`` × ``height`` block on z = 0 with a horizontal bore along X at
    mid-height: its ceiling is a wall over air in any planar print (the tests' quickest part
    the closed loop refuses)."""
    block = m3.Manifold.cube([size, size, height], True).translate([0.0, 0.0, height / 2])
    bore = m3.Manifold.cylinder(size + 2.0, bore_radius, bore_radius, segments, True)
    return to_trimesh(block - bore.rotate([0.0, 90.0, 0.0]).translate([0.0, 0.0, height / 2]))


def _tube_with_base(radius: float, wall: float, height: float, base_radius: float,
                    base_height: float, segments: int) -> tuple[m3.Manifold, m3.Manifold]:
    """(outer solid, bore) of a vertical tube on a solid disc base (a cup open at the top)."""
    outer = m3.Manifold.cylinder(height, radius, radius, segments)
    outer = outer + m3.Manifold.cylinder(base_height, base_radius, base_radius, segments)
    bore = m3.Manifold.cylinder(height, radius - wall, radius - wall, segments)
    return outer, bore.translate((0.0, 0.0, base_height))


def branched_pipe(branches: Sequence[tuple[float, float, float]] = ((25.0, 0.0, 45.0),),
                  radius: float = 10.0, wall: float = 2.0, height: float = 60.0,
                  branch_radius: float = 7.0, branch_length: float = 32.0,
                  base_radius: float = 16.0, base_height: float = 3.0,
                  segments: int = SEGMENTS) -> trimesh.Trimesh:
    """A hollow vertical tube on a disc base with straight hollow branches.

    Parameters
    ----------
    branches : sequence of (z, azimuth_deg, elevation_deg)
        Each branch leaves the tube axis at height ``z``, heading at ``azimuth`` about +Z and
        ``elevation`` above the horizontal; its axis is ``branch_length`` long from the tube
        axis.
    radius, wall, height : float
        Outer radius, wall thickness and height of the main tube, mm.
    branch_radius : float
        Outer radius of each branch (same wall), mm.
    base_radius, base_height : float
        The flat disc the tube stands on; the bore goes through it.
    """
    outer, bore = _tube_with_base(radius, wall, height, base_radius, base_height, segments)
    solids, holes = [outer], [bore]
    for z, az, el in branches:
        d = branch_direction(az, el)
        start = np.array([0.0, 0.0, z])
        solids.append(_rod(start, d, branch_length, branch_radius, segments))
        holes.append(_rod(start, d, branch_length + 1.0, branch_radius - wall, segments))
    solid = m3.Manifold.batch_boolean(solids, m3.OpType.Add)
    return to_trimesh(largest_body(solid - m3.Manifold.batch_boolean(holes, m3.OpType.Add)))


def largest_body(solid: m3.Manifold) -> m3.Manifold:
    """The largest-volume connected body of ``solid``.

    A short branch whose end lies in the main tube's wall (or that leaves through its rim)
    has its bore cut a sliver off the rim; the sample is the part those slivers fell off.
    """
    bodies = solid.decompose()
    if len(bodies) <= 1:
        return solid
    return max(bodies, key=lambda b: b.volume())


#: Ranges of :func:`pipe_variant` (mm and degrees).
VARIANT_HEIGHT = (20.0, 60.0)
VARIANT_BRANCH_Z = (8.0, 40.0)  # and at most VARIANT_TOP_CLEARANCE below the top
VARIANT_TOP_CLEARANCE = 4.0
VARIANT_LENGTH = (10.0, 32.0)
VARIANT_ELEVATIONS = (30.0, 45.0, 60.0)


def pipe_variant(index: int) -> dict[str, object]:
    """Keyword arguments of :func:`branched_pipe` for the seeded robustness sweep.

    Variant ``index`` draws (from ``numpy.random.default_rng(index)``) a tube height in
    :data:`VARIANT_HEIGHT`, one or two branches leaving at heights in :data:`VARIANT_BRANCH_Z`
    (and at least :data:`VARIANT_TOP_CLEARANCE` below the top), any azimuth, an elevation of
    :data:`VARIANT_ELEVATIONS`, and one branch length in :data:`VARIANT_LENGTH`.

    Examples
    --------
    >>> mesh = branched_pipe(**pipe_variant(0))
    """
    rng = np.random.default_rng(index)
    height = float(np.round(rng.uniform(*VARIANT_HEIGHT), 1))
    z_hi = min(VARIANT_BRANCH_Z[1], height - VARIANT_TOP_CLEARANCE)
    count = int(rng.integers(1, 3))
    branches = tuple((float(np.round(rng.uniform(VARIANT_BRANCH_Z[0], z_hi), 1)),
                      float(np.round(rng.uniform(0.0, 360.0))),
                      float(rng.choice(VARIANT_ELEVATIONS))) for _ in range(count))
    length = float(np.round(rng.uniform(*VARIANT_LENGTH), 1))
    return {"branches": branches, "height": height, "branch_length": length}


def pipe2(segments: int = SEGMENTS) -> trimesh.Trimesh:
    """The paper's two-branched pipe: the tube and one 45° branch leaving at z = 25."""
    return branched_pipe(((25.0, 0.0, 45.0),), segments=segments)


def pipe3(segments: int = SEGMENTS) -> trimesh.Trimesh:
    """The three-branched pipe: 45° branches at z = 18 (azimuth 0°) and z = 36 (150°)."""
    return branched_pipe(((18.0, 0.0, 45.0), (36.0, 150.0, 45.0)), segments=segments)


def pipe_cross(segments: int = 96) -> trimesh.Trimesh:
    """A large hollow cross fitting: an upright tube of 50 mm pipe (wall 2.5 mm) 180 mm tall
    on a 70 mm flange, with two horizontal branches of the same pipe at mid-height reaching
    130 mm from its axis: about 152 cm³ of material (the replay's memory bench, issue 34)."""
    return branched_pipe(((90.0, 0.0, 0.0), (90.0, 180.0, 0.0)), radius=25.0, wall=2.5,
                         height=180.0, branch_radius=25.0, branch_length=130.0,
                         base_radius=35.0, base_height=3.0, segments=segments)


def curved_pipe(bend_radius: float = 30.0, bend_deg: float = 60.0, z: float = 25.0,
                radius: float = 10.0, wall: float = 2.0, height: float = 60.0,
                branch_radius: float = 6.0, stub: float = 14.0, base_radius: float = 16.0,
                base_height: float = 3.0, segments: int = SEGMENTS) -> trimesh.Trimesh:
    """A tube with one hollow branch that leaves horizontally and bends upward.

    The branch runs ``stub`` mm straight out along +X from the tube axis at height ``z``, then
    follows a torus arc of ``bend_radius`` turning ``bend_deg`` degrees upward.
    """
    outer, bore = _tube_with_base(radius, wall, height, base_radius, base_height, segments)
    x_axis = np.array([1.0, 0.0, 0.0])
    start = np.array([0.0, 0.0, z])
    solids = [outer, _rod(start, x_axis, stub, branch_radius, segments)]
    holes = [bore, _rod(start, x_axis, stub + 0.01, branch_radius - wall, segments)]
    for r, out, deg in ((branch_radius, solids, bend_deg),
                        (branch_radius - wall, holes, bend_deg + 5.0)):  # bore runs out
        ring = m3.CrossSection.circle(r, segments).translate((bend_radius, 0.0))
        arc = m3.Manifold.revolve(ring, segments, deg)  # about +Z, in the XY plane
        # revolve turns about +Z from +X towards +Y: map (x, y, z) -> (y, z', ...) so the
        # arc starts at the stub end heading +X and bends towards +Z.
        mat = np.array([[0.0, 1.0, 0.0, stub], [0.0, 0.0, 1.0, 0.0],
                        [-1.0, 0.0, 0.0, z + bend_radius]])
        out.append(arc.transform(mat))
    solid = m3.Manifold.batch_boolean(solids, m3.OpType.Add)
    return to_trimesh(largest_body(solid - m3.Manifold.batch_boolean(holes, m3.OpType.Add)))


def prism_volume(radius: float, height: float, segments: int = SEGMENTS) -> float:
    """Exact volume of a ``segments``-gon prism inscribed in a circle of ``radius``."""
    return 0.5 * segments * radius**2 * math.sin(2.0 * math.pi / segments) * height


def tube_volume(radius: float = 10.0, wall: float = 2.0, height: float = 60.0,
                base_radius: float = 16.0, base_height: float = 3.0,
                segments: int = SEGMENTS) -> float:
    """Exact volume of the branchless tube on its base (the pipes without branches)."""
    bore = radius - wall
    return (prism_volume(radius, height, segments)
            - prism_volume(bore, height - base_height, segments)
            + prism_volume(base_radius, base_height, segments)
            - prism_volume(radius, base_height, segments))
