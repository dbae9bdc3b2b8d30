"""hostctl slice refuses parts that leave the machine: one line, exit 2, no file written."""

from __future__ import annotations

import manifold3d as m3
import pytest
import trimesh

from hostd.cli.errors import EXIT_USAGE
from hostd.cli.main import main
from slicer.mesh.samples import cylinder, to_trimesh


def _thin_wall_box() -> trimesh.Trimesh:
    solid = m3.Manifold.cube([20, 20, 10], True) - m3.Manifold.cube([19.4, 19.4, 12], True)
    return to_trimesh(solid.translate([0, 0, 5]))


MODELS = {
    "cylinder": lambda: cylinder(radius=6.0, height=12.0),
    "bar400": lambda: trimesh.creation.box([400, 20, 10]).apply_translation([0, 0, 5]),
    "thinwall": _thin_wall_box,
}


@pytest.mark.parametrize(("model", "config", "expected"), [
    # the first transition lifts safe_height (60) above the part's top (table Z 100 + 12)
    ("cylinder", "machine: {z_range: [0, 150]}",
     ["machine Z reaches 172.", "outside machine.z_range [0, 150]",
      "(transition to sub-part 0: the lift clears the part by process.safe_height 60 mm)"]),
    ("cylinder", "machine: {table_origin: [5, 250, 100], a_pivot: [5, 250, 80]}",
     ["machine X reaches -", "outside machine.x_range [0, 500]", "(sub-part 0, layer 0)"]),
    ("bar400", "",
     ["footprint radius 200.2 mm exceeds machine.platform_radius 150 mm"]),
    ("thinwall", "",
     ["nothing to print: walls thinner than the line width (0.45 mm)"]),
])
def test_outside_the_machine_is_one_line_exit_2_and_no_file(tmp_path, capsys, model, config,
                                                            expected):
    stl, cfg, out = tmp_path / f"{model}.stl", tmp_path / "m.yaml", tmp_path / "out.gcode"
    MODELS[model]().export(stl)
    cfg.write_text(config + "\n")
    rc = main(["slice", str(stl), "-o", str(out), "--config", str(cfg)])
    err = capsys.readouterr().err.strip()
    assert rc == EXIT_USAGE
    assert len(err.splitlines()) == 1 and err.startswith(f"hostctl: {stl}: ")
    for text in expected:
        assert text in err
    assert not out.exists()
