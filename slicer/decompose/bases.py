"""Which flat face the part stands on: its own base, or a much larger one when that fails.

The loader stands a part on its own bottom (:func:`slicer.mesh.placement.find_base`). A part
exported upside down then stands on a small face (a branch end, the top rim of its tube)
and the decomposition refuses it, or leaves it overhanging. :func:`decompose_on_bases`
decomposes the part as placed first; only when that is refused, or its best result
overhangs more than the retry threshold, does it try the flat faces at least
``TOL.base_ratio`` times larger than the one it stands on (largest first, at most
``TOL.base_tries``), each with the full seed plan of :func:`~slicer.decompose.decompose`. A
part standing well keeps its placement and costs one convex hull more. The choice, and every
face tried, is in :class:`~slicer.mesh.placement.BaseChoice` (``Decomposition.base``); the placement
matrix of the G-code header and ``decomposition.json`` is the one it stands on.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np
import trimesh

from kinematics.machine import MachineGeometry
from slicer.decompose.decomposition import (
    DecomposeSettings,
    Decomposition,
    DecompositionError,
    RootRegionError,
    decompose,
)
from slicer.mesh import (
    BaseChoice,
    FlatBase,
    MeshError,
    flat_bases,
    place_on_platform,
    standing_base,
)
from slicer.planes2d import TOL
from slicer.printhead import Printhead

log = logging.getLogger(__name__)

#: Axis names of the file's frame, for the normal of a face.
_AXES = {"+X": (1, 0, 0), "-X": (-1, 0, 0), "+Y": (0, 1, 0), "-Y": (0, -1, 0),
         "+Z": (0, 0, 1), "-Z": (0, 0, -1)}


@dataclass(frozen=True)
class _Outcome:
    """One face tried: where it stands, and the decomposition or why it was refused."""

    base: FlatBase  # in the placed frame of the loaded part
    normal: np.ndarray  # (3,) its outward normal in the file's frame
    turn: np.ndarray | None  # (4, 4) loaded placed frame → this one; None: as loaded
    result: Decomposition | None
    refusal: str  # why it was refused ("" when decomposed)

    def face(self) -> str:
        """``"113 mm² face (normal -Z in the file)"``."""
        return f"{self.base.area:.0f} mm² face (normal {direction_text(self.normal)} in the file)"

    def line(self) -> str:
        """What happened on this face, one line."""
        if self.result is None:
            return f"{self.face()}: refused: {self.refusal}"
        return (f"{self.face()}: {len(self.result.subparts)} sub-parts, seed "
                f"{self.result.seed}, overhang {self.result.overhang_area:.1f} mm²")


def decompose_on_bases(mesh: trimesh.Trimesh, settings: DecomposeSettings,
                       machine: MachineGeometry, head: Printhead,
                       build_volume: np.ndarray | None, placement: np.ndarray
                       ) -> Decomposition:
    """Decompose a placed part, standing it on a much larger flat face when it fails as placed.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The part as placed by :func:`~slicer.mesh.placement.place_on_platform` (base on z = 0).
    settings, machine, head, build_volume
        As for :func:`~slicer.decompose.decompose`. A fixed ``settings.root`` names a region
        of this placement's partition, so it pins the placement (no other face is tried).
    placement : (4, 4) float
        File frame → the frame ``mesh`` is placed in.

    Returns
    -------
    Decomposition
        With ``base`` set; ``placement`` is file frame → the frame it stands in, and
        ``base.turn`` moves ``mesh`` there (:func:`~slicer.mesh.placement.moved`).

    Raises
    ------
    DecompositionError
        Refused on every face tried: the refusal as placed, then the other faces' (one line);
        or refused as placed with a fixed root while a much larger face exists (named).
    slicer.mesh.errors.MeshError
    """
    t0 = time.perf_counter()
    rotation = np.asarray(placement, dtype=float)[:3, :3]
    own = standing_base(mesh)
    larger = [b for b in flat_bases(mesh) if b.area >= TOL.base_ratio * own.area]
    first = _try(mesh, own, None, rotation, settings, machine, head, build_volume, placement)
    if settings.root is not None or not larger or _good(first, mesh):
        return _kept(first, larger, rotation)
    tried = [first]
    for base in larger[:TOL.base_tries]:
        placed, moved_by = place_on_platform(mesh, base=base)
        tried.append(_try(placed, base, moved_by.matrix, rotation, settings, machine, head,
                          build_volume, moved_by.matrix @ placement))
        if _good(tried[-1], placed):
            break
    best = _best(tried, mesh)
    if best.result is None:
        raise DecompositionError(_refused_everywhere(tried))
    dec = best.result
    note = (_turned_note(first, best) if best is not first
            else _stayed_note(first, tried[1:], larger, rotation))
    chosen = BaseChoice(best.base.area, best.normal, best.turn, note,
                        tuple(o.line() for o in tried))
    _set_base(dec, chosen)
    dec.timings = {**dec.timings, "other_bases": time.perf_counter() - t0
                   - sum(dec.timings.values())}
    _log(chosen)
    return dec


def _try(mesh: trimesh.Trimesh, base: FlatBase, turn: np.ndarray | None,
         rotation: np.ndarray, settings: DecomposeSettings, machine: MachineGeometry,
         head: Printhead, build_volume: np.ndarray | None, placement: np.ndarray) -> _Outcome:
    """Decompose ``mesh`` standing on ``base``; a refusal is kept, not raised (but a bad
    ``--root``, which no other face mends)."""
    normal = rotation.T @ base.normal  # every base was found on the part as loaded
    try:
        dec = decompose(mesh, settings, machine, head, build_volume, placement)
    except RootRegionError:
        raise
    except MeshError as exc:
        if turn is None:  # bad input as loaded (too big, ...): refused as before
            raise
        return _Outcome(base, normal, turn, None, str(exc).removeprefix("<mesh>: "))
    except DecompositionError as exc:
        return _Outcome(base, normal, turn, None, str(exc))
    return _Outcome(base, normal, turn, dec, "")


def _good(outcome: _Outcome, mesh: trimesh.Trimesh) -> bool:
    """Decomposed with no more overhang than the seed retries accept (no other face tried)."""
    return outcome.result is not None and outcome.result.overhang_area <= _retry_above(mesh)


def _retry_above(mesh: trimesh.Trimesh) -> float:
    """The overhang, mm², above which :func:`~slicer.decompose.decompose` retries seeds."""
    return max(TOL.overhang_retry_abs, TOL.overhang_retry_rel * float(mesh.area))


def _best(tried: list[_Outcome], mesh: trimesh.Trimesh) -> _Outcome:
    """The placement kept: as placed (the first) unless another face overhangs less by more
    than the retry threshold; among the others, the least overhang (then the larger face)."""
    done = [o for o in tried if o.result is not None]
    if not done:
        return tried[0]
    best = min(done, key=lambda o: round(_overhang(o), 1))
    first = tried[0]
    if first.result is not None and _overhang(best) >= _overhang(first) - _retry_above(mesh):
        return first
    return best


def _overhang(outcome: _Outcome) -> float:
    assert outcome.result is not None
    return outcome.result.overhang_area


def _larger_hint(first: _Outcome, larger: list[FlatBase], rotation: np.ndarray) -> str | None:
    """``"the part stands on a 113 mm² face; its largest flat face (804 mm², normal +Z in the
    file) is 7.1× larger"``, or None when no face is much larger."""
    if not larger:
        return None
    big = larger[0]
    return (f"the part stands on a {first.base.area:.0f} mm² face; its largest flat face "
            f"({big.area:.0f} mm², normal {direction_text(rotation.T @ big.normal)} in the "
            f"file) is {big.area / first.base.area:.1f}× larger")


