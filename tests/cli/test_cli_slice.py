"""hostctl slice: offline slicing to checked G-code, one-line errors."""

from __future__ import annotations

import json
import re

import pytest

from hostd.cli.main import main
from slicer.mesh.samples import cylinder


@pytest.fixture(scope="module")
def stl(tmp_path_factory):
    path = tmp_path_factory.mktemp("models") / "cyl.stl"
    cylinder(radius=6.0, height=12.0).export(path)
    return path


def test_slice_writes_checked_gcode_and_summary(stl, tmp_path, capsys):
    out, png = tmp_path / "out.gcode", tmp_path / "out.png"
    rc = main(["slice", str(stl), "-o", str(out), "--layer-height", "0.3", "--preview",
               str(png)])
    assert rc == 0
    lines = out.read_text().splitlines()
    assert lines[0].startswith(";HOSTD_KINEMATICS ")
    assert json.loads(lines[1].split(" ", 1)[1])["layer_height"] == 0.3
    assert png.stat().st_size > 1000
    text = capsys.readouterr().out
    for word in ("sub-parts 1", "layers", "filament", "time", "replay: inside",
                 "collisions 0", "seconds"):
        assert word in text
    stages = text.split("seconds ", 1)[1]
    named = [part.split()[0] for part in stages.split("(", 1)[1].rstrip(")\n").split(", ")]
    assert named == ["load", "plan", "gcode", "read", "replay", "text"]
    assert "text " in stages and "beside the replay" in stages


@pytest.mark.parametrize(("args", "message"), [
    (["slice", "/nonexistent.stl", "-o", "x.gcode"], "/nonexistent.stl"),
    (["slice", "{stl}", "-o", "x.gcode", "--layer-height", "0.9"], "--layer-height"),
    (["slice", "{stl}", "-o", "x.gcode", "--config", "/nonexistent.yaml"], "no such file"),
    (["slice", "{stl}", "-o", "x.gcode", "--preview", "{tmp}/p.xyz"], "name a *.png file"),
    (["slice", "{stl}", "-o", "x.gcode", "--preview", "{tmp}/p"], "name a *.png file"),
    (["slice", "{stl}", "-o", "x.gcode", "--preview", "{tmp}/no/p.png"], "no such directory"),
])
def test_bad_input_is_one_line_and_nonzero(stl, tmp_path, capsys, args, message):
    argv = [a.format(stl=stl, tmp=tmp_path) for a in args]
    argv[argv.index("-o") + 1] = str(tmp_path / "x.gcode")
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc != 0 and message in err and len(err.splitlines()) == 1
    assert not (tmp_path / "x.gcode").exists()


def test_the_model_is_never_its_own_output(tmp_path, capsys):
    model = tmp_path / "part.stl"
    cylinder(radius=6.0, height=12.0).export(model)
    before = model.read_bytes()
    rc = main(["slice", str(model), "-o", str(tmp_path / "." / "part.stl")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "that is the model itself" in err and len(err.splitlines()) == 1
    assert model.read_bytes() == before


def test_a_part_turned_to_stand_says_so(tmp_path, capsys):
    import trimesh

    lying = cylinder(radius=6.0, height=12.0)
    lying.apply_transform(trimesh.transformations.rotation_matrix(0.6, [1.0, 0.0, 0.0]))
    model, out = tmp_path / "tilted.stl", tmp_path / "t.gcode"
    lying.export(model)
    assert main(["slice", str(model), "-o", str(out), "--layer-height", "0.3"]) == 0
    turned = re.search(r"placed turned (\d+)° from the file's orientation",
                       capsys.readouterr().out)
    assert turned is not None and int(turned[1]) in (34, 146)  # onto either end disc
    upright = tmp_path / "upright.stl"
    cylinder(radius=6.0, height=12.0).export(upright)
    assert main(["slice", str(upright), "-o", str(out), "--layer-height", "0.3"]) == 0
    assert "placed turned" not in capsys.readouterr().out


def test_overlapping_shells_slice_as_one_solid_and_say_so(tmp_path, capsys):
    import trimesh

    cube = trimesh.creation.box([20.0, 20.0, 20.0])
    post = trimesh.creation.box([10.0, 10.0, 30.0])
    post.apply_translation([5.0, 0.0, 5.0])  # through the cube's +x half, 10 mm above it
    model, out = tmp_path / "overlap.stl", tmp_path / "overlap.gcode"
    trimesh.util.concatenate([cube, post]).export(model)
    assert main(["slice", str(model), "-o", str(out), "--layer-height", "0.3"]) == 0
    text = capsys.readouterr().out
    assert "merged 2 overlapping shells of the file into one solid" in text
    assert "collisions 0" in text and out.stat().st_size > 0


def test_a_pipe_upside_down_slices_standing_on_its_base(tmp_path, capsys):
    """pipe2 exported turned 180° about X stood on its tube's rim and was refused (exit 1);
    it is stood on its base disc, says so, and the replay checks it as it stands."""
    from pathlib import Path

    import numpy as np
    import trimesh

    mesh = trimesh.load_mesh(Path(__file__).resolve().parents[3] / "shared" / "models"
                             / "pipe2.stl")
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi, [1.0, 0.0, 0.0]))
    model, out = tmp_path / "pipe2_upside_down.stl", tmp_path / "p.gcode"
    mesh.export(model)
    rc = main(["slice", str(model), "-o", str(out)])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert ("turned to stand on its 804 mm² face (normal +Z in the file), 180° from the file's "
            "orientation: standing as placed, on its 113 mm² face (normal -Z in the file), it "
            "was refused: ") in text
    assert "placed turned" not in text and "collisions 0" in text and "sub-parts 2" in text
    inside = re.search(r"replay: inside (\d+\.\d+)%", text)
    assert inside is not None and float(inside[1]) > 99.0  # checked against the turned part
    header = next(line for line in out.read_text().splitlines()[:8]
                  if line.startswith(";HOSTD_PLACEMENT "))
    matrix = np.array(json.loads(header.split(" ", 1)[1])["matrix"])
    assert matrix[:3, :3] @ [0.0, 0.0, 1.0] == pytest.approx([0.0, 0.0, -1.0])
    placed = trimesh.transform_points(mesh.vertices, matrix)
    assert placed[:, 2].min() == pytest.approx(0.0, abs=1e-6)


def test_the_seconds_line_gives_the_closed_loops_stages_with_their_counts():
    from hostd.cli.cmd_slice import _stages

    line = _stages({"load": 0.1, "plan": 2.0, "gcode": 0.5, "replay": 1.0, "text": 0.2,
                    "repair": 7.66, "repair_rounds": 1.0, "alternatives": 48.4,
                    "alternatives_tried": 2.0, "plan.lean": 0.9})
    assert line == ("load 0.10, plan 2.00, gcode 0.50, replay 1.00, repair 7.66 (1 round), "
                    "alternatives 48.40 (2 tried), text 0.20 beside the replay")
