"""Unsupported wall layers: described by the replay (where, how bad), refused by the slicer
unless allowed, and marked in the preview.

A small tee (a tube with a horizontal branch) leaves a lip of the branch's underside in the
trunk: the replay finds unsupported wall layers there (``docs/decomposition.md``, known
limits). The part is given away from the STL origin, so that a point named in the part's
frame is told apart from one in the platform frame.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pytest
import trimesh

from kinematics.machine import MachineGeometry
from slicer import pipeline
from slicer.advice import PRINT_OPTIONS, SLICE_OPTIONS, walls_message
from slicer.mesh.samples import branched_pipe
from slicer.pipeline import (
    OverhangPolicy,
    SliceResult,
    UnsupportedWallsError,
    slice_model,
    walls_verdict,
)
from slicer.printhead import Printhead
from slicer.repair import ALTERNATIVES
from slicer.replay.geometry import ModelIndex
from slicer.replay.support import BAD_LAYER_SHARE
from slicer.replay.walls import (
    MAX_WALL_SAMPLES,
    WallLayerPoints,
    WallSamples,
    wall_layers,
    worst_first,
)
from slicer.settings import ProcessSettings

GEO = MachineGeometry()
OFFSET = np.array([30.0, -20.0, 5.0])  # where the STL lies: not the platform frame
BRANCH_Z, BRANCH_R, BRANCH_LENGTH, TUBE_R = 7.0, 4.5, 12.0, 6.0


def small_tee() -> trimesh.Trimesh:
    """A tube R6 × 14 on a disc R9 with a horizontal branch R4.5 at z 7, 12 mm long from the
    tube's axis, moved to OFFSET; 32 facets around a circle (the closed loop refuses it for
    the same lip as a tube R10 × 26 with a branch R7, in half the time)."""
    mesh = branched_pipe(((BRANCH_Z, 0.0, 0.0),), radius=TUBE_R, height=14.0,
                         branch_radius=BRANCH_R, branch_length=BRANCH_LENGTH, base_radius=9.0,
                         base_height=2.0, segments=32)
    return mesh.apply_translation(OFFSET)


def _slice(**kw: object) -> SliceResult:
    return slice_model(small_tee(), ProcessSettings(), GEO, Printhead.default(), **kw)


@dataclass
class _Verdicts:
    """The tee sliced once with ``allow_overhang=True``, and the refusal of the same file."""

    allowed: SliceResult
    refused: UnsupportedWallsError


@pytest.fixture(scope="module")
def verdicts() -> _Verdicts:
    """One closed loop for both policies. :func:`slice_model` reads the overhang policy only
    where it judges the try it keeps, by one call of :func:`walls_verdict` (the loop's own
    tries are written unjudged); refused, that call raises out of :func:`slice_model` as it
    is. So the refusal is that very call again, with the allowing policy turned back to the
    default (refuse), on the arguments the allowed slice judged."""
    calls: list[tuple[Any, ...]] = []

    def judged(*args: Any) -> str | None:
        calls.append(args)
        return walls_verdict(*args)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(pipeline, "walls_verdict", judged)
        allowed = _slice(allow_overhang=True, keep_plan=True)
    (call,) = calls
    rep, plan, seed, policy, thinner = call
    assert policy == OverhangPolicy(allow=True)
    with pytest.raises(UnsupportedWallsError) as err:
        walls_verdict(rep, plan, seed, replace(policy, allow=False), thinner)
    return _Verdicts(allowed, err.value)


@pytest.fixture(scope="module")
def refused(verdicts: _Verdicts) -> UnsupportedWallsError:
    return verdicts.refused


@pytest.fixture(scope="module")
def allowed(verdicts: _Verdicts) -> SliceResult:
    return verdicts.allowed


def _distance(points: np.ndarray, limit: float) -> np.ndarray:
    """Distance of points (n, 3) to the tee's surface where within ``limit``, else inf."""
    mesh = small_tee()
    return ModelIndex(np.asarray(mesh.vertices), np.asarray(mesh.faces)).distance(points, limit)


