"""Configuration → the plain values the slicer takes (``slicer`` never reads YAML).

``process.*`` and the extrusion/motion keys of ``machine.*`` become
:class:`~slicer.settings.ProcessSettings`; ``machine.*`` the
:class:`~kinematics.machine.MachineGeometry`; ``printhead.segments`` the
:class:`~slicer.printhead.Printhead`; ``decompose.*`` the decomposition settings.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hostd.config.loader import Config
from hostd.config.placeholders import process_values
from kinematics.machine import MachineGeometry
from slicer.printhead import Printhead
from slicer.settings import ProcessSettings


def process_settings(cfg: Config, **override: Any) -> ProcessSettings:
    """ProcessSettings from ``process.*`` and ``machine.*`` (``override`` wins)."""
    return ProcessSettings(**{**process_values(cfg), **override})


def machine_geometry(cfg: Config) -> MachineGeometry:
    """The table geometry and limits of ``machine.*``."""
    c_lim = cfg["machine.c_limits"]
    return MachineGeometry(tuple(cfg["machine.table_origin"]), tuple(cfg["machine.a_pivot"]),
                           tuple(cfg["machine.a_limits"]),
                           None if c_lim is None else tuple(c_lim))


def printhead(cfg: Config) -> Printhead:
    """The head of ``printhead.segments`` (raises PrintheadError if malformed)."""
    return Printhead.from_records(cfg["printhead.segments"])


def platform_radius(cfg: Config) -> float:
    """``machine.platform_radius``, mm."""
    return float(cfg["machine.platform_radius"])


def build_volume(cfg: Config) -> np.ndarray:
    """Largest part extents (x, y, z) the machine travel allows, mm."""
    return np.array([hi - lo for lo, hi in (cfg[f"machine.{a}_range"] for a in "xyz")],
                    dtype=float)


def travel(cfg: Config) -> tuple[tuple[float, float], ...]:
    """[min, max] of machine X, Y and Z (``machine.x_range`` ...), mm."""
    return tuple((float(lo), float(hi)) for lo, hi in (cfg[f"machine.{a}_range"] for a in "xyz"))


def decompose_settings(cfg: Config, **override: Any) -> Any:
    """DecomposeSettings of ``decompose.*`` (``override`` wins)."""
    from slicer.decompose import DecomposeSettings, SearchSettings

    search = SearchSettings(offset_max=cfg["decompose.plane_offset_max"],
                            angle_max=cfg["decompose.plane_angle_max"],
                            area_growth_max=cfg["decompose.area_growth_max"],
                            max_iterations=cfg["decompose.max_iterations"])
    values: dict[str, Any] = {"parts": cfg["decompose.parts"], "seed": cfg["decompose.seed"],
                              "search": search,
                              "nozzle_diameter": cfg["machine.nozzle_diameter"]}
    values.update(override)
    return DecomposeSettings(**values)


def slice_inputs(cfg: Config, decompose: dict[str, Any] | None = None, **override: Any
                 ) -> dict[str, Any]:
    """Keyword arguments of :func:`slicer.pipeline.slice_model` for this config.

    ``override`` replaces process settings (e.g. ``layer_height``), ``decompose`` the
    decomposition's (``seed``, ``parts``). Raises PrintheadError, TypeError or ValueError
    for values the slicer cannot take.
    """
    return {"settings": process_settings(cfg, **override), "geometry": machine_geometry(cfg),
            "head": printhead(cfg),
            "decompose_settings": decompose_settings(cfg, **(decompose or {})),
            "platform_radius": platform_radius(cfg), "build_volume": build_volume(cfg),
            "travel": travel(cfg)}
