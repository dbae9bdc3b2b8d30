"""G-code writer: headers, markers, extrusion and the kinematic round trip through the text."""

from __future__ import annotations

import json
import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from handmade_plans import H, W, box_plan, two_part_plan

from kinematics.machine import MachineGeometry
from kinematics.transform import forward, inverse
from slicer.gcode.extrusions import forward_at
from slicer.gcode.format import DECIMALS, format_moves, format_moves_reference
from slicer.gcode.reader import parse_lines, parse_words
from slicer.gcode.writer import MachineSetup, draft, generate, path_extrusion
from slicer.plan import Layer, Path, PrintPlan, SubpartPlan
from slicer.replay.check import part_frame_path
from slicer.settings import ProcessSettings

GEO = MachineGeometry()
SETTINGS = ProcessSettings()


def _clean_two_part() -> tuple[PrintPlan, np.ndarray]:
    plan, d = two_part_plan(GEO, tilt_deg=30.0)
    return plan, d


@pytest.fixture(scope="module")
def two_part():
    plan, _ = _clean_two_part()
    res = generate(plan, SETTINGS, MachineSetup(GEO))
    return plan, res, parse_lines(res.lines)


def _planned_path(plan: PrintPlan) -> np.ndarray:
    pts = []
    for sp in plan.subparts:
        for la in sp.layers:
            for p in la.paths:
                v, _ = path_extrusion(p, 1.0)
                pts.append(v[1:])
    return np.concatenate(pts)


def test_headers_come_first_with_the_fixed_names(two_part):
    _, res, _ = two_part
    names = ["KINEMATICS", "PROCESS", "PLACEMENT", "ESTIMATE"]
    for line, name in zip(res.lines[:4], names, strict=True):
        assert line.startswith(f";HOSTD_{name} {{")
        json.loads(line.split(" ", 1)[1])
    kin = json.loads(res.lines[0].split(" ", 1)[1])
    assert kin["type"] == "xyzac-trt"
    assert kin["table_origin"] == list(GEO.table_origin)
    assert kin["a_pivot"] == list(GEO.a_pivot)
    proc = json.loads(res.lines[1].split(" ", 1)[1])
    assert proc["layer_height"] == SETTINGS.layer_height
    assert proc["line_width"] == SETTINGS.line_width
    assert np.allclose(json.loads(res.lines[2].split(" ", 1)[1])["matrix"], np.eye(4))
    est = json.loads(res.lines[3].split(" ", 1)[1])
    assert est["filament_mm"] > 0 and est["time_s"] > 0


def test_only_g0_g1_absolute_axes_relative_e(two_part):
    _, res, _ = two_part
    heads = {ln.split()[0] for ln in res.lines if ln and not ln.startswith(";")}
    assert heads <= {"G0", "G1", "G28", "G90", "G92", "M83", "M104", "M140", "M84", "M106"}
    assert "M83" in heads and "G90" in heads


def test_round_trip_through_text_matches_plan(two_part):
    plan, _, parsed = two_part
    replayed = part_frame_path(parsed)
    planned = _planned_path(plan)
    assert replayed.shape == planned.shape
    assert np.abs(replayed - planned).max() < 0.01


def test_round_trip_with_placement_maps_back_to_stl_frame():
    plan, _ = _clean_two_part()
    place = np.eye(4)
    place[:3, 3] = (3.0, -2.0, 1.5)
    plan.placement = place
    parsed = parse_lines(generate(plan, SETTINGS, MachineSetup(GEO)).lines)
    stl = part_frame_path(parsed)
    assert np.abs(stl + place[:3, 3] - _planned_path(plan)).max() < 0.01


def test_extrusion_matches_bead_volume():
    pts = np.array([[0.0, 0.0, H], [20.0, 0.0, H]])
    path = Path("infill", pts, np.full(2, H), W, 40.0)
    layer = Layer(0, 0, np.zeros(3), np.array([0.0, 0.0, 1.0]), 0.0, 0.0, (H, H), [path])
    plan = PrintPlan(np.eye(4), [SubpartPlan(0, None, None, None, np.array([0, 0, 1.0]),
                                             [layer])])
    parsed = parse_lines(generate(plan, SETTINGS, MachineSetup(GEO)).lines)
    moving = np.linalg.norm(np.nan_to_num(parsed.end - parsed.start)[:, :3], axis=1) > 0
    e = parsed.e[moving & (parsed.e > 0)]
    expected = W * H * 20.0 / (math.pi * SETTINGS.filament_diameter ** 2 / 4)
    assert e.sum() == pytest.approx(expected, rel=1e-4)