def _worst_clause(text: str) -> str:
    return text.split("worst ", 1)[1].split("; try", 1)[0]


def test_the_refusal_is_one_line_naming_the_worst_layer_and_what_to_try(refused, allowed):
    msg = str(refused)
    assert "\n" not in msg
    n = allowed.replay["wall_layers_over_air"]
    worst = allowed.replay["wall_layers"][0]
    assert msg.startswith(f"replay found {n} unsupported wall layers over air (over 5% of a "
                          "layer's wall points with nothing beneath them within 45° and no "
                          "sparse infill to bridge); ")
    assert (f"refusing to write the file: worst sub-part {worst['subpart']} layer "
            f"{worst['layer']}, {100 * worst['share']:.1f}% of its {worst['wall_points']} wall "
            "points unsupported, around [") in msg
    # the seed after those the closed loop tried (seed 0, then ALTERNATIVES more)
    assert msg.endswith(f"mm (part frame); try decompose.seed {ALTERNATIVES + 1} (or another "
                        "seed), another decompose.parts (the coarse part count) or "
                        "allow_overhang=True to write it as it is")


def test_the_refusal_names_a_point_of_the_branch_underside_in_the_stl_frame(refused):
    at = re.search(r"around \[(.*?)\] mm \(part frame\)", str(refused))
    assert at is not None
    point = np.array([float(v) for v in at.group(1).split(",")])
    x, y, z = point - OFFSET
    # the lip of the branch (+x) under its axis, beside the trunk (within 4/5 of the branch's
    # length outside it), in the file's coordinates
    assert TUBE_R - 1.0 < x < TUBE_R + 0.8 * (BRANCH_LENGTH - TUBE_R) and abs(y) < BRANCH_R
    assert BRANCH_Z - BRANCH_R - 0.5 < z < BRANCH_Z
    assert _distance(point[None], 1.0)[0] < 1.0


def test_the_refusal_carries_the_plan_and_the_unsupported_wall_samples(refused, allowed):
    assert refused.plan is not None and len(refused.plan.subparts) == allowed.subparts
    marks = refused.marks
    assert marks.shape[1] == 3 and 0 < len(marks) <= MAX_WALL_SAMPLES
    assert np.array_equal(marks, allowed.walls.p)
    # platform frame: moved back by the placement they lie on the part given
    place = refused.plan.placement
    back = (marks - place[:3, 3]) @ np.linalg.inv(place[:3, :3]).T
    near = 0.75 * ProcessSettings().line_width + 0.2
    assert np.mean(_distance(back, near) <= near) > 0.95


def test_allowed_the_file_is_returned_with_a_warning_naming_the_same_figures(refused, allowed):
    assert allowed.lines and allowed.warning is not None and "\n" not in allowed.warning
    assert allowed.warning.startswith(str(refused).split(";", 1)[0])
    assert "written anyway, as asked (allow_overhang=True)" in allowed.warning
    assert _worst_clause(allowed.warning) == _worst_clause(str(refused))
    assert "walls" not in allowed.summary()  # the arrays stay out of the plain summary


def test_the_report_describes_every_unsupported_wall_layer_worst_first(allowed):
    rep = allowed.replay
    layers = rep["wall_layers"]
    names = [f"sub-part {w['subpart']} layer {w['layer']}" for w in layers]
    assert len(names) == rep["wall_layers_over_air"]  # fewer than the cap
    # over air: the unsupported wall layers (strict rule) whose walls bridge no infill
    assert set(names) <= set(rep["unsupported_wall_layers"])
    shares = [w["share"] for w in layers]
    assert shares == sorted(shares, reverse=True) and min(shares) > BAD_LAYER_SHARE
    for w in layers:
        assert w["share"] == pytest.approx(w["unsupported"] / w["wall_points"], abs=1e-4)
    walls = allowed.walls
    assert walls.total >= len(walls) > 0
    bad = {(w["subpart"], w["layer"]) for w in layers}
    assert {(int(s), int(k)) for s, k in zip(walls.subpart, walls.layer, strict=True)} == bad