def _kept(first: _Outcome, larger: list[FlatBase], rotation: np.ndarray) -> Decomposition:
    """The part as placed (no other face tried), with a note naming a much larger face."""
    hint = _larger_hint(first, larger, rotation)
    if first.result is None:
        if hint is None:
            raise DecompositionError(first.refusal)
        raise DecompositionError(f"{first.refusal}; {hint} and may decompose: turn the part to "
                                 "stand on it, or leave the root region automatic (no --root) so "
                                 "the slicer tries it")
    dec = first.result
    note = None if hint is None else f"{hint}: turn the part to stand on it for a steadier print"
    base = BaseChoice(first.base.area, first.normal, None, note, (first.line(),))
    _set_base(dec, base)
    _log(base)
    return dec


def _set_base(dec: Decomposition, base: BaseChoice) -> None:
    """``dec`` and its runners-up stand on ``base``."""
    for one in (dec, *dec.runners_up):
        one.base = base


def _turned_note(first: _Outcome, best: _Outcome) -> str:
    """Why the part stands on ``best``'s face and not as placed."""
    assert best.result is not None
    as_placed = (f"was refused: {first.refusal}" if first.result is None
                 else f"overhangs {_overhang(first):.0f} mm² (here {_overhang(best):.0f} mm²)")
    return (f"turned to stand on its {best.face()}, {_degrees(first, best):.0f}° from the "
            f"file's orientation: standing as placed, on its {first.face()}, it {as_placed}")


def _stayed_note(first: _Outcome, others: list[_Outcome], larger: list[FlatBase],
                 rotation: np.ndarray) -> str:
    """Why a part that overhangs as placed still stands so: the larger faces did no better."""
    tried = "; ".join(o.line() for o in others)
    return (f"{_larger_hint(first, larger, rotation)}; tried standing on {tried}; it stands as "
            f"placed (overhang {_overhang(first):.0f} mm²)")


def _degrees(first: _Outcome, best: _Outcome) -> float:
    """Angle between the file-frame normals of two faces, degrees."""
    return float(np.degrees(np.arccos(np.clip(first.normal @ best.normal, -1.0, 1.0))))


def _refused_everywhere(tried: list[_Outcome]) -> str:
    """One line: the refusal as placed, then the other faces'."""
    first, others = tried[0], tried[1:]
    rest = "; ".join(f"on its {o.face()} it is refused too: {o.refusal}" for o in others)
    return f"{first.refusal}, standing as placed on its {first.face()}; {rest}"


def direction_text(normal: np.ndarray) -> str:
    """``"+Z"`` for a unit vector within 1° of an axis, else ``"[0.71, 0.00, -0.71]"``."""
    n = np.asarray(normal, dtype=float)
    for name, axis in _AXES.items():
        if n @ np.asarray(axis, dtype=float) >= np.cos(np.radians(1.0)):
            return name
    return "[" + ", ".join(f"{x:.2f}" for x in n + 0.0) + "]"


def _log(base: BaseChoice) -> None:
    for line in base.tried:
        log.debug("base tried: %s", line)
    if base.note:
        log.info("%s", base.note)


__all__ = ["decompose_on_bases", "direction_text"]
