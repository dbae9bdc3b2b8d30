"""The replay's support rule at thin layers: solid skins crossing the lines below are not
reported unsupported (the cone one layer down is narrower than half a line), while a real
ledge still is."""

from __future__ import annotations

import manifold3d as m3
import pytest

from kinematics.machine import MachineGeometry
from slicer.gcode.reader import parse_lines
from slicer.mesh.samples import to_trimesh
from slicer.pipeline import OverhangError, slice_model
from slicer.printhead import Printhead
from slicer.replay.check import replay_check
from slicer.replay.support import THIN_LAYER
from slicer.settings import ProcessSettings

GEO = MachineGeometry()
THIN = ProcessSettings(layer_height=0.05)


def _slice(solid: m3.Manifold, settings: ProcessSettings) -> dict:
    return slice_model(to_trimesh(solid), settings, GEO, Printhead.default(), planar=True).replay


def test_thin_layers_are_below_the_threshold_and_the_default_is_not():
    assert THIN.layer_height < THIN_LAYER * THIN.line_width
    assert ProcessSettings().layer_height >= THIN_LAYER * ProcessSettings().line_width


@pytest.mark.parametrize("settings", [THIN, ProcessSettings()], ids=["0.05", "0.2"])
def test_a_cylinder_is_supported_everywhere(settings: ProcessSettings):
    rep = _slice(m3.Manifold.cylinder(3.0, 5.0, 5.0, 48), settings)
    assert rep["wall_supported"] >= 0.995 and rep["unsupported_wall_layers"] == []
    assert rep["supported"] >= 0.99


@pytest.mark.parametrize("settings", [THIN, ProcessSettings()], ids=["0.05", "0.2"])
def test_a_ledge_is_still_unsupported(settings: ProcessSettings):
    """A disc r 6 on a post r 3: the disc's first layers hang 3 mm out over the air. The
    slice is refused (a layer in the air); the replay of its G-code shows the ledge."""
    post = m3.Manifold.cylinder(2.0, 3.0, 3.0, 48)
    disc = m3.Manifold.cylinder(1.0, 6.0, 6.0, 48).translate((0.0, 0.0, 2.0))
    with pytest.raises(OverhangError, match="layer printed in the air"):
        _slice(post + disc, settings)
    res = slice_model(to_trimesh(post + disc), settings, GEO, Printhead.default(), planar=True,
                      check=False)
    rep = replay_check(parse_lines(res.lines), to_trimesh(post + disc))
    assert rep.wall_supported < 0.99
    assert rep.unsupported_wall_layers
    assert rep.overhang_layers[0]["z"] == pytest.approx(2.0 + settings.layer_height)