def test_every_option_a_refusal_of_hostctl_slice_names_exists(allowed):
    from hostd.cli.main import build_parser
    from slicer.replay import ReplayReport

    rep = ReplayReport(**{k: v for k, v in allowed.replay.items() if k != "wall_layers"})
    rep.wall_layers = _layers(allowed.replay["wall_layers"])
    msg = walls_message(rep, 0, SLICE_OPTIONS, (0.13, 53.4))
    named = set(re.findall(r"--[a-z-]+", msg))
    assert named == {"--seed", "--parts", "--allow-overhang", "--layer-height"}
    assert "--layer-height 0.13 or thinner" in msg
    assert "--layer-height" not in walls_message(rep, 0, PRINT_OPTIONS, (0.13, 53.4))
    (sub,) = [a for a in build_parser()._actions if hasattr(a, "choices") and a.choices
              and "slice" in a.choices]
    offered = {o for a in sub.choices["slice"]._actions for o in a.option_strings}
    assert named <= offered


def _layers(dicts: list[dict]) -> list:
    from slicer.replay import WallLayer

    return [WallLayer(**{**d, "point": tuple(d["point"]) if d["point"] else None})
            for d in dicts]


# -- wall_layers on seeded random points, against a plain count ------------------------------

@pytest.mark.parametrize("seed", [0, 1, 2])
def test_wall_layers_are_those_over_the_share_with_their_counts(seed):
    rng = np.random.default_rng(seed)
    m = 4000
    seq = np.sort(rng.integers(0, 40, m))
    wall = rng.random(m) < 0.4
    supported = rng.random(m) > rng.choice([0.0, 0.03, 0.3], 40)[seq]  # some bad layers
    p = rng.normal(size=(m, 3)) + seq[:, None] * [0.0, 0.0, 0.2]
    points = WallLayerPoints(p, seq, seq // 10, seq % 10, wall, supported)
    to_part = np.eye(4)
    to_part[:3, 3] = [1.0, 2.0, 3.0]
    layers, samples = wall_layers(points, to_part)
    expected = []
    for k in np.unique(seq[wall]):
        here = wall & (seq == k)
        bad = here & ~supported
        if bad.sum() / here.sum() > BAD_LAYER_SHARE:
            expected.append((int(k), int(here.sum()), int(bad.sum())))
    assert [(w.seq, w.wall_points, w.unsupported) for w in layers] == expected
    assert expected and len(expected) < len(np.unique(seq))  # both kinds of layer
    for w in layers:
        assert (w.subpart, w.layer) == (w.seq // 10, w.seq % 10)
        mine = p[wall & ~supported & (seq == w.seq)] + [1.0, 2.0, 3.0]
        assert np.min(np.linalg.norm(mine - np.array(w.point), axis=1)) < 0.01
    assert samples.total == len(samples) == sum(e[2] for e in expected)
    assert set(samples.layer.tolist()) <= {e[0] % 10 for e in expected}


def test_the_samples_are_thinned_evenly_to_the_cap_and_layers_sorted_worst_first():
    p = np.arange(30.0).reshape(10, 3)
    one = WallSamples(p, np.zeros(10, np.int32), np.arange(10, dtype=np.int32), 10)
    joined = WallSamples.joined([one, one], cap=5)
    assert len(joined) == 5 and joined.total == 20
    assert joined.layer.tolist() == [0, 5, 0, 4, 9]  # of 20: 0, 5, 10, 14, 19
    layers = _layers([{"subpart": 0, "layer": i, "seq": i, "wall_points": 10,
                       "unsupported": 1 + i % 3, "share": (1 + i % 3) / 10, "z": 0.0,
                       "point": None} for i in range(7)])
    assert [w.seq for w in worst_first(layers, cap=4)] == [2, 5, 1, 4]
