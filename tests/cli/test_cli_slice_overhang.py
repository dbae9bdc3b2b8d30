"""hostctl slice of a part whose replay finds unsupported wall layers: refused (exit 1, no
file) in one line naming the worst layer and only options the command has, its preview
drawn anyway with the unsupported walls in red; written with a warning under
``--allow-overhang``; ``--seed``/``--parts`` reach the decomposition.

The part is a small block with a horizontal bore: the bore's ceiling is a wall over air
whatever the closed loop tries, as is the lip of a tee's branch bore in the trunk
(``tests/slicer/test_replay_walls.py``); the block is one sub-part (every other
decomposition the loop tries is the same one) and sliced in a fraction of the tee's time.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hostd.cli.main import build_parser, main
from slicer.mesh.samples import bored_block
from slicer.repair import ALTERNATIVES  # seeds the closed loop tries after the first


@pytest.fixture(scope="module")
def bored(tmp_path_factory) -> Path:
    """A part whose bore's ceiling is an unsupported wall."""
    path = tmp_path_factory.mktemp("models") / "bored.stl"
    bored_block().export(path)
    return path


def _slice_options() -> set[str]:
    (sub,) = [a for a in build_parser()._actions if getattr(a, "choices", None)
              and "slice" in a.choices]
    return {o for a in sub.choices["slice"]._actions for o in a.option_strings}


def _red_share(png: Path) -> float:
    """Share of the picture's pixels that are pure-ish red (the marks)."""
    import matplotlib.image

    rgb = matplotlib.image.imread(png)[:, :, :3]
    red = (rgb[:, :, 0] > 0.8) & (rgb[:, :, 1] < 0.25) & (rgb[:, :, 2] < 0.25)
    return float(red.mean())


def test_a_file_with_unsupported_walls_is_refused_and_its_preview_marks_them(bored, tmp_path,
                                                                              capsys):
    out, png = tmp_path / "bored.gcode", tmp_path / "bored.png"
    rc = main(["slice", str(bored), "-o", str(out), "--preview", str(png)])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and not out.exists()
    assert len(err.splitlines()) == 1
    assert re.match(rf"hostctl: {re.escape(str(bored))}: replay found \d+ unsupported wall "
                    r"layers over air .*; refusing to write the file: worst sub-part \d+ layer "
                    r"\d+, [\d.]+% of its \d+ wall points unsupported, around \[.*\] mm \(part "
                    rf"frame\); try --seed {ALTERNATIVES + 1} \(or another seed\), another "
                    r"--parts \(the coarse "
                    r"part count\) or --allow-overhang to write it as it is$", err), err
    assert set(re.findall(r"--[a-z-]+", err)) <= _slice_options()
    assert _red_share(png) > 1e-4  # the preview is drawn, the failing walls in red


def test_allow_overhang_writes_it_with_a_warning_of_the_same_figures(bored, tmp_path, capsys):
    out, png = tmp_path / "bored.gcode", tmp_path / "bored.png"
    rc = main(["slice", str(bored), "-o", str(out), "--allow-overhang", "--preview", str(png)])
    captured = capsys.readouterr()
    assert rc == 0 and out.exists()
    (warning,) = [ln for ln in captured.err.splitlines() if ln.startswith("hostctl: warning:")]
    assert re.match(r"hostctl: warning: replay found \d+ unsupported wall layers over air .*; "
                    r"written "
                    r"anyway, as asked \(--allow-overhang\): worst sub-part \d+ layer \d+, "
                    r"[\d.]+% of its \d+ wall points unsupported, around \[", warning), warning
    count = int(re.search(r"found (\d+) unsupported", warning).group(1))
    assert f"unsupported wall layers, {count} over air" in captured.out  # the summary agrees
    assert _red_share(png) > 1e-4


def test_seed_and_parts_reach_the_decomposition(bored, tmp_path, monkeypatch, capsys):
    import slicer.pipeline

    seen: dict[str, Any] = {}

    def fake(model: str, **kw: Any) -> Any:
        seen.update(kw)
        raise slicer.pipeline.SliceError("stop here")

    monkeypatch.setattr(slicer.pipeline, "slice_model", fake)
    rc = main(["slice", str(bored), "-o", str(tmp_path / "o.gcode"), "--seed", "7",
               "--parts", "3", "--allow-overhang"])
    assert rc == 1 and "stop here" in capsys.readouterr().err
    dec = seen["decompose_settings"]
    assert (dec.seed, dec.parts, seen["allow_overhang"]) == (7, 3, True)
    rc = main(["slice", str(bored), "-o", str(tmp_path / "o.gcode")])
    assert seen["decompose_settings"].seed == 0 and seen["allow_overhang"] is False


@pytest.mark.parametrize(("option", "value", "bounds"), [
    ("--parts", "65", "[0, 64] (as decompose.parts)"),
    ("--seed", "-1", "[0, 2147483647] (as decompose.seed)"),
])
def test_seed_and_parts_keep_the_bounds_of_their_keys(bored, tmp_path, capsys, option,
                                                       value, bounds):
    rc = main(["slice", str(bored), "-o", str(tmp_path / "o.gcode"), option, value])
    assert rc == 2
    assert capsys.readouterr().err.strip() == f"hostctl: {option} {value}: must lie in {bounds}"
    assert not np.any([p.suffix == ".gcode" for p in tmp_path.iterdir()])
