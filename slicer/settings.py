"""Process settings of the slicer: plain values, built from the config at the edge.

``slicer`` never reads YAML: the CLI and the daemon build these from the ``process.*`` and
``machine.*`` keys (``hostd.config.convert``). Defaults equal the shipped config's.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

MAX_BEAD_SHARE = 0.8
"""A bead's thickness (a layer's, locally) is at most this share of the nozzle diameter:
thicker, it neither presses onto the layer below nor keeps its width."""


@dataclass(frozen=True)
class ProcessSettings:
    """Everything that shapes layers, toolpaths, extrusion and the G-code around them."""

    layer_height: float = 0.2
    line_width: float = 0.45
    perimeters: int = 2
    infill_density: float = 0.2
    infill_angle: float = 45.0
    solid_layers: int = 3
    min_shell_thickness: float = 0.6
    print_speed: float = 40.0
    perimeter_speed: float = 30.0
    first_layer_speed: float = 15.0
    travel_speed: float = 120.0
    retract_length: float = 1.0
    retract_speed: float = 35.0
    z_hop: float = 0.4
    safe_height: float = 60.0
    min_layer_factor: float = 0.5
    max_layer_factor: float = 1.5
    interface_layers: int = 3
    interface_speed_factor: float = 0.5
    interface_flow: float = 1.1
    nozzle_temperature: float = 210.0
    bed_temperature: float = 60.0
    fan_speed: int = 255
    nozzle_diameter: float = 0.4
    filament_diameter: float = 1.75
    max_velocity: float = 200.0
    max_accel: float = 1000.0
    max_rotary_velocity: float = 90.0
    max_rotary_accel: float = 360.0
    linearize_tolerance: float = 0.01
    start_gcode: str = "G28\nG92 E0\n"
    end_gcode: str = "M104 S0\nM140 S0\nM84\n"

    def skin_layers(self) -> int:
        """Solid layers at the bottom and top: ``solid_layers``, or more when layers are thin,
        so that the skin is at least ``min_shell_thickness`` thick (0.05 mm layers: 12)."""
        need = math.ceil(self.min_shell_thickness / self.layer_height - 1e-9)
        return max(self.solid_layers, need)

    def max_layer_share(self) -> float:
        """Largest local layer thickness as a share of ``layer_height``: ``max_layer_factor``,
        capped so that no bead is thicker than :data:`MAX_BEAD_SHARE` × the nozzle (never
        below 1: a layer parallel to the one below is always ``layer_height`` thick)."""
        cap = MAX_BEAD_SHARE * self.nozzle_diameter / self.layer_height
        return max(1.0, min(self.max_layer_factor, cap))

    def header(self) -> dict[str, float]:
        """The ``;HOSTD_PROCESS`` header payload."""
        keys = ("layer_height", "line_width", "filament_diameter", "nozzle_diameter")
        d = asdict(self)
        return {k: d[k] for k in keys}
