"""Replay check: a G-code file mapped back onto the part, and what it would build judged.

* :mod:`~slicer.replay.check`: :func:`replay_check` and :func:`replay_file`, the whole
  check and its :class:`ReplayReport`; :func:`model_index`, the model's queries built once.
* :mod:`~slicer.replay.samples`: the file's moves as platform-frame samples (beads, nozzle
  tips), from its own ``;HOSTD_KINEMATICS`` header.
* :mod:`~slicer.replay.support`: which beads rest on earlier material, and the layers printed
  in the air; :mod:`~slicer.replay.coverage`: how much of the part the beads fill.
* :mod:`~slicer.replay.walls`: the unsupported wall layers (:class:`WallLayer`) and their
  unsupported wall samples (:class:`WallSamples`), for a refusal to name and a preview to
  mark; :mod:`~slicer.replay.steepness`: how steep the surface is there, and the layer
  height that would hold it.
* :mod:`~slicer.replay.collide` and :mod:`~slicer.replay.tip_hits`: head collisions with
  material printed before and with the platform.
* :mod:`~slicer.replay.geometry`: distance to the surface and inside test of the model;
  :mod:`~slicer.replay.columns`: a closed mesh crossed by vertical lines.
* :mod:`~slicer.replay.stages`: the check's stages, in order or on a small thread pool;
  :mod:`~slicer.replay.kdtree` and :mod:`~slicer.replay.unique`: the KD-trees and sorted
  distinct values they share.

The other stages import what they need from here, not from the modules.
"""

from __future__ import annotations

from slicer.replay.check import (
    ReplayReport,
    model_index,
    overhang_text,
    replay_check,
    worst_layer_text,
)
from slicer.replay.coverage import shell_depth, shell_grid
from slicer.replay.geometry import ModelIndex
from slicer.replay.steepness import held_height, held_heights, overhang_deg, thickness_step
from slicer.replay.support import BAD_LAYER_SHARE, OVERHANG_DEG
from slicer.replay.walls import WallLayer, WallSamples, wall_layer_text

__all__ = [
    "BAD_LAYER_SHARE",
    "OVERHANG_DEG",
    "ModelIndex",
    "ReplayReport",
    "WallLayer",
    "WallSamples",
    "held_height",
    "held_heights",
    "model_index",
    "overhang_deg",
    "overhang_text",
    "replay_check",
    "shell_depth",
    "shell_grid",
    "thickness_step",
    "wall_layer_text",
    "worst_layer_text",
]
