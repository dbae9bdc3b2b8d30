"""hostctl decompose: its options keep the bounds of the config keys they override; a part
given upside down is stood on its base, or the refusal names it."""

from __future__ import annotations

from pathlib import Path

import pytest

from hostd.cli.main import main

MODELS = Path(__file__).resolve().parents[3] / "shared" / "models"  # as tests/slicer's


@pytest.mark.parametrize(("option", "value", "bounds"), [
    ("--parts", "65", "[0, 64] (as decompose.parts)"),
    ("--parts", "-1", "[0, 64] (as decompose.parts)"),
    ("--seed", "2147483648", "[0, 2147483647] (as decompose.seed)"),
    ("--seed", "-3", "[0, 2147483647] (as decompose.seed)"),
])
def test_an_option_past_its_keys_bounds_is_one_line_exit_2(tmp_path, capsys, option, value,
                                                          bounds):
    rc = main(["decompose", "/work/never-read.stl", "-o", str(tmp_path / "o"), option, value])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err == f"hostctl: {option} {value}: must lie in {bounds}"
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("verb", ["slice", "decompose"])
def test_without_config_the_printers_installed_config_is_used(tmp_path, capsys, monkeypatch,
                                                             verb):
    """On the printer's computer an offline slice is for that printer: without ``--config``
    the installed file is read (here one with a wrong key, which names it), and where there
    is none, the shipped defaults."""
    import hostd.config.paths as paths

    installed = tmp_path / "hostd.yaml"
    installed.write_text("machine:\n  name: mine\n  bogus: 1\n")
    monkeypatch.setattr(paths, "INSTALLED_CONFIG", installed)
    rc = main([verb, "/work/never-read.stl", "-o", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and str(installed) in err and "machine.bogus" in err
    assert paths.offline_config() == installed
    installed.unlink()
    assert paths.offline_config() == paths.DEFAULT_CONFIG


def _upside_down_pipe2(tmp_path):
    """pipe2 exported turned 180° about X: its base disc on top, the tube's rim down."""
    import trimesh

    mesh = trimesh.load_mesh(MODELS / "pipe2.stl")
    mesh.apply_transform(trimesh.transformations.rotation_matrix(3.141592653589793, [1, 0, 0]))
    path = tmp_path / "pipe2_upside_down.stl"
    mesh.export(path)
    return path


def test_a_part_upside_down_is_turned_onto_its_base_and_says_why(tmp_path, capsys):
    """Standing on the tube's 113 mm² rim it is refused; on its 804 mm² disc it decomposes."""
    import json

    import numpy as np

    out = tmp_path / "o"
    rc = main(["decompose", str(_upside_down_pipe2(tmp_path)), "-o", str(out), "--no-preview"])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert text.splitlines()[0].startswith(
        "turned to stand on its 804 mm² face (normal +Z in the file), 180° from the file's "
        "orientation: standing as placed, on its 113 mm² face (normal -Z in the file), it was "
        "refused: sub-part 0 overhangs ")
    record = json.loads((out / "decomposition.json").read_text())
    assert record["base"]["turned"] is True and record["base"]["normal_in_file"] == [0, 0, 1]
    assert len(record["base"]["tried"]) == 2 and len(record["subparts"]) == 2
    matrix = np.array(record["placement"])
    assert matrix[:3, :3] @ [0.0, 0.0, 1.0] == pytest.approx([0.0, 0.0, -1.0])
    assert sum(s["overhang_mm2"] for s in record["subparts"]) == pytest.approx(0.0, abs=5.0)


def test_with_a_fixed_root_the_refusal_names_the_larger_face(tmp_path, capsys):
    import json

    from hostd.cli.errors import EXIT_FAILED

    model = _upside_down_pipe2(tmp_path)
    rc = main(["decompose", str(model), "-o", str(tmp_path / "o"), "--root", "0"])
    err = capsys.readouterr().err.strip()
    assert rc == EXIT_FAILED and len(err.splitlines()) == 1
    assert err.startswith(f"hostctl: {model}: sub-part ")
    assert err.endswith("; the part stands on a 113 mm² face; its largest flat face (804 mm², "
                        "normal +Z in the file) is 7.1× larger and may decompose: turn the part "
                        "to stand on it, or leave the root region automatic (no --root) so the "
                        "slicer tries it")
    # refused, it still writes the refusal and a picture of the part with its point
    record = json.loads((tmp_path / "o" / "decomposition.json").read_text())
    assert record["refused"] == err.removeprefix(f"hostctl: {model}: ")
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["decomposition.json",
                                                                  "preview.png"]
    [(x, y, z)] = record["points"]  # the rim's overhang, now on top: in the placed frame
    assert z == pytest.approx(57.0, abs=1.0) and abs(x) < 10.0 and abs(y) < 10.0
    assert record["seed"] == 0 and record["parts"] == 0
