"""Independent checks of a decomposition, shared by the tests and ``bench/decompose_sweep.py``.

Nothing here uses the decomposition's own constraint code: constraint I is checked by placing
the printhead model at sampled tips of every base and testing earlier sub-parts' surface
samples against it, constraint II from the sub-part's vertices and the A limits.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree

VOLUME_REL = 0.005  # sub-part volumes sum to the part's within this share
SIDE_TOL = 1e-4  # mm: sub-part vertices may lie this far below their base plane
BASE_TOL = 1e-5  # mm: a face on the base plane
OBSTACLE_SAMPLES = 20_000  # surface samples per earlier sub-part
TIPS = 400  # nozzle tips per base


def check_decomposition(mesh: trimesh.Trimesh, dec: object, head: object,
                        a_limits: tuple[float, float]) -> None:
    """Assert watertight sub-parts, conserved volume and constraints I and II."""
    for s in dec.subparts:
        assert s.mesh.is_watertight and s.mesh.volume > 0, f"sub-part {s.index} not a solid"
    total = sum(s.mesh.volume for s in dec.subparts)
    assert abs(total - mesh.volume) <= VOLUME_REL * mesh.volume, (total, mesh.volume)
    independent_check(dec, head, a_limits)


def independent_check(dec: object, head: object, a_limits: tuple[float, float]) -> None:
    """Constraints I and II by brute force: head placed at sampled tips of the base."""
    rng = np.random.default_rng(0)
    for rank, i in enumerate(dec.order):
        s = dec.subparts[i]
        if s.parent is None:
            assert np.allclose(s.build_direction, [0.0, 0.0, 1.0])
            continue
        p, n = s.base_plane.point, s.base_plane.normal
        assert abs(np.linalg.norm(n) - 1.0) < 1e-9
        # II: child on the positive side; direction reachable (tilt within A limits)
        assert ((s.mesh.vertices - p) @ n).min() > -SIDE_TOL
        tilt = np.degrees(np.arccos(np.clip(n[2], -1, 1)))
        assert tilt <= max(abs(a_limits[0]), abs(a_limits[1])) + 1e-9
        assert np.allclose(s.build_direction, n)
        # the base: the sub-part's faces lying on the plane and facing -n
        on = ((np.abs((s.mesh.triangles_center - p) @ n) < BASE_TOL)
              & (s.mesh.face_normals @ n < -0.999))
        base_area = s.mesh.area_faces[on].sum()
        assert abs(base_area - s.base_area) <= 0.02 * s.base_area, (base_area, s.base_area)
        base = trimesh.Trimesh(s.mesh.vertices, s.mesh.faces[on])
        tips = np.concatenate([trimesh.sample.sample_surface(base, 300, seed=1)[0],
                               base.vertices[np.unique(base.faces)]])
        tips = tips[rng.permutation(len(tips))[:TIPS]]
        # I: platform clear at every tip; nothing printed earlier inside the head
        assert min(head.lowest_point(t, n) for t in tips) >= -1e-6
        earlier = [dec.subparts[j].mesh for j in dec.order[:rank]]
        obstacles = np.concatenate([np.concatenate(
            [trimesh.sample.sample_surface(m, OBSTACLE_SAMPLES, seed=2)[0], m.vertices])
            for m in earlier])
        # the parent's face glued to this base lies on the plane (h = 0): not an obstacle
        obstacles = obstacles[np.abs((obstacles - p) @ n) > 1e-6]
        for t in tips:
            assert not head.contains(obstacles, t, n).any(), f"sub-part {i}: I fails"


def is_clean_failure(message: str) -> bool:
    """A refusal that names the boundary and the violated constraint, on one line."""
    return ("boundary between sub-part" in message and "constraint" in message
            and "\n" not in message)


def owners(dec: object, points: list[np.ndarray]) -> list[int]:
    """Index of the sub-part nearest to each input-frame point (placed by the
    decomposition's own placement): which sub-part prints a branch's end."""
    verts = np.concatenate([s.mesh.vertices for s in dec.subparts])
    owner = np.concatenate([np.full(len(s.mesh.vertices), s.index) for s in dec.subparts])
    placed = trimesh.transform_points(np.asarray(points), dec.placement)
    return [int(owner[i]) for i in cKDTree(verts).query(placed)[1]]