def test_markers_delimit_subparts_layers_interfaces(two_part):
    plan, res, parsed = two_part
    subs = [json.loads(ln.split(" ", 1)[1]) for ln in res.lines
            if ln.startswith(";HOSTD_SUBPART ")]
    assert subs == [{"index": 0, "parent": None}, {"index": 1, "parent": 0}]
    layers = [json.loads(ln.split(" ", 1)[1]) for ln in res.lines
              if ln.startswith(";HOSTD_LAYER ")]
    assert layers == [{"subpart": sp.index, "index": la.index}
                      for sp in plan.subparts for la in sp.layers]
    inter = [ln for ln in res.lines if ln.startswith(";HOSTD_INTERFACE ")]
    assert [json.loads(x.split(" ", 1)[1]) for x in inter] == [{"parent": 0, "child": 1}]
    ext = (parsed.e > 0) & (np.linalg.norm(np.nan_to_num(parsed.end - parsed.start)[:, :3],
                                           axis=1) > 0)
    assert (parsed.layer[ext] >= 0).all() and not parsed.transition[ext].any()


def test_transition_block_ends_at_the_announced_pose(two_part):
    _, res, parsed = two_part
    assert res.lines.count(";HOSTD_TRANSITION_END") == 2
    for t in parsed.transitions:
        last = parsed.end[t["last"]]
        assert np.allclose(last, [t["x"], t["y"], t["z"], t["a"], t["c"]], atol=0)
        block = slice(t["first"], t["last"] + 1)
        assert (parsed.e[block] == 0).all()
        turning = np.abs(np.nan_to_num(parsed.end[block, 3:] - parsed.start[block, 3:])
                         ).max(axis=1) > 0
        assert (parsed.end[block][turning, 2] >= t["safe_z"] - 1e-3).all()


def test_transition_target_is_above_the_first_point(two_part):
    plan, _, parsed = two_part
    t = parsed.transitions[1]
    layer = plan.subparts[1].layers[0]
    first = layer.paths[0].points[0]
    above = forward(first, layer.a, layer.c, GEO) + np.array([0.0, 0.0, SETTINGS.z_hop])
    assert np.allclose([t["x"], t["y"], t["z"]], above, atol=1e-3)
    assert (t["a"], t["c"]) == pytest.approx((layer.a, layer.c))


def test_safe_height_clears_the_part_at_both_poses(two_part):
    plan, _, parsed = two_part
    pts = _planned_path(plan)
    for t in parsed.transitions[1:]:
        prev = parsed.start[t["first"]]
        for a, c in ((prev[3], prev[4]), (t["a"], t["c"])):
            top = forward(pts, a, c, GEO)[:, 2].max()
            assert t["safe_z"] >= top + SETTINGS.safe_height - 1e-6


def test_reorientation_inside_a_subpart_is_linearised():
    plan = box_plan(GEO, n_layers=2)
    second = plan.subparts[0].layers[1]
    second.a, second.c = 10.0, 0.0  # same plane, turned table: the tip must go straight
    parsed = parse_lines(generate(plan, SETTINGS, MachineSetup(GEO)).lines)
    turning = np.flatnonzero(np.abs(np.nan_to_num(parsed.end[:, 3] - parsed.start[:, 3])) > 0)
    turning = turning[~parsed.transition[turning]]
    assert len(turning) > 1  # split into several joint moves

    tips = inverse(parsed.end[turning, :3], parsed.end[turning, 3], parsed.end[turning, 4],
                   GEO)
    start = inverse(parsed.start[turning[0], :3], parsed.start[turning[0], 3],
                    parsed.start[turning[0], 4], GEO)
    d = tips[-1] - start
    rel = tips - start
    off = np.linalg.norm(rel - np.outer(rel @ d / (d @ d), d), axis=1)
    assert off.max() < 0.02


