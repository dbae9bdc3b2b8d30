"""Parametric parts of the classes a planar print cannot make without support.

The classes of ``shared/models/hard`` (hollow branches shallower than 45°, horizontal tees and
branches pointing down, elbows, solid trees and a ball with arms), drawn with other angles,
radii, heights, azimuths and numbers of branches by :func:`hard_variant`, so that the product
is measured on parts it was not tuned to (``bench/hard_sweep.py``, the tests). Every generator
returns a watertight :class:`trimesh.Trimesh`, millimetres, +Z up, flat base on z = 0.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import manifold3d as m3
import numpy as np
import trimesh

from slicer.mesh.samples import (
    SEGMENTS,
    _rod,
    _tube_with_base,
    branch_direction,
    branched_pipe,
    largest_body,
    to_trimesh,
)

KINDS = ("pipe", "elbow", "tree", "ball")


def elbow_pipe(z: float = 22.0, azimuth: float = 60.0, reach: float = 12.0,
               bend_radius: float = 16.0, rise: float = 10.0, radius: float = 10.0,
               wall: float = 2.0, height: float = 60.0, branch_radius: float = 7.0,
               base_radius: float = 16.0, base_height: float = 3.0,
               segments: int = SEGMENTS) -> trimesh.Trimesh:
    """A hollow tube with one hollow branch that leaves horizontally at height ``z`` towards
    ``azimuth``, runs ``reach`` mm from the tube axis, turns 90° upward on a bend of
    ``bend_radius`` and ends in a vertical stub ``rise`` mm long."""
    outer, bore = _tube_with_base(radius, wall, height, base_radius, base_height, segments)
    solids, holes = [outer], [bore]
    for r, out, extra in ((branch_radius, solids, 0.0), (branch_radius - wall, holes, 1.0)):
        out.extend(_elbow(z, reach, bend_radius, rise + extra, r, segments))
    solid = m3.Manifold.batch_boolean(solids, m3.OpType.Add)
    body = largest_body(solid - m3.Manifold.batch_boolean(holes, m3.OpType.Add))
    return to_trimesh(body.rotate((0.0, 0.0, azimuth)))


def _elbow(z: float, reach: float, bend: float, rise: float, r: float, segments: int
           ) -> list[m3.Manifold]:
    """The three solids of an elbow of radius ``r`` along +X (straight, bend, stub)."""
    start = np.array([0.0, 0.0, z])
    straight = _rod(start, np.array([1.0, 0.0, 0.0]), reach, r, segments)
    ring = m3.CrossSection.circle(r, segments).translate((bend, 0.0))
    arc = m3.Manifold.revolve(ring, segments, 90.0)
    # the revolve turns about +Z from +X towards +Y; map it so it starts at the straight's
    # end heading +X and bends towards +Z
    mat = np.array([[0.0, 1.0, 0.0, reach], [0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, z + bend]])
    top = np.array([reach + bend, 0.0, z + bend])
    stub = _rod(top, np.array([0.0, 0.0, 1.0]), rise, r, segments)
    return [straight, arc.transform(mat), stub]


def solid_tree(arms: Sequence[tuple[float, float]] = ((0.0, 20.0), (180.0, 20.0)),
               trunk_radius: float = 6.0, trunk_height: float = 28.0, arm_radius: float = 5.0,
               arm_length: float = 30.0, base_radius: float = 12.0, base_height: float = 3.0,
               segments: int = SEGMENTS) -> trimesh.Trimesh:
    """A solid trunk on a disc that splits at its top into solid arms, each ``(azimuth,
    elevation)`` in degrees, ``arm_length`` long from the trunk's top centre (a ball there
    joins them smoothly)."""
    top = np.array([0.0, 0.0, trunk_height])
    parts = [m3.Manifold.cylinder(base_height, base_radius, base_radius, segments),
             m3.Manifold.cylinder(trunk_height, trunk_radius, trunk_radius, segments),
             m3.Manifold.sphere(trunk_radius, segments).translate(tuple(top))]
    parts += [_rod(top, branch_direction(az, el), arm_length, arm_radius, segments)
              for az, el in arms]
    return to_trimesh(largest_body(m3.Manifold.batch_boolean(parts, m3.OpType.Add)))


def ball_arms(arms: Sequence[tuple[float, float]] = ((0.0, 20.0), (120.0, 20.0),
                                                     (240.0, 20.0)),
              trunk_radius: float = 6.0, height: float = 50.0, ball_z: float = 32.0,
              ball_radius: float = 9.0, arm_radius: float = 4.0, arm_length: float = 30.0,
              base_radius: float = 12.0, base_height: float = 3.0,
              segments: int = SEGMENTS) -> trimesh.Trimesh:
    """A solid trunk through a ball at ``ball_z`` with solid arms, each ``(azimuth,
    elevation)``, ``arm_length`` long from the ball's centre."""
    centre = np.array([0.0, 0.0, ball_z])
    parts = [m3.Manifold.cylinder(base_height, base_radius, base_radius, segments),
             m3.Manifold.cylinder(height, trunk_radius, trunk_radius, segments),
             m3.Manifold.sphere(ball_radius, segments).translate(tuple(centre))]
    parts += [_rod(centre, branch_direction(az, el), arm_length, arm_radius, segments)
              for az, el in arms]
    return to_trimesh(largest_body(m3.Manifold.batch_boolean(parts, m3.OpType.Add)))


