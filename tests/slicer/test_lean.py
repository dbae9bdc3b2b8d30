"""The lean plan of an upright sub-part: its price, its dynamic programme, its stacked pieces.

Invariants on seeded random price tables (the path's cost is what it reports, its turns stay
within the bound, no random feasible path is cheaper, jumps only where allowed) and on parts
built with manifold3d (a column leaning past 45° is leaned towards, a cut keeps the volume and
leaves every earlier piece under it, a deferred child prints right after its piece).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace

import manifold3d as m3
import numpy as np
import pytest

from slicer.decompose import Decomposition, Plane, Subpart
from slicer.mesh import to_trimesh
from slicer.paths.columns import column_of, restack, stack
from slicer.paths.lean import LeanPlan, Turning, _cheapest, lean_problem, solve
from slicer.paths.lean_costs import (
    DirectionGrid,
    LeanCosts,
    LeanSettings,
    Stranded,
    _Faces,
    _overhang,
    _platform,
    hinge,
)
from slicer.paths.upright import lean_upright
from slicer.planes2d import slicing_solid
from slicer.printhead import Printhead

SMALL = LeanSettings(max_tilt=20.0, step_deg=4.0)
TURNING = Turning(0.2, 0.5, 1.5, 0.9)


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(float(np.clip(a @ b, -1.0, 1.0))))


def test_the_grid_covers_the_cap_around_the_axis() -> None:
    grid = DirectionGrid.make(50.0, 2.0)
    k = grid.centre
    assert np.allclose(grid.local[k, k], [0.0, 0.0, 1.0])
    assert np.allclose(np.linalg.norm(grid.local, axis=-1), 1.0)
    tilt = grid.tilt[grid.inside]
    assert tilt.max() <= 50.0 + 1e-9 and tilt.max() > 48.0
    assert not (grid.tilt[~grid.inside] <= 50.0 - 1e-9).any()


@pytest.mark.parametrize("soft, hard", [(35.0, 45.0), (40.0, 50.0)])
def test_the_hinge_is_nothing_below_soft_everything_past_hard(soft: float, hard: float) -> None:
    over = np.linspace(0.0, 90.0, 181)
    share = hinge(-np.sin(np.radians(over)), soft, hard)
    assert (share[over <= soft] == 0.0).all() and (share[over >= hard] == 1.0).all()
    assert (np.diff(share) >= 0.0).all()


def _random_costs(rng: np.random.Generator, nb: int, grid: DirectionGrid,
                  jumps: bool = False) -> LeanCosts:
    n = grid.inside.shape[0]
    over = rng.exponential(1.0, size=(nb, n, n)) * (rng.random((nb, n, n)) < 0.6)
    allowed = np.broadcast_to(grid.inside, (nb, n, n)).copy()
    jump_ok = allowed & jumps
    return LeanCosts(over, allowed, rng.random((nb, n, n)), jump_ok, float(over[:, 0, 0].sum()))


def _path_cost(costs: LeanCosts, grid: DirectionGrid, cells: list[tuple[int, int]],
               jumps: list[int], s: LeanSettings) -> float:
    total = 0.0
    tilt = grid.tilt
    for b, (i, j) in enumerate(cells):
        total += costs.overhang[b, i, j] + s.tilt_cost * tilt[i, j]
        if b == 0:
            continue
        if b in jumps:
            total += s.jump_cost + costs.jump_penalty[b, i, j]
        else:
            pi, pj = cells[b - 1]
            total += s.turn_cost * _angle(grid.local[pi, pj], grid.local[i, j])
    return total


@pytest.mark.parametrize("seed", range(4))
def test_the_cheapest_path_costs_what_it_says_and_turns_within_the_bound(seed: int) -> None:
    rng = np.random.default_rng(seed)
    grid = DirectionGrid.make(SMALL.max_tilt, SMALL.step_deg)
    nb = 12
    costs = _random_costs(rng, nb, grid)
    limits = rng.uniform(4.0, 9.0, size=nb)
    cells, jumps, total = _cheapest(costs, grid, limits, SMALL)
    assert jumps == [] and cells[0] == (grid.centre, grid.centre)
    assert total == pytest.approx(_path_cost(costs, grid, cells, jumps, SMALL))
    cos = np.cos(np.radians(grid.tilt))
    for b in range(1, nb):
        (pi, pj), (i, j) = cells[b - 1], cells[b]
        assert grid.inside[i, j]
        assert _angle(grid.local[pi, pj], grid.local[i, j]) <= limits[b] * cos[i, j] + 1e-6


@pytest.mark.parametrize("seed", range(3))
def test_no_random_feasible_path_is_cheaper(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    grid = DirectionGrid.make(SMALL.max_tilt, SMALL.step_deg)
    nb = 10
    costs = _random_costs(rng, nb, grid)
    limits = np.full(nb, 9.0)
    _, _, best = _cheapest(costs, grid, limits, SMALL)
    n = grid.inside.shape[0]
    cos = np.cos(np.radians(grid.tilt))
    for _ in range(300):  # random walks that keep within the bound
        cells = [(grid.centre, grid.centre)]
        for b in range(1, nb):
            pi, pj = cells[-1]
            options = [(i, j) for i in range(max(0, pi - 2), min(n, pi + 3))
                       for j in range(max(0, pj - 2), min(n, pj + 3))
                       if grid.inside[i, j] and _angle(grid.local[pi, pj], grid.local[i, j])
                       <= limits[b] * cos[i, j]]
            cells.append(options[int(rng.integers(len(options)))])
        assert _path_cost(costs, grid, cells, [], SMALL) >= best - 1e-9


def _free_then_tilted() -> tuple[DirectionGrid, np.ndarray, np.ndarray]:
    """(grid, overhang, allowed) of 10 bands: upright free up to band 5, then only a cell
    19° off."""
    grid = DirectionGrid.make(SMALL.max_tilt, SMALL.step_deg)
    nb, n = 10, grid.inside.shape[0]
    over = np.full((nb, n, n), 50.0)
    over[:5] = 0.0
    over[5:, 1, n // 2] = 0.0
    return grid, over, np.broadcast_to(grid.inside, (nb, n, n)).copy()


def test_a_jump_is_taken_only_where_allowed_and_when_it_pays() -> None:
    grid, over, allowed = _free_then_tilted()
    nb, n = over.shape[:2]
    jump_ok = np.zeros_like(allowed)
    jump_ok[4:6] = allowed[4:6]
    costs = LeanCosts(over, allowed, np.zeros_like(over), jump_ok, 0.0)
    cells, jumps, total = _cheapest(costs, grid, np.full(nb, 0.5), SMALL)
    assert grid.inside[1, n // 2]
    assert jumps in ([4], [5]) and cells[-1] == (1, n // 2)
    assert total < 10.0
    no_jump = LeanCosts(over, allowed, np.zeros_like(over), np.zeros_like(allowed), 0.0)
    _, jumps, stuck = _cheapest(no_jump, grid, np.full(nb, 0.5), SMALL)
    assert jumps == [] and stuck > 100.0


def _rod_on_column(elevation: float) -> m3.Manifold:
    """A disc, a round column, and a solid rod leaving it at z = 15 towards +X
    ``elevation`` degrees above the horizontal (its underside overhangs 90 − elevation)."""
    el = math.radians(elevation)
    rod = m3.Manifold.cylinder(16.0, 3.0, 3.0, 32).rotate((0.0, 90.0 - elevation, 0.0))
    return (m3.Manifold.cylinder(2.0, 12.0, 12.0, 48)
            + m3.Manifold.cylinder(40.0, 6.0, 6.0, 48)
            + rod.translate((0.0, 0.0, 15.0)) + m3.Manifold.sphere(3.0, 32).translate(
                (16.0 * math.cos(el), 0.0, 15.0 + 16.0 * math.sin(el))))


def _subpart(solid: m3.Manifold, index: int = 0, parent: int | None = None,
             base: Plane | None = None) -> Subpart:
    mesh = to_trimesh(solid)
    return Subpart(index, parent, mesh, base, 0.0,
                   np.array([0.0, 0.0, 1.0]) if base is None else base.normal)


def _problem(solid: m3.Manifold, kids: list[Subpart] | None = None):
    root = _subpart(solid)
    origin = np.array([0.0, 0.0, 0.0])
    column = column_of(root, kids or [], slicing_solid(root.mesh), origin, np.eye(3))
    return column, lean_problem(column, Printhead.default(), TURNING)


def test_a_rod_overhanging_past_the_limit_is_leaned_towards() -> None:
    _, problem = _problem(_rod_on_column(25.0))
    plan = solve(problem)
    assert problem.costs.upright > 10.0  # its underside faces 65° off the vertical
    assert plan.cost < 0.3 * plan.upright
    at_rod = plan.direction(np.array([16.0, 20.0]))  # where the rod leaves the column
    assert (at_rod[:, 0] > math.sin(math.radians(12.0))).all()  # towards +X, 12° or more
    assert abs(at_rod[:, 1]).max() < 0.1


def test_a_steep_rod_leaves_the_column_upright() -> None:
    _, problem = _problem(_rod_on_column(60.0))  # its underside faces 30° off: printable
    plan = solve(problem)
    assert not plan.leans and plan.cost < 1e-3  # mm²: a sliver of the sphere at its tip


def _plan_with_jump(column, band: int, direction: np.ndarray) -> LeanPlan:
    nb = len(column.profile[0]) // 4 + 2
    dirs = np.tile([0.0, 0.0, 1.0], (nb, 1))
    dirs[band:] = direction / np.linalg.norm(direction)
    return LeanPlan(column.origin, column.axis, 2.0, dirs, (band,), 0.0, 0.0)


def test_a_cut_keeps_the_volume_and_leaves_the_lower_piece_under_it() -> None:
    tube = m3.Manifold.cylinder(40.0, 10.0, 10.0, 48) - m3.Manifold.cylinder(
        40.0, 8.0, 8.0, 48).translate((0.0, 0.0, 3.0))
    column, _ = _problem(tube)
    plan = _plan_with_jump(column, 8, np.array([0.5, 0.0, 1.0]))
    pieces, bad = stack(column, plan)
    assert bad is None and len(pieces) == 2
    assert pieces[0].base is None and pieces[1].base is not None
    assert sum(p.mesh.volume for p in pieces) == pytest.approx(tube.volume(), rel=1e-6)
    assert all(p.mesh.is_watertight for p in pieces)
    cut = pieces[1].base
    assert cut.signed(pieces[0].mesh.vertices).max() <= 1e-3
    assert cut.signed(pieces[1].mesh.vertices).min() >= -1e-3


def test_a_cut_through_a_childs_base_is_refused() -> None:
    tube = m3.Manifold.cylinder(40.0, 10.0, 10.0, 48)
    child_solid = m3.Manifold.cylinder(8.0, 3.0, 3.0, 24).rotate((0.0, 90.0, 0.0)).translate(
        (10.0, 0.0, 17.0))
    base = Plane(np.array([10.0, 0.0, 17.0]), np.array([1.0, 0.0, 0.0]))
    kid = _subpart(child_solid, 1, 0, base)
    column, _ = _problem(tube, [kid])
    plan = _plan_with_jump(column, 8, np.array([0.0, 0.0, 1.0]))  # a cut at z = 17
    pieces, bad = stack(column, plan)
    assert pieces == [] and bad == 8


def test_restacking_numbers_pieces_first_and_prints_a_deferred_child_on_its_piece() -> None:
    tube = m3.Manifold.cylinder(40.0, 10.0, 10.0, 48)
    low_kid = _subpart(m3.Manifold.cube((4.0, 4.0, 4.0)).translate((10.0, -2.0, 8.0)), 1, 0,
                       Plane(np.array([10.0, 0.0, 10.0]), np.array([1.0, 0.0, 0.0])))
    high_kid = _subpart(m3.Manifold.cube((4.0, 4.0, 4.0)).translate((10.0, -2.0, 30.0)), 2,
                        0, Plane(np.array([10.0, 0.0, 32.0]), np.array([1.0, 0.0, 0.0])))
    grandkid = _subpart(m3.Manifold.cube((2.0, 2.0, 2.0)).translate((14.0, -1.0, 9.0)), 3,
                        1, Plane(np.array([14.0, 0.0, 10.0]), np.array([1.0, 0.0, 0.0])))
    root = _subpart(tube)
    dec = Decomposition(np.eye(4), [root, low_kid, high_kid, grandkid], [0, 1, 2, 3],
                        float(tube.volume()), {}, 1, 1)
    column, _ = _problem(tube, [low_kid, high_kid])
    pieces, bad = stack(column, _plan_with_jump(column, 10, np.array([0.0, 0.0, 1.0])))
    assert bad is None and len(pieces) == 2
    plain, original = restack(dec, 0, pieces)
    assert plain.order == [0, 1, 2, 3, 4]
    parents = {s.index: s.parent for s in plain.subparts}
    assert parents == {0: None, 1: 0, 2: 0, 3: 1, 4: 2}
    assert original == {2: 1, 3: 2, 4: 3}
    early, _ = restack(dec, 0, pieces, frozenset({1}))
    assert early.order == [0, 2, 4, 1, 3]  # the low child and its child before the top piece
    seen: set[int] = set()
    parents = {s.index: s.parent for s in early.subparts}
    for k in early.order:
        assert parents[k] is None or parents[k] in seen
        seen.add(k)


@pytest.mark.parametrize("seed", range(4))
def test_each_stacked_piece_keeps_its_own_directions_past_its_last_band(seed: int) -> None:
    """A piece's layers reach past the next cut's band on the side they lean to: there they
    keep the piece's last direction (what the plan priced), never the next piece's."""
    rng = np.random.default_rng(seed)
    nb = int(rng.integers(12, 30))
    dirs = rng.normal(size=(nb, 3)) + np.array([0.0, 0.0, 4.0])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    jumps = tuple(sorted(int(j) for j in rng.choice(np.arange(2, nb - 1), 2, replace=False)))
    plan = LeanPlan(np.zeros(3), np.array([0.0, 0.0, 1.0]), 2.0, dirs, jumps, 0.0, 0.0)
    s = np.linspace(-5.0, 2.0 * nb + 5.0, 400)
    whole = plan.direction(s)
    bands = np.clip(np.floor(s / 2.0).astype(int), 0, nb - 1)
    assert np.array_equal(whole, dirs[bands])  # the whole plan: unchanged
    ends = [0, *jumps, nb]
    for k in range(len(jumps) + 1):
        got = plan.piece(k).direction(s)
        lo, hi = ends[k], ends[k + 1] - 1
        inside = (bands >= lo) & (bands <= hi)
        assert np.array_equal(got[inside], dirs[bands[inside]])
        assert np.array_equal(got[bands > hi], np.repeat(dirs[hi][None], (bands > hi).sum(), 0))
        assert np.array_equal(got[bands < lo], np.repeat(dirs[lo][None], (bands < lo).sum(), 0))


def _faces(rng: np.random.Generator, count: int) -> _Faces:
    centre = rng.uniform([-10.0, -10.0, 0.0], [10.0, 10.0, 30.0], size=(count, 3))
    normal = rng.normal(size=(count, 3)) - [0.0, 0.0, 1.0]  # mostly facing down
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    area = rng.uniform(0.1, 2.0, count)
    soft, hard = np.full(count, 44.0), np.full(count, 49.0)
    zero = np.zeros(count)
    return _Faces(centre, normal, area, centre[:, 2], soft, hard, zero, zero)


@pytest.mark.parametrize("seed", range(4))
def test_a_jump_prices_what_it_leaves_below_in_the_lower_pieces_last_direction(seed: int
                                                                               ) -> None:
    """Brute force over faces and directions: a face costs a jump at band b to d when the
    cut (square to d through the axis at the band's middle) leaves it below, and the lower
    piece's last direction e reaches it at band b or later; it costs its overhang on e."""
    rng = np.random.default_rng(seed)
    grid = DirectionGrid.make(20.0, 4.0)
    dirs = grid.world(np.eye(3))
    faces = _faces(rng, 300)
    axis = np.array([0.0, 0.0, 1.0])
    stranded = Stranded(faces, dirs.reshape(-1, 3), axis, 2.0, grid.inside.shape)
    b = int(rng.integers(3, 12))
    cell = (int(rng.integers(0, grid.inside.shape[0])), int(rng.integers(0, grid.inside.shape[0])))
    got = stranded.penalty(b, cell)
    e = dirs[cell]
    want = np.zeros(grid.inside.shape)
    for f in range(len(faces.area)):
        c, n = faces.centre[f], faces.normal[f]
        if (c @ e) / (e @ axis) < b * 2.0:
            continue  # the piece printed it before the jump's band
        cost = float(hinge(np.array(n @ e), 44.0, 49.0)) * faces.area[f]
        for i, j in np.ndindex(*grid.inside.shape):
            d = dirs[i, j]
            if (c - (b + 0.5) * 2.0 * axis) @ d < 0.0:  # under the cut
                want[i, j] += cost
    assert np.allclose(got, want)
    assert got.max() > 0.0  # the random faces leave something somewhere


@pytest.mark.parametrize("seed", range(3))
def test_the_band_tables_are_the_faces_summed_one_by_one(seed: int) -> None:
    """Brute force over faces and directions: a face costs its hinged area in the band where
    its layer in ``d`` crosses the axis, and a jump's cut at any band after that one and up
    to the face's own leaves it below (its ``stranded`` cost). The tables price only the
    pairs that cost; the sum must be the same."""
    rng = np.random.default_rng(seed)
    grid = DirectionGrid.make(20.0, 4.0)
    dirs = grid.world(np.eye(3))
    faces = _faces(rng, 300)
    faces = replace(faces, stranded=np.where(rng.random(300) < 0.5, faces.area, 0.0))
    axis, nb, band = np.array([0.0, 0.0, 1.0]), 14, 2.0
    over, penalty = _overhang(faces, dirs, grid.inside, nb, axis, LeanSettings(band=band))
    want_over, want_penalty = np.zeros_like(over), np.zeros_like(penalty)
    own = np.clip(np.floor(faces.height / band), 0, nb - 1).astype(int)
    for f, (i, j) in itertools.product(range(300), zip(*np.nonzero(grid.inside), strict=True)):
        d = dirs[i, j]
        b = int(np.clip(np.floor((faces.centre[f] @ d) / (d @ axis) / band), 0, nb - 1))
        want_over[b, i, j] += hinge(np.array(faces.normal[f] @ d), 44.0, 49.0) * faces.area[f]
        want_penalty[b + 1:own[f] + 1, i, j] += faces.stranded[f]
    assert np.allclose(over, want_over, rtol=1e-12, atol=1e-12)
    assert np.allclose(penalty, want_penalty, rtol=1e-12, atol=1e-12)
    assert over.max() > 0.0 and penalty.max() > 0.0
    assert not over[:, ~grid.inside].any()  # directions off the grid's cap are not priced


def test_a_direction_is_allowed_where_its_layer_keeps_the_head_over_the_platform() -> None:
    """Direction by direction: a layer through the axis at the band's low point, tilted θ,
    reaches down to the lowest height z where the part's extent R(z) ≥ (s − z) / tan θ;
    the head reaches its lowest point below that; allowed when that stays at the platform's
    clearance (upright always)."""
    column = _problem(_rod_on_column(20.0))[0]
    grid, head, nb = DirectionGrid.make(SMALL.max_tilt, SMALL.step_deg), Printhead.default(), 12
    got = _platform(column, grid.world(column.frame), grid, nb, head, SMALL)
    z, radius = column.profile
    want = np.zeros_like(got)
    for b, (i, j) in itertools.product(range(nb), np.ndindex(*grid.inside.shape)):
        s, theta = (b + 0.25) * SMALL.band, math.radians(grid.tilt[i, j])
        reach = (s - z) / max(math.tan(theta), 1e-9)
        low = min(float(np.min(z[(radius >= reach) & (z <= s)], initial=np.inf)), s)
        drop = head.lowest_point(np.zeros(3), grid.local[i, j])
        want[b, i, j] = theta < 1e-9 or low + column.origin[2] + drop >= SMALL.clearance
    assert np.array_equal(got, want)
    assert want[0].any() and not want[0].all() and want[-1].sum() > want[0].sum()


@dataclass
class _Left:
    """Stands in for :class:`Stranded`: what a jump at band b leaves below it costs
    ``cost[b]`` in every direction; the bands it was asked about are kept."""

    cost: dict[int, float]
    shape: tuple[int, int]
    asked: list[int] = field(default_factory=list)

    def penalty(self, b: int, cell: tuple[int, int]) -> np.ndarray:
        self.asked.append(b)
        return np.full(self.shape, self.cost.get(b, 0.0))


@pytest.mark.parametrize("left_at_5", [0.0, 1000.0])
def test_what_a_jump_leaves_below_decides_it_where_the_jump_could_win(left_at_5: float
                                                                     ) -> None:
    """The stranded faces' price is asked for where a jump could still be the cheaper way
    (it only adds to the jump's cost): left cheap, the jump comes at band 5, where upright
    stops being free; left dear there, a band before or after. Where no jump can win (at
    band 2 only upright may jump, and staying upright costs nothing), it is not asked
    for."""
    grid, over, allowed = _free_then_tilted()
    nb, n = over.shape[:2]
    jump_ok = np.zeros_like(allowed)
    jump_ok[4:7] = allowed[4:7]
    jump_ok[2, grid.centre, grid.centre] = True
    left = _Left({5: left_at_5}, (n, n))
    costs = LeanCosts(over, allowed, np.zeros_like(over), jump_ok, 0.0,
                      stranded=left)  # type: ignore[arg-type]
    cells, jumps, total = _cheapest(costs, grid, np.full(nb, 0.5), SMALL)
    assert cells[-1] == (1, n // 2) and total < 10.0
    assert jumps == [5] if left_at_5 == 0.0 else jumps in ([4], [6])
    assert 5 in left.asked and 2 not in left.asked


def test_the_lean_of_the_root_times_its_pricing_and_its_solving() -> None:
    """The rod past the limit leans; the plan says how long pricing and solving took
    (``hostctl slice``'s plan stages, ``bench/plan.py --lean``)."""
    solid = _rod_on_column(20.0)
    root = _subpart(solid)
    dec = Decomposition(np.eye(4), [root], [0], float(solid.volume()), {}, 1, 1)

    def centre(mesh, point: np.ndarray, normal: np.ndarray) -> np.ndarray:
        return np.array([0.0, 0.0, float(point[2])])

    leaned = lean_upright(dec, slicing_solid(root.mesh), centre, TURNING, Printhead.default(),
                          SMALL)
    assert leaned.plans and set(leaned.seconds) == {"lean_price", "lean_solve"}
    assert all(s > 0.0 for s in leaned.seconds.values())
    upright = lean_upright(dec, slicing_solid(root.mesh), centre, TURNING,
                           Printhead.default(), None)
    assert not upright.plans and upright.seconds == {}
