"""Hand-made print plans for the G-code, estimate and replay tests (no decomposition needed),
and a hand-made two-part decomposition for the planner's tests.

A square prism is printed as layers of two square perimeters and a solid zigzag fill, on
planes normal to any direction; the matching watertight mesh comes with it.
"""

from __future__ import annotations

from types import SimpleNamespace

import manifold3d as m3
import numpy as np
import trimesh

from kinematics.machine import MachineGeometry
from kinematics.orient import solve_orientation
from slicer.mesh.samples import to_trimesh
from slicer.plan import Layer, Path, PrintPlan, SubpartPlan

W = 0.45
H = 0.2


def frame(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit normal and two in-plane unit axes (e1 in the x-z plane when possible)."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    ref = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e2 = np.cross(n, ref)
    e2 /= np.linalg.norm(e2)
    return n, np.cross(e2, n), e2


def square(center: np.ndarray, e1: np.ndarray, e2: np.ndarray, half: float) -> np.ndarray:
    """Corners (4, 3) of a square loop."""
    c = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float) * half
    return center + c[:, :1] * e1 + c[:, 1:] * e2


def zigzag(center: np.ndarray, e1: np.ndarray, e2: np.ndarray, half: float, w: float,
           turn: bool) -> np.ndarray:
    """A solid zigzag filling the square of half-size ``half`` at line spacing ``w``."""
    if turn:
        e1, e2 = e2, e1
    ys = np.arange(-half + w / 2, half - w / 2 + 1e-9, w)
    pts = []
    for i, y in enumerate(ys):
        xs = (-half + w / 2, half - w / 2)[:: 1 if i % 2 == 0 else -1]
        pts.extend(center + x * e1 + y * e2 for x in xs)
    return np.asarray(pts)


def prism_layers(subpart: int, base: np.ndarray, normal: np.ndarray, half: float,
                 n_layers: int, geometry: MachineGeometry, h: float = H, w: float = W,
                 shift: tuple[float, float] = (0.0, 0.0), shift_from: int = 10**9,
                 speed: float = 30.0) -> list[Layer]:
    """Layers of a square prism along ``normal`` from the plane through ``base``.

    Layers from ``shift_from`` on are moved by ``shift`` (e1, e2) mm: an overhang step.
    """
    n, e1, e2 = frame(normal)
    a, c = solve_orientation(n, geometry)
    layers = []
    for i in range(n_layers):
        off = np.asarray(shift, float) if i >= shift_from else np.zeros(2)
        center = np.asarray(base, float) + (i + 1) * h * n + off[0] * e1 + off[1] * e2
        paths = []
        for k in range(2):
            loop = square(center, e1, e2, half - w / 2 - k * w)
            paths.append(Path("perimeter", loop, np.full(4, h), w, speed, closed=True))
        fill = zigzag(center, e1, e2, half - 2 * w, w, turn=i % 2 == 1)
        paths.append(Path("solid", fill, np.full(len(fill), h), w, speed * 1.3))
        layers.append(Layer(subpart, i, center - h * n, n, a, c, (h, h), paths))
    return layers


def prism_mesh(base: np.ndarray, normal: np.ndarray, half: float, length: float
               ) -> trimesh.Trimesh:
    """The solid the layers of :func:`prism_layers` fill (no shift)."""
    n, e1, e2 = frame(normal)
    box = trimesh.creation.box(extents=(2 * half, 2 * half, length))
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = e1, e2, n
    m[:3, 3] = np.asarray(base, float) + n * length / 2
    box.apply_transform(m)
    return box


def box_plan(geometry: MachineGeometry, half: float = 5.0, n_layers: int = 10, **kw
             ) -> PrintPlan:
    """One upright square prism on the platform."""
    layers = prism_layers(0, np.zeros(3), np.array([0.0, 0.0, 1.0]), half, n_layers, geometry,
                          **kw)
    sp = SubpartPlan(0, None, None, None, np.array([0.0, 0.0, 1.0]), layers)
    return PrintPlan(np.eye(4), [sp])


def two_part_plan(geometry: MachineGeometry, tilt_deg: float = 30.0, half: float = 5.0,
                  n_root: int = 20, n_child: int = 10, lift: float = 0.0
                  ) -> tuple[PrintPlan, np.ndarray]:
    """An upright prism and a smaller prism tilted by ``tilt_deg`` about X on its top.

    The child's base plane passes ``lift`` mm above the centre of the root's top (with no
    lift, part of the root's top lies above the tilted base: the head must hit it).
    Returns the plan and the child's build direction (3,).
    """
    root = prism_layers(0, np.zeros(3), np.array([0.0, 0.0, 1.0]), half, n_root, geometry)
    t = np.radians(tilt_deg)
    d = np.array([0.0, -np.sin(t), np.cos(t)])
    top = np.array([0.0, 0.0, n_root * H + lift])
    root[-1].interface_child = 1
    child = prism_layers(1, top, d, 2.0, n_child, geometry)
    sps = [SubpartPlan(0, None, None, None, np.array([0.0, 0.0, 1.0]), root),
           SubpartPlan(1, 0, top, d, d, child)]
    return PrintPlan(np.eye(4), sps), d


def two_part_decomposition(root: m3.Manifold, child: m3.Manifold, point: object,
                           normal: object) -> SimpleNamespace:
    """A decomposition of ``root`` on the platform and ``child`` printed on it from the base
    plane through ``point`` with ``normal``, in that order (what the planner reads of one)."""
    plane = SimpleNamespace(point=np.asarray(point, float), normal=np.asarray(normal, float))
    subs = [SimpleNamespace(index=0, parent=None, mesh=to_trimesh(root), base_plane=None,
                            build_direction=np.array([0, 0, 1.0])),
            SimpleNamespace(index=1, parent=0, mesh=to_trimesh(child), base_plane=plane,
                            build_direction=np.asarray(normal, float))]
    return SimpleNamespace(placement=np.eye(4), subparts=subs, order=[0, 1],
                           volume=root.volume() + child.volume())