def test_start_and_end_gcode_with_placeholders():
    s = ProcessSettings(start_gcode="M104 S{nozzle_temperature}\nG28\n",
                        end_gcode="G0 Z{safe_z} F3000\nG0 A0 C0\n")
    plan, _ = _clean_two_part()
    lines = generate(plan, s, MachineSetup(GEO)).lines
    assert "M104 S210.0" in lines
    end_z = next(ln for ln in lines if ln.startswith("G0 Z") and ln.endswith("F3000"))
    assert float(end_z.split()[1][1:]) > 60.0


def _same_parse(a, b) -> None:
    for f in ("start", "end", "e", "feed", "g", "line", "subpart", "layer", "layer_seq",
              "transition"):
        x, y = getattr(a, f), getattr(b, f)
        assert x.shape == y.shape, f
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-12, err_msg=f)
    assert a.headers == b.headers and a.parents == b.parents
    assert a.interfaces == b.interfaces and a.transitions == b.transitions


@pytest.mark.parametrize("start", ["", "G28\nG1 Z5 F600\n", "M82\nG92 E0\nG1 E2 F300\n"])
def test_numeric_moves_parse_as_their_text(start):
    s = ProcessSettings(start_gcode=start)
    plan, _ = _clean_two_part()
    res = generate(plan, s, MachineSetup(GEO))
    _same_parse(parse_lines(res.lines), parse_words(res.words()))


def test_a_draft_reads_as_its_finished_file_but_for_the_estimate():
    """The slicer replays a draft while its text is formatted on another thread: the moves,
    markers, line numbers and every header but the estimate must be the file's."""
    plan, _ = _clean_two_part()
    moves = draft(plan, SETTINGS, MachineSetup(GEO))
    early = parse_words(moves.words())
    with ThreadPoolExecutor(1) as writer:
        res = writer.submit(moves.finish).result()
    final = parse_lines(res.lines)
    assert res.lines == generate(plan, SETTINGS, MachineSetup(GEO)).lines
    assert early.headers["ESTIMATE"]["time_s"] == 0.0 < final.headers["ESTIMATE"]["time_s"]
    early.headers["ESTIMATE"] = final.headers["ESTIMATE"]
    _same_parse(final, early)


def test_bulk_move_text_is_the_percent_format_of_each_word():
    rng = np.random.default_rng(7)
    n = 5000
    scale = rng.choice([1e-4, 1e-2, 1.0, 10.0, 999.0, 1e5], size=(n, 7))
    raw = rng.normal(size=(n, 7)) * scale
    raw[rng.random((n, 7)) < 0.05] = -0.0
    raw[rng.random((n, 7)) < 0.05] = 0.0
    vals = np.column_stack([np.round(raw[:, k], d) for k, d in enumerate(DECIMALS)])
    mask = rng.random((n, 7)) < 0.6
    g1 = rng.random(n) < 0.5
    assert format_moves(vals, mask, g1) == format_moves_reference(vals, mask, g1)
    assert format_moves(vals[:0], mask[:0], g1[:0]) == []


def test_written_lines_are_the_reference_text_of_the_moves(two_part):
    _, res, _ = two_part
    expected = []
    for item in res.words():
        expected += [item] if isinstance(item, str) else format_moves_reference(*item)
    assert res.lines == expected


def test_joint_positions_at_one_pose_are_the_kinematics_forward():
    rng = np.random.default_rng(3)
    pts = rng.uniform(-80.0, 80.0, (500, 3))
    for a, c in ((0.0, 0.0), (37.5, -212.25), (-90.0, 719.0)):
        assert np.array_equal(forward_at(pts, a, c, GEO), forward(pts, a, c, GEO))


def test_a_marlin_reading_of_the_file_extrudes_what_the_slicer_planned(two_part):
    """Marlin 2 clears relative E on G90: the file must set G90 before M83, or the
    relative E values are read as absolute positions and almost nothing is extruded.
    ``ModalState`` follows Marlin's rules (as the emulator does)."""
    from hostd.printer.modal import ModalState

    _, res, parsed = two_part
    marlin = ModalState()
    marlin.apply_many([ln.split(";", 1)[0].strip() for ln in res.lines
                       if ln.split(";", 1)[0].strip()])
    est = json.loads(res.lines[3].split(" ", 1)[1])["filament_mm"]
    assert est > 0
    assert marlin.extruded == pytest.approx(float(parsed.e.sum()), rel=1e-6)
    assert marlin.extruded == pytest.approx(est, rel=0.02)


