"""The print plan: what slicing produces and what the G-code writer and replay consume.

All coordinates are in the platform frame (origin at the table centre on its surface, z up
along the C axis, the part placed on z = 0). A plan is pure data: numpy arrays and numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from slicer.decompose import Decomposition
    from slicer.mesh import BaseChoice

PATH_KINDS = ("perimeter", "infill", "solid", "interface")


@dataclass
class Path:
    """One extruded polyline in a layer.

    Attributes
    ----------
    kind : str
        One of :data:`PATH_KINDS` ("interface" = solid fill of a parent under a child's base).
    points : (n, 3) float
        Vertices in the platform frame, mm, on the layer's surface.
    height : (n,) float
        Local layer thickness at each vertex along the build direction (wedge layers), mm.
    width : float
        Extrusion width, mm.
    speed : float
        Feed rate while extruding, mm/s.
    flow : float
        Extrusion multiplier (1.0 nominal).
    closed : bool
        Whether the last vertex joins the first (perimeters).
    """

    kind: str
    points: np.ndarray
    height: np.ndarray
    width: float
    speed: float
    flow: float = 1.0
    closed: bool = False


@dataclass
class Layer:
    """One dynamic slice of a sub-part: a plane through ``origin`` normal to ``normal``.

    ``a`` and ``c`` are the table angles (degrees) that make ``normal`` machine +Z.
    ``interface_child`` names the child whose base lies just above this (solid) layer;
    ``nominal`` is the layer height it was marched at (less than the settings' where the
    march thinned it; 0 unknown).
    """

    subpart: int
    index: int
    origin: np.ndarray
    normal: np.ndarray
    a: float
    c: float
    thickness: tuple[float, float]
    paths: list[Path] = field(default_factory=list)
    interface_child: int | None = None
    first_of_child: bool = False
    nominal: float = 0.0


@dataclass
class SubpartPlan:
    """The layers of one sub-part, printed on top of ``parent`` (None for the root)."""

    index: int
    parent: int | None
    base_point: np.ndarray | None
    base_normal: np.ndarray | None
    build_direction: np.ndarray
    layers: list[Layer] = field(default_factory=list)

    @property
    def thickness_range(self) -> tuple[float, float]:
        """Smallest and largest local layer thickness over all layers, mm."""
        if not self.layers:
            return (0.0, 0.0)
        return (min(la.thickness[0] for la in self.layers),
                max(la.thickness[1] for la in self.layers))


@dataclass
class PrintPlan:
    """Sub-parts in build order, with the placement that maps STL → platform frame.

    ``base`` is the decomposition's choice of the face it stands on (None for the planar
    control); when ``base.turn`` is set the part stands on another face than the loader's.
    ``decomposition`` is the one it was planned from (None for the planar control), for a
    plan again with hints (:func:`slicer.paths.plan_print`).
    """

    placement: np.ndarray
    subparts: list[SubpartPlan]
    volume_mm3: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)
    base: BaseChoice | None = None
    decomposition: Decomposition | None = field(default=None, repr=False)
