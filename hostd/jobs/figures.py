"""A job's figures, one type for every view of them: the ``job.progress`` event, the current
and latest job of ``status()`` (and so the metrics) and the live fields of ``job.get``.

:class:`JobFigures` is built from the job on the printer (:meth:`JobFigures.live`) or, after a
restart, from the job database (:meth:`JobFigures.stored`), and each view is rendered from it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from hostd.jobs.active import Active
from hostd.jobs.store import Job


@dataclass(frozen=True)
class JobFigures:
    """How far one job has got. ``None`` where the source does not know (a job read back
    from the database has no program loaded: no sub-part and layer totals, no axes)."""

    id: int
    name: str
    state: str
    acked: int
    total: int
    progress: float
    subpart: int | None
    layer: int | None
    elapsed_s: float
    remaining_s: float | None
    filament_mm: float
    subparts_total: int | None = None
    layers_total: int | None = None
    a: float | None = None
    c: float | None = None
    subpart_layers: int | None = None
    """Layers of the sub-part being printed (``layer`` counts within it)."""
    stream: str | None = None
    """The streamer's state (streaming, paused, ...), for the progress event."""
    pause_reason: str | None = None

    @classmethod
    def live(cls, act: Active, now: float) -> JobFigures:
        """The figures of the job on the printer at ``now`` (monotonic seconds)."""
        st = act.streamer
        total = st.program.total
        ratio = st.acked / total if total else 1.0
        elapsed = act.elapsed(now)
        since, mark = act.rate_mark or (elapsed, ratio)
        modal = st.modal
        return cls(id=act.job.id, name=act.job.name, state=act.job.state.value,
                   acked=st.acked, total=total, progress=ratio, subpart=st.subpart,
                   layer=st.layer, elapsed_s=elapsed,
                   remaining_s=eta(act.program.estimate.get("time_s"), ratio, elapsed - since,
                                   mark),
                   filament_mm=modal.extruded, subparts_total=len(act.program.subparts),
                   layers_total=len(act.program.layers),
                   subpart_layers=act.layers_of(st.subpart), a=modal.position["A"],
                   c=modal.position["C"], stream=st.state, pause_reason=st.pause_reason)

    @classmethod
    def stored(cls, job: Job) -> JobFigures:
        """The figures the job database kept of ``job`` (after a restart)."""
        total = job.total_lines
        return cls(id=job.id, name=job.name, state=job.state.value, acked=job.acked_lines,
                   total=total, progress=job.acked_lines / total if total else 0.0,
                   subpart=job.subpart, layer=job.layer, elapsed_s=job.print_seconds,
                   remaining_s=None, filament_mm=job.filament_mm)

    def with_state(self, state: str) -> JobFigures:
        return replace(self, state=state)

    def progress_event(self) -> dict[str, Any]:
        """The ``job.progress`` event's data."""
        return {"job_id": self.id, "acked": self.acked, "total": self.total,
                "progress": self.progress, "subpart": self.subpart, "layer": self.layer,
                "elapsed_s": self.elapsed_s, "eta_s": self.remaining_s,
                "filament_mm": self.filament_mm, "state": self.state, "stream": self.stream,
                "a": self.a, "c": self.c, "subparts_total": self.subparts_total,
                "subpart_layers": self.subpart_layers}

    def status(self) -> dict[str, Any]:
        """``status()``'s ``current`` and ``latest`` job (the metrics read them)."""
        return {"info": {"id": str(self.id), "name": self.name}, "id": self.id,
                "state": self.state, "progress": self.progress, "acked": self.acked,
                "total": self.total, "subpart": self.subpart,
                "subparts_total": self.subparts_total, "layer": self.layer,
                "layers_total": self.layers_total, "subpart_layers": self.subpart_layers,
                "elapsed_s": self.elapsed_s,
                "remaining_s": self.remaining_s, "filament_mm": self.filament_mm,
                "a": self.a, "c": self.c,
                "axes": {} if self.a is None else {"A": self.a, "C": self.c},
                "pause_reason": self.pause_reason}

    def job_fields(self) -> dict[str, Any]:
        """The live fields a job's row gets while it is on the printer (``job.get``)."""
        return {"acked_lines": self.acked, "progress": self.progress, "subpart": self.subpart,
                "layer": self.layer, "eta_s": self.remaining_s, "elapsed_s": self.elapsed_s,
                "filament_mm": self.filament_mm}


def eta(estimate_s: float | None, ratio: float, elapsed: float, start_ratio: float
        ) -> float | None:
    """Remaining seconds: the slicer's estimate scaled by the measured/estimated rate.

    ``elapsed`` is the printing time since progress was ``start_ratio``; until 1 % more is
    done the estimate stands (None without one)."""
    done = ratio - start_ratio
    if ratio >= 1.0:
        return 0.0
    if estimate_s is None or estimate_s <= 0:
        return elapsed * (1 - ratio) / done if done > 0.01 else None
    remaining = estimate_s * (1 - ratio)
    if done <= 0.01 or elapsed <= 0:
        return remaining
    factor = elapsed / (estimate_s * done)
    return remaining * factor