@dataclass(frozen=True)
class HardVariant:
    """One drawn part: its class (one of :data:`KINDS`), a short name and the generator's
    keyword arguments."""

    kind: str
    name: str
    params: dict[str, object]

    def mesh(self) -> trimesh.Trimesh:
        """The part."""
        makers: dict[str, Callable[..., trimesh.Trimesh]] = {
            "pipe": branched_pipe, "elbow": elbow_pipe, "tree": solid_tree,
            "ball": ball_arms}
        return makers[self.kind](**self.params)


def hard_variant(index: int) -> HardVariant:
    """Variant ``index`` of the hard classes, drawn from ``numpy.random.default_rng(index)``;
    the class cycles with ``index`` (pipe, elbow, tree, ball).

    * pipe: 1–3 hollow branches (radius 5–8 mm) at elevations from −20° to 40° (a horizontal
      tee included), any azimuth, leaving at heights 15–45 mm, at least 14 mm apart;
    * elbow: a horizontal branch reaching 12–16 mm, a bend of 12–20 mm and a 6–14 mm stub;
    * tree: 2–3 solid arms at 10–35° from the top of a 22–34 mm trunk;
    * ball: 2–4 solid arms at 10–30° from a ball of radius 8–10 mm at 26–36 mm.
    """
    rng = np.random.default_rng(index)
    kind = KINDS[index % len(KINDS)]
    draw = {"pipe": _pipe, "elbow": _elbow_params, "tree": _tree, "ball": _ball}[kind]
    name, params = draw(rng)
    return HardVariant(kind, f"{kind}{index}_{name}", params)


def _pipe(rng: np.random.Generator) -> tuple[str, dict[str, object]]:
    count = int(rng.integers(1, 4))
    radius = float(np.round(rng.uniform(5.0, 8.0), 1))
    length = float(np.round(rng.uniform(22.0, 32.0)))
    els = np.round(rng.uniform(-20.0, 40.0, size=count))
    # a branch pointing down keeps its lowest point 5 mm above the base
    low = 15.0 + np.maximum(0.0, length * np.sin(np.radians(-els)) + radius - 10.0)
    taken: list[tuple[float, float]] = []
    for k in np.argsort(-low):  # the most constrained first; one with no room is dropped
        free = [z for z in range(int(np.ceil(low[k])), 47)
                if all(abs(z - other) >= 14.0 for other, _ in taken)]
        if free:
            taken.append((float(rng.choice(free)), float(els[k])))
    branches = tuple((z, float(np.round(rng.uniform(0.0, 360.0))), el)
                     for z, el in sorted(taken))
    params = {"branches": branches, "branch_radius": radius, "branch_length": length}
    return "_".join(f"{el:g}" for _, _, el in branches), params


def _elbow_params(rng: np.random.Generator) -> tuple[str, dict[str, object]]:
    params: dict[str, object] = {"z": float(np.round(rng.uniform(18.0, 30.0))),
              "azimuth": float(np.round(rng.uniform(0.0, 360.0))),
              "reach": float(np.round(rng.uniform(12.0, 16.0))),
              "bend_radius": float(np.round(rng.uniform(12.0, 20.0))),
              "rise": float(np.round(rng.uniform(6.0, 14.0)))}
    return f"r{params['bend_radius']:g}", params


def _tree(rng: np.random.Generator) -> tuple[str, dict[str, object]]:
    count = int(rng.integers(2, 4))
    az0 = float(rng.uniform(0.0, 360.0))
    arms = tuple((float(np.round(az0 + k * 360.0 / count + rng.uniform(-20.0, 20.0))),
                  float(np.round(rng.uniform(10.0, 35.0)))) for k in range(count))
    params = {"arms": arms, "trunk_height": float(np.round(rng.uniform(22.0, 34.0)))}
    return "_".join(f"{el:g}" for _, el in arms), params


def _ball(rng: np.random.Generator) -> tuple[str, dict[str, object]]:
    count = int(rng.integers(2, 5))
    az0 = float(rng.uniform(0.0, 360.0))
    arms = tuple((float(np.round(az0 + k * 360.0 / count)),
                  float(np.round(rng.uniform(10.0, 30.0)))) for k in range(count))
    params = {"arms": arms, "ball_z": float(np.round(rng.uniform(26.0, 36.0))),
              "ball_radius": float(np.round(rng.uniform(8.0, 10.0), 1))}
    return "_".join(f"{el:g}" for _, el in arms), params
