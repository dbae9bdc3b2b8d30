"""Planner: planar control, a hand-made two-part decomposition, collisions, sample pipes."""

from __future__ import annotations

import contextlib
import functools
import itertools
import os
from concurrent.futures import Executor, Future
from concurrent.futures.process import BrokenProcessPool
from types import SimpleNamespace

import manifold3d as m3
import numpy as np
import pytest
import shapely
import shapely.affinity
from handmade_plans import two_part_decomposition

from kinematics.machine import MachineGeometry
from kinematics.transform import machine_direction
from slicer.mesh.samples import to_trimesh
from slicer.paths.layer_workers import _staged_in_processes as REAL_STAGED
from slicer.paths.layers import LayerPlane
from slicer.paths.planner import SlicingError, plan_planar, plan_print
from slicer.printhead import Printhead
from slicer.settings import ProcessSettings

S = ProcessSettings()
G = MachineGeometry()
TILT = np.radians(30.0)
AXIS = np.array([np.sin(TILT), 0.0, np.cos(TILT)])


def _leaning() -> SimpleNamespace:
    """A cylinder R8 × 20 with a rod R5 leaning 30° standing on its top face."""
    root = m3.Manifold.cylinder(20.0, 8.0, 8.0, 48)
    mat = np.eye(4)[:3]
    c, s = np.cos(TILT), np.sin(TILT)
    mat[:, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    rod = m3.Manifold.cylinder(30.0, 5.0, 5.0, 48).translate((0, 0, -5)).transform(mat)
    child = rod.translate((0, 0, 20.0)).trim_by_plane((0, 0, 1.0), 20.0)
    return two_part_decomposition(root, child, [0, 0, 20.0], [0, 0, 1.0])


@pytest.fixture(scope="module")
def leaning() -> SimpleNamespace:
    return _leaning()


@pytest.fixture(scope="module")
def leaning_plan(leaning):
    return plan_print(leaning, S, G, Printhead.default())


def test_planar_cylinder_is_flat_exact_and_inside() -> None:
    plan = plan_planar(to_trimesh(m3.Manifold.cylinder(10.0, 6.0, 6.0, 64)), S, G)
    (sub,) = plan.subparts
    assert len(sub.layers) == 50
    assert sub.thickness_range == pytest.approx((0.2, 0.2))
    for la in sub.layers:
        assert (la.a, la.c) == (0.0, 0.0) and np.allclose(la.normal, [0, 0, 1])
        for p in la.paths:
            assert np.allclose(p.points[:, 2], la.origin[2])
            assert np.hypot(p.points[:, 0], p.points[:, 1]).max() <= 6.0 - 0.5 * p.width + 1e-3
            assert np.allclose(p.height, 0.2)
    kinds = [{p.kind for p in la.paths} for la in sub.layers]
    assert all("solid" in k for k in kinds[:3] + kinds[-3:])
    assert all("infill" in k and "solid" not in k for k in kinds[3:-3])
    assert sub.layers[0].paths[0].speed == S.first_layer_speed


def test_thin_layers_get_skins_of_the_minimum_thickness() -> None:
    """3 solid layers of 0.05 mm would leave a 0.15 mm skin over sparse infill: the skins
    are at least min_shell_thickness (0.6 mm) thick, 12 layers; at 0.2 mm nothing changes."""
    from dataclasses import replace

    thin = replace(S, layer_height=0.05)
    assert (thin.skin_layers(), S.skin_layers()) == (12, S.solid_layers)
    plan = plan_planar(to_trimesh(m3.Manifold.cylinder(2.0, 6.0, 6.0, 64)), thin, G)
    (sub,) = plan.subparts
    kinds = [{p.kind for p in la.paths} for la in sub.layers]
    assert len(kinds) == 40
    assert all("solid" in k and "infill" not in k for k in kinds[:12] + kinds[-12:])
    assert all("infill" in k and "solid" not in k for k in kinds[12:-12])


def test_child_layers_turn_from_base_to_axis_within_bounds(leaning_plan) -> None:
    _root, child = leaning_plan.subparts
    assert [s.index for s in leaning_plan.subparts] == [0, 1] and child.parent == 0
    assert np.allclose(child.layers[0].normal, [0, 0, 1])  # flat on the parent
    assert child.layers[-1].normal @ AXIS > np.cos(np.radians(1.5))  # then along the rod
    lo, hi = child.thickness_range
    assert 0.5 * S.layer_height - 1e-9 <= lo and hi <= 1.5 * S.layer_height + 1e-9
    for la in child.layers:
        z = machine_direction(la.normal, la.a, la.c)
        assert np.allclose(z, [0, 0, 1], atol=1e-9)  # A/C turn the build direction up
        for p in la.paths:
            assert S.min_layer_factor * 0.2 - 1e-9 <= p.height.min()
            assert p.height.max() <= S.max_layer_factor * 0.2 + 1e-9
    c = np.array([la.c for la in child.layers[1:]])
    assert np.abs(np.diff(c)).max() < 1.0  # C continuity


def test_no_bead_is_thicker_than_the_nozzle_allows(leaning) -> None:
    """With t = 0.3 on a 0.4 mm nozzle, 1.5 t (0.45 mm) would not press onto the layer below:
    the local thickness is capped at 0.8 × the nozzle (0.32 mm). The bounds [0.15, 0.32] are
    then lopsided about t, so while the planes turn they sit at the middle of the bounds
    (a thinner layer on the skeleton) and still reach the rod's axis."""
    from dataclasses import replace

    thick = replace(S, layer_height=0.3)
    assert thick.max_layer_share() == pytest.approx(0.32 / 0.3)
    assert S.max_layer_share() == S.max_layer_factor  # 0.3 mm: under the cap already
    child = plan_print(leaning, thick, G, Printhead.default()).subparts[1]
    lo, hi = child.thickness_range
    assert hi <= 0.32 + 1e-9 and lo >= 0.5 * 0.3 - 1e-9
    assert max(p.height.max() for la in child.layers for p in la.paths) <= 0.32 + 1e-9
    toward = [la.normal @ AXIS for la in child.layers]
    assert toward[0] == pytest.approx(np.cos(TILT))  # flat on the parent
    assert toward[-1] > np.cos(np.radians(1.5))  # then along the rod
    reached = next(i for i, x in enumerate(toward) if x > np.cos(np.radians(1.5)))
    assert all(b >= a - 1e-9 for a, b in itertools.pairwise(toward[:reached + 1]))  # turns on
    pairs = list(itertools.pairwise(child.layers))
    step = [(b.origin - a.origin) @ a.normal for a, b in pairs]  # thickness on the skeleton
    turning = [not np.allclose(a.normal, b.normal, atol=1e-9) for a, b in pairs]
    mid = 0.5 * (0.15 + 0.32)  # the middle of the bounds
    assert any(abs(h - mid) < 1e-4 for h, turn in zip(step, turning, strict=True) if turn)
    body, end = step[:-2], step[-2:]  # the last two share what is left to the rod's end
    assert all(abs(h - 0.3) < 1e-4 or abs(h - mid) < 1e-4 for h in body)
    assert abs(body[-1] - 0.3) < 1e-4  # along the rod: t again
    assert all(0.25 * 0.3 - 1e-9 <= h <= 0.3 + 1e-9 for h in end)


def test_child_paths_stay_inside_the_rod(leaning_plan) -> None:
    child = leaning_plan.subparts[1]
    base = np.array([0.0, 0.0, 20.0])
    for la in child.layers:
        for p in la.paths:
            rel = p.points - base
            r = np.linalg.norm(rel - np.outer(rel @ AXIS, AXIS), axis=1)
            assert r.max() <= 5.0 - 0.1  # inside the rod with margin (mid-layer sections)
            assert (p.points[:, 2] >= 20.0).all()


def test_bonded_interface(leaning_plan) -> None:
    root, child = leaning_plan.subparts
    marked = [la for la in root.layers if la.interface_child == 1]
    ellipse = shapely.affinity.scale(shapely.Point(0, 0).buffer(1.0, 256), 5.0 / np.cos(TILT), 5.0)
    # the child's base section (cut mid-first-layer, t/2 up the leaning rod) grown by a width
    ellipse = shapely.affinity.translate(ellipse, 0.5 * S.layer_height * np.tan(TILT))
    foot = ellipse.buffer(S.line_width + 1e-3)
    assert marked and all(la.index >= len(root.layers) - S.interface_layers - 1 for la in marked)
    assert all(any(p.kind == "interface" for p in la.paths) for la in marked)
    for p in (p for la in marked for p in la.paths if p.kind == "interface"):
        assert foot.contains(shapely.points(p.points[:, :2])).all()
    first = child.layers[0]
    assert first.first_of_child and not any(la.first_of_child for la in child.layers[1:])
    assert all(p.flow == S.interface_flow for p in first.paths)
    assert all(p.speed <= S.interface_speed_factor * S.perimeter_speed + 1e-9
               or p.speed <= S.interface_speed_factor * S.print_speed + 1e-9
               for p in first.paths)


def test_collision_with_printed_part_is_named() -> None:
    disc = m3.Manifold.cylinder(5.0, 25.0, 25.0, 48)
    pillar = m3.Manifold.cylinder(40.0, 4.0, 4.0, 32).translate((-14.0, 0.0, 0.0))
    child = m3.Manifold.cylinder(10.0, 5.0, 5.0, 48).translate((0.0, 0.0, 5.0))
    dec = two_part_decomposition(disc + pillar, child, [0, 0, 5.0], [0, 0, 1.0])
    with pytest.raises(SlicingError, match=r"sub-part 1, layer 0: .*printed part"):
        plan_print(dec, S, G, Printhead.default())
    thin = Printhead(((0.0, 50.0, 0.5, 0.5),))  # a needle clears the pillar
    assert plan_print(dec, S, G, thin).subparts[1].layers


def _tilts(plan) -> np.ndarray:
    return np.degrees(np.arccos(np.clip([la.normal[2] for la in plan.subparts[1].layers],
                                        -1.0, 1.0)))


def test_collision_limits_the_turn(leaning, leaning_plan) -> None:
    wide = Printhead(((0.0, 0.05, 0.5, 0.5), (0.05, 40.0, 60.0, 60.0)))
    plan = plan_print(leaning, S, G, wide)
    # a disc-shaped head would sweep the root's top face: the turn towards the rod is held back
    free, held = _tilts(leaning_plan), _tilts(plan)
    n = min(len(free), len(held))
    assert (held[:n] <= free[:n] + 1e-6).all() and (free[:n] - held[:n]).max() > 3.0
    root = leaning.subparts[0].mesh.vertices
    for la in plan.subparts[1].layers:  # and no chosen plane puts the head into the root
        tips = np.vstack([p.points for p in la.paths])
        assert not wide.collisions(root, tips, la.normal).any()


@pytest.fixture(scope="module")
def pipe2_plan():
    decompose = pytest.importorskip("slicer.decompose")
    from slicer.mesh.samples import pipe2

    dec = decompose.decompose(pipe2(), decompose.DecomposeSettings(), G, Printhead.default())
    return dec, plan_print(dec, S, G, Printhead.default())


def test_sample_pipes_plan(pipe2_plan) -> None:
    dec, plan = pipe2_plan
    assert [s.index for s in plan.subparts] == list(dec.order)
    for sub in plan.subparts:
        lo, hi = sub.thickness_range
        assert 0.1 - 1e-9 <= lo and hi <= 0.3 + 1e-9
        assert all(la.paths for la in sub.layers)
    root = plan.subparts[0]
    assert all(la.a == 0.0 for la in root.layers)
    assert any(la.interface_child is not None for la in root.layers)
    assert set(plan.timings) >= {"skeleton", "layers", "zones", "toolpaths"}


def test_thin_wall_interface_is_solid_under_the_child(pipe2_plan) -> None:
    """On the 2 mm pipe wall the interface zone holds only wall loops: their pieces in the zone
    are marked "interface", and (with loops in the slivers they miss) those beads cover the
    zone: ≥ 95 % over all interface layers, most of it on each (the last layers' zones are
    slivers of the junction a few tenths of a millimetre wide)."""
    from slicer.paths.interfaces import interface_zone
    from slicer.paths.layers import LayerPlane
    from slicer.paths.planner import _child_base
    from slicer.planes2d import section, slicing_solid

    dec, plan = pipe2_plan
    root = plan.subparts[0]
    subs = {s.index: s for s in dec.subparts}
    solid = slicing_solid(subs[0].mesh)
    t = S.layer_height
    marked = [la for la in root.layers if la.interface_child is not None]
    assert len(marked) >= S.interface_layers
    zone_area, covered = 0.0, 0.0
    for la in marked:
        child = subs[la.interface_child]
        base = _child_base(child.index, child.mesh, child.base_plane.point,
                           child.base_plane.normal, t)
        frame = np.eye(3)  # the root's layers are horizontal with the platform frame's axes
        region = section(solid, la.origin - 0.5 * t * frame[2], frame)
        below = (la.origin - t * frame[2], frame[2])
        plane = LayerPlane(la.index, 0.0, la.origin, frame, region, below, (t, t), 0.0)
        zone = interface_zone(plane, base, S.interface_layers * t, t, S.line_width)
        iface = [p for p in la.paths if p.kind == "interface"]
        if zone.buffer(-0.5 * S.line_width).is_empty:  # narrower than a bead: none fits
            zone_area += zone.area  # (canonical order: layer 232, 0.22 mm², 0.3 mm wide)
            continue
        assert iface, la.index
        beads = shapely.union_all([shapely.LineString(p.points[:, :2] - la.origin[:2])
                                   .buffer(0.5 * p.width) for p in iface])
        here = beads.intersection(zone).area
        assert here >= 0.6 * zone.area, la.index
        zone_area, covered = zone_area + zone.area, covered + here
    assert zone_area > 1.0  # the zones are not empty slivers
    assert covered >= 0.95 * zone_area


def _bead_cover(paths, band: shapely.Geometry, kinds: set[str] | None = None) -> float:
    """Share of ``band``'s area under the beads (centre line ⊕ w/2) of ``paths`` (xy)."""
    lines = [shapely.LineString(p.points[:, :2]) for p in paths
             if len(p.points) > 1 and (kinds is None or p.kind in kinds)]
    beads = shapely.union_all(shapely.buffer(lines, 0.5 * S.line_width)) if lines else None
    return 0.0 if beads is None else beads.intersection(band).area / band.area


@pytest.fixture(scope="module")
def stepped_plan():
    """A solid cylinder R4 standing on a disc R10 × 2 mm (layers 0–9 are the disc)."""
    disc = m3.Manifold.cylinder(2.0, 10.0, 10.0, 96)
    post = m3.Manifold.cylinder(3.0, 4.0, 4.0, 64).translate((0, 0, 2.0))
    return plan_planar(to_trimesh(disc + post), S, G)


def test_solid_infill_under_the_walls_of_the_next_layer(stepped_plan) -> None:
    """The disc's last layer is solid under the cylinder's wall band (its first layer's walls
    stand on beads, not on sparse infill); the layer below and the centre keep sparse infill."""
    (sub,) = stepped_plan.subparts
    last = round(2.0 / S.layer_height) - 1
    assert shapely.Point(0, 0).buffer(9.0).within(shapely.MultiPoint(
        sub.layers[last].paths[0].points[:, :2]).convex_hull)  # layer `last` is the disc
    band = (shapely.Point(0, 0).buffer(4.0, quad_segs=64)
            - shapely.Point(0, 0).buffer(4.0 - S.perimeters * S.line_width, quad_segs=64))
    assert _bead_cover(sub.layers[last].paths, band) >= 0.95
    assert _bead_cover(sub.layers[last].paths, band, {"solid"}) >= 0.9
    deeper = sub.layers[last - 1].paths
    assert _bead_cover(deeper, band) < 0.5
    core = band & shapely.Point(0, 0).buffer(4.0 - 0.6 * S.line_width)  # inside the skin beads
    assert _bead_cover(deeper, core, {"solid"}) < 0.01
    assert any(p.kind == "infill" for p in deeper)
    centre = shapely.Point(0, 0).buffer(4.0 - (S.perimeters + 3) * S.line_width)
    inner = [p for p in sub.layers[last].paths
             if shapely.LineString(p.points[:, :2]).intersects(centre) and len(p.points) > 1]
    assert inner and {p.kind for p in inner} == {"infill"}


def _plane(index: int, origin, normal, region) -> LayerPlane:
    from slicer.planes2d import plane_frame

    o = np.asarray(origin, float)
    frame = plane_frame(np.asarray(normal, float))
    return LayerPlane(index, 0.0, o, frame, region, (o - 0.2 * frame[2], frame[2]), (0.2, 0.2),
                      0.0)


def _footings(lower, upper):
    from slicer.paths.toolpaths import FillSpec, shell
    from slicer.paths.zones import under_walls

    spec = FillSpec(S.line_width, S.perimeters, S.infill_density, S.infill_angle)
    shells = [shell(lp.region, spec) for lp in (lower, upper)]
    return under_walls([lower, upper], [s.inner for s in shells], [s.domain for s in shells],
                       S.line_width), shells


def test_solid_under_walls_between_turned_planes() -> None:
    """A ring printed on a plane turned 20° from the disc below it: the disc's footing is its
    fill domain under the ring's wall band, mapped with the planes' affine map; a shifted copy
    (a sliver of overhang the 45° rule supports) and the last layer get none."""
    from slicer.planes2d import map_between

    w, n = S.line_width, np.array([0.0, np.sin(np.radians(20.0)), np.cos(np.radians(20.0))])
    disc = shapely.Point(0, 0).buffer(10.0, quad_segs=32)
    ring = shapely.Point(0, 0).buffer(5.0, quad_segs=32) - shapely.Point(0, 0).buffer(3.0)
    lower, upper = _plane(0, [0, 0, 0], [0, 0, 1], disc), _plane(1, [0, 0, 0.2], n, ring)
    (foot, last), shells = _footings(lower, upper)
    assert last.is_empty
    src, dst = (upper.origin, upper.frame), (lower.origin, lower.frame)
    band = map_between(ring - shells[1].inner, src, dst) & shells[0].domain
    assert band.area > 10.0
    assert (band - foot).area < 0.01 * band.area
    assert foot.difference(band.buffer(1.5 * w)).area < 1e-6
    assert foot.area < band.buffer(1.5 * w).area
    shifted = _plane(1, [0, 0, 0.2], [0, 0, 1], shapely.affinity.translate(disc, 0.05))
    (foot, _), _ = _footings(lower, shifted)
    assert foot.is_empty


class _BrokenPool(Executor):
    """A process pool whose workers have died."""

    def submit(self, fn, /, *args, **kwargs):  # type: ignore[no-untyped-def]
        raise BrokenProcessPool("a worker died")


class _DyingPool(Executor):
    """A process pool whose worker dies on every second chunk: the first chunk's results
    are in when the failure is met."""

    def __init__(self) -> None:
        self.chunks = 0

    def submit(self, fn, /, *args, **kwargs):  # type: ignore[no-untyped-def]
        self.chunks += 1
        out: Future = Future()
        if self.chunks % 2 == 0:
            out.set_exception(BrokenProcessPool("a worker died"))
        else:
            out.set_result(fn(*args, **kwargs))
        return out


class _BreakingPool(Executor):
    """A process pool that breaks after its first chunk was submitted: the chunks it then
    refuses are computed by stage 3's thread."""

    def __init__(self) -> None:
        self.chunks = 0

    def submit(self, fn, /, *args, **kwargs):  # type: ignore[no-untyped-def]
        self.chunks += 1
        if self.chunks > 1:
            raise BrokenProcessPool("a worker died")
        out: Future = Future()
        out.set_result(fn(*args, **kwargs))
        return out


def _plan_with(leaning, monkeypatch, threads: int, procs: str, chunked: list[int]) -> object:
    """The leaning part planned on ``threads`` threads and with ``procs``: "none" (threads
    only), "chunked" (every sub-part's stages 1-2 in forked processes, by chunks of layers)
    or "broken" / "dies" / "breaks" (a pool that fails at once, on every second chunk, or
    refuses chunks after the first: the threads take over). Layers of sub-parts sent to the
    pool are added to ``chunked``."""
    from slicer.paths import layer_workers, planner

    def staged(layers, *args):  # type: ignore[no-untyped-def]
        chunked.append(len(layers))
        return REAL_STAGED(layers, *args)

    monkeypatch.setattr(layer_workers, "_staged_in_processes", staged)
    monkeypatch.setattr(planner, "workers", lambda: threads)
    pools = {"none": lambda longest: contextlib.nullcontext(None),
             "chunked": lambda longest: layer_workers.layer_processes(longest, min_layers=1),
             "broken": lambda longest: contextlib.nullcontext(_BrokenPool()),
             "dies": lambda longest: contextlib.nullcontext(_DyingPool()),
             "breaks": lambda longest: contextlib.nullcontext(_BreakingPool())}
    monkeypatch.setattr(planner, "layer_processes", pools[procs])
    monkeypatch.setattr(planner, "start_stages",
                        functools.partial(layer_workers.start_stages, min_layers=1))
    return plan_print(leaning, S, G, Printhead.default())


def test_plan_does_not_depend_on_threads_or_processes(leaning, monkeypatch) -> None:
    """Threads, worker processes by chunks of layers, or a broken pool: the same paths."""
    if (os.cpu_count() or 1) < 2:
        pytest.skip("worker processes need two cores")
    runs = ((1, "none"), (2, "none"), (1, "chunked"), (2, "broken"), (1, "dies"), (2, "breaks"))
    chunked: dict[str, list[int]] = {procs: [] for _, procs in runs}
    plans = [_plan_with(leaning, monkeypatch, t, procs, chunked[procs]) for t, procs in runs]
    layers = sorted(len(sp.layers) for sp in plans[0].subparts)
    assert chunked["none"] == [] and sorted(chunked["chunked"]) == layers
    assert sorted(chunked["broken"]) == layers  # tried, then done on the threads
    assert sorted(chunked["dies"]) == layers == sorted(chunked["breaks"])
    for other in plans[1:]:
        _assert_same_paths(plans[0], other)


def test_a_long_sub_part_is_sent_to_the_workers_before_the_next_is_marched(
        leaning, monkeypatch) -> None:
    """The workers compute a marched sub-part's shells and zones while the planner marches
    the sub-parts after it."""
    from slicer.paths import layer_workers, planner

    if (os.cpu_count() or 1) < 2:
        pytest.skip("worker processes need two cores")
    events: list[tuple[str, int]] = []
    march = planner._slice_subpart

    def marched(index, *args, **kwargs):  # type: ignore[no-untyped-def]
        events.append(("march", index))
        return march(index, *args, **kwargs)

    def staged(layers, *args):  # type: ignore[no-untyped-def]
        events.append(("workers", len(layers)))
        return REAL_STAGED(layers, *args)

    monkeypatch.setattr(planner, "_slice_subpart", marched)
    monkeypatch.setattr(layer_workers, "_staged_in_processes", staged)
    monkeypatch.setattr(planner, "layer_processes",
                        lambda longest: layer_workers.layer_processes(longest, min_layers=1))
    monkeypatch.setattr(planner, "start_stages",
                        functools.partial(layer_workers.start_stages, min_layers=1))
    plan = plan_print(leaning, S, G, Printhead.default())
    kinds = [kind for kind, _ in events]
    assert len(plan.subparts) >= 2
    assert kinds == ["march", "workers"] * len(plan.subparts)  # each at once, in turn


def _assert_same_paths(one, other) -> None:  # type: ignore[no-untyped-def]
    pairs = [(a, b) for sa, sb in zip(one.subparts, other.subparts, strict=True)
             for la, lb in zip(sa.layers, sb.layers, strict=True)
             for a, b in zip(la.paths, lb.paths, strict=True)]
    assert pairs
    for a, b in pairs:
        assert a.kind == b.kind and a.closed == b.closed and a.width == b.width
        assert np.array_equal(a.points, b.points) and np.array_equal(a.height, b.height)


def test_planar_plan_is_the_same_with_worker_processes(monkeypatch) -> None:
    from slicer.paths import layer_workers, planner

    if (os.cpu_count() or 1) < 2:
        pytest.skip("worker processes need two cores")
    mesh = to_trimesh(m3.Manifold.cylinder(10.0, 6.0, 6.0, 64))
    monkeypatch.setattr(planner, "layer_processes", lambda n: contextlib.nullcontext(None))
    threads = plan_planar(mesh, S, G)
    chunked: list[int] = []
    monkeypatch.setattr(planner, "layer_processes",
                        lambda n: layer_workers.layer_processes(n, min_layers=1))
    monkeypatch.setattr(planner, "start_stages",
                        functools.partial(layer_workers.start_stages, min_layers=1))
    monkeypatch.setattr(layer_workers, "_staged_in_processes",
                        lambda layers, *a: chunked.append(len(layers)) or REAL_STAGED(layers, *a))
    _assert_same_paths(threads, plan_planar(mesh, S, G))
    assert chunked == [50]


def test_inline_executor_delivers_results_and_errors() -> None:
    from slicer.paths.subpart_paths import InlineExecutor

    ex = InlineExecutor()
    assert list(ex.map(lambda x: x * x, [1, 2, 3])) == [1, 4, 9]
    with pytest.raises(ZeroDivisionError):
        ex.submit(lambda: 1 / 0).result()


def test_the_last_layers_without_a_path_are_dropped_the_others_kept() -> None:
    """A sub-part's last sections can be slivers narrower than a line: no path, nothing to
    print, only table turns. They are dropped; a pathless layer between printed ones stays
    (its index names it in messages), and a sub-part keeps at least one layer."""
    from slicer.paths.planner import _built, _Timer
    from slicer.plan import Layer, Path

    def layer(i: int, printed: bool) -> Layer:
        paths = [Path("perimeter", np.zeros((2, 3)), np.full(2, 0.2), 0.45, 30.0)]
        return Layer(1, i, np.zeros(3), np.array([0.0, 0.0, 1.0]), 0.0, 0.0, (0.2, 0.2),
                     paths if printed else [])

    def built(printed: list[bool]) -> list[int]:
        job: Future = Future()
        job.set_result(([layer(i, p) for i, p in enumerate(printed)], {"toolpaths": 0.5}))
        timer = _Timer()
        out = [la.index for la in _built(job, timer)]
        assert timer.laps["toolpaths"] == 0.5
        return out

    assert built([True, False, True, False, False]) == [0, 1, 2]
    assert built([True, True]) == [0, 1]
    assert built([False, False]) == [0]