def test_the_retract_comes_before_the_transition_marker_and_the_block_lifts_first(two_part):
    """docs/gcode-format.md: SUBPART, the retract, then TRANSITION; the block starts with
    the lift to the safe height (the first approach has no retract)."""
    _, res, _ = two_part
    at = [i for i, ln in enumerate(res.lines) if ln.startswith(";HOSTD_TRANSITION ")]
    assert len(at) == 2
    first, second = at
    assert res.lines[first - 1].startswith(";HOSTD_SUBPART ")
    assert res.lines[second - 2].startswith(";HOSTD_SUBPART ")
    assert res.lines[second - 1] == (f"G1 E{-SETTINGS.retract_length:.5f} "
                                     f"F{SETTINGS.retract_speed * 60:.0f}")
    safe_z = json.loads(res.lines[second].split(" ", 1)[1])["safe_z"]
    assert res.lines[second + 1].startswith(f"G0 Z{safe_z:.3f}")


def test_no_transition_turns_the_table_while_the_nozzle_moves(two_part):
    """docs/gcode-format.md: a block lifts (Z alone, at the old angles), turns (A C alone),
    travels and descends; the first block too, though the angles the start script left are
    not known: it states them (A0 C0, after homing) in a turn of its own, so a table the
    script left turned is not swung round while the nozzle rises from the platform."""
    _, res, _ = two_part
    starts = [i for i, ln in enumerate(res.lines) if ln.startswith(";HOSTD_TRANSITION ")]
    for first, at in enumerate(starts):
        end = res.lines.index(";HOSTD_TRANSITION_END", at)
        axes = [{w[0] for w in ln.split()[1:] if w[0] in "XYZAC"}
                for ln in res.lines[at + 1:end]]
        safe_z = json.loads(res.lines[at].split(" ", 1)[1])["safe_z"]
        assert axes[0] == {"Z"} and res.lines[at + 1].startswith(f"G0 Z{safe_z:.3f} ")
        assert not [a for a in axes if a & {"A", "C"} and a & {"X", "Y", "Z"}]
        if first == 0:
            assert axes[1] == {"A", "C"}
            assert res.lines[at + 2].startswith("G0 A0.0000 C0.0000 ")


def test_moves_that_round_to_a_standstill_are_dropped_and_their_filament_kept():
    """A path whose vertices lie closer than the printed precision (0.001 mm) would write
    bare ``G1 E..`` lines: those moves are dropped, their filament goes to the next move."""
    pts = np.array([[0.0, 0.0, H], [5.0, 0.0, H], [5.0002, 0.0, H], [5.0004, 0.0, H],
                    [5.0, 5.0, H], [5.0, 5.0003, H]])
    path = Path("infill", pts, np.full(len(pts), H), W, 40.0)
    layer = Layer(0, 0, np.zeros(3), np.array([0.0, 0.0, 1.0]), 0.0, 0.0, (H, H), [path])
    plan = PrintPlan(np.eye(4), [SubpartPlan(0, None, None, None, np.array([0, 0, 1.0]),
                                             [layer])])
    res = generate(plan, SETTINGS, MachineSetup(GEO))
    parsed = parse_lines(res.lines)
    moved = np.abs(np.nan_to_num(parsed.end - parsed.start)).max(axis=1) > 0
    standstill = (parsed.e > 0) & ~moved & (parsed.e != SETTINGS.retract_length)
    assert not standstill.any(), [res.lines[i - 1] for i in parsed.line[standstill]]
    _, e = path_extrusion(path, math.pi * SETTINGS.filament_diameter ** 2 / 4)
    printed = parsed.e[(parsed.e > 0) & moved]
    assert len(printed) == 2  # the two long sides carry the whole path's filament
    assert printed.sum() == pytest.approx(e.sum(), abs=1e-5)
