"""The exported metrics, declared once: name, type, help text and where each value lives.

Every value is read from the daemon's status snapshot (a dict of component ``status()``
results, see :meth:`hostd.daemon.Daemon.snapshot`), addressed by a dotted path such as
``link.lines_sent``. The job figures are those of ``jobs.latest``: the job on the printer, or
else the last one that printed (so a finished job shows its outcome and a progress of 1 until
the next one starts); jobs waiting in the queue are counted in ``hostd_jobs``, not shown
there. Metrics never reach into a component's internals.
Names follow Prometheus conventions: ``hostd_`` prefix, base units, ``_total`` on counters,
labels of low cardinality only (the job id appears only in ``hostd_job_info``).
"""

from __future__ import annotations

from dataclasses import dataclass

from hostd.control.limits import DROP_REASONS


@dataclass(frozen=True)
class Spec:
    """One metric family.

    kind : "gauge" | "counter" | "histogram" | "info" | "stateset"
    path : dotted path to the value in the snapshot
    label : for a dict-valued path, the label its keys become
    field : for a labelled path whose values are dicts, the entry of each to export
    keys : for a labelled path, export only these keys (in this order); for a stateset, its
        states (the first one is set when the path holds nothing, a value not among them
        sets none)
    scale : factor applied to numbers (e.g. mm → m)
    """

    name: str
    kind: str
    doc: str
    path: str
    label: str | None = None
    field: str | None = None
    keys: tuple[str, ...] | None = None
    scale: float = 1.0

    @property
    def unit(self) -> str:
        """The base unit ending the name (``seconds``, ``celsius``...), or ``""``."""
        if self.kind not in ("gauge", "counter", "histogram"):
            return ""
        stem = self.name.removesuffix("_total") if self.kind == "counter" else self.name
        return next((u for u in UNITS if stem.endswith("_" + u)), "")


UNITS = ("seconds", "celsius", "meters", "degrees", "bytes", "ratio")


JOB_STATES = ("queued", "slicing", "ready", "printing", "paused", "completed", "failed",
              "cancelled", "interrupted")
PRINTER_JOB_STATES = ("idle", "printing", "paused", "completed", "failed", "cancelled",
                      "interrupted")
"""The states ``hostd_job_state`` shows: a job on the printer, or how the last one ended."""
LINK_STATES = ("disconnected", "handshake", "ready", "halted")
LISTENERS = ("control", "metrics")

SPECS: tuple[Spec, ...] = (
    Spec("hostd", "info", "Daemon version, printer and firmware identity.", "daemon.info"),
    Spec("hostd_start_time_seconds", "gauge", "Unix time hostd started (a change is a restart: "
         "the counters began again at 0).", "metrics.start_time_s"),
    Spec("hostd_firmware_capability", "gauge", "Firmware capabilities from M115 (1 = on).",
         "link.capabilities", label="capability"),
    Spec("hostd_job", "info", "Identity of the current (or last) job (id, name).",
         "jobs.latest.info"),
    Spec("hostd_job_state", "stateset", "State of the job on the printer (printing, paused), "
         "else how the last job that printed ended; idle when none has. Jobs waiting to print "
         "are in hostd_jobs.", "jobs.latest.state", label="state", keys=PRINTER_JOB_STATES),
    Spec("hostd_jobs", "gauge", "Jobs in the job database, by state (queued, slicing and "
         "ready wait to print; hostctl delete removes finished ones).", "jobs.counts",
         label="state", keys=JOB_STATES),
    Spec("hostd_job_progress_ratio", "gauge", "Acknowledged lines over total lines (0..1).",
         "jobs.latest.progress"),
    Spec("hostd_job_subpart", "gauge", "Index of the sub-part being printed.",
         "jobs.latest.subpart"),
    Spec("hostd_job_subparts", "gauge", "Number of sub-parts of the job.",
         "jobs.latest.subparts_total"),
    Spec("hostd_job_layer", "gauge", "Index of the layer being printed, counted from the "
         "start of its sub-part (hostd_job_subpart): not comparable with hostd_job_layers.",
         "jobs.latest.layer"),
    Spec("hostd_job_layers", "gauge", "Number of layers of the whole job, every sub-part's "
         "together (progress across the job: hostd_job_progress_ratio).",
         "jobs.latest.layers_total"),
    Spec("hostd_job_elapsed_seconds", "gauge", "Print time elapsed.",
         "jobs.latest.elapsed_s"),
    Spec("hostd_job_remaining_seconds", "gauge", "Estimated print time remaining.",
         "jobs.latest.remaining_s"),
    Spec("hostd_job_filament_used_meters", "gauge", "Filament fed so far in the job.",
         "jobs.latest.filament_mm", scale=1e-3),
    Spec("hostd_queue_length", "gauge", "Jobs waiting (queued, slicing or ready).",
         "jobs.queue_length"),
    Spec("hostd_queue_held", "gauge", "1 while no new job starts: a part is on the platform "
         "(daemon.next_job: after_clear) or the operator held the queue.", "jobs.queue.held"),
    Spec("hostd_queue_waiting_for_printer", "gauge", "1 while a ready job waits for the serial "
         "link (down or halted).", "jobs.waiting_for_printer"),
    Spec("hostd_storage_failing", "gauge", "1 while the job database cannot be written (a full "
         "disk, a failing card): the job printing is paused (reason storage error), uploads "
         "are refused; 0 once the writes go through again.", "jobs.storage.failing"),
    Spec("hostd_jobs_finished_total", "counter", "Jobs finished since hostd started, by "
         "outcome (0 at each start, as every counter here).", "metrics.jobs_finished",
         label="outcome"),
    Spec("hostd_slicing_duration_seconds", "histogram", "Wall time of slicing jobs.",
         "slicer.durations"),
    Spec("hostd_slicing_failures_total", "counter", "Slicing jobs that failed (the part "
         "refused, the worker died, the G-code could not be kept); not those cancelled.",
         "slicer.failures"),
    Spec("hostd_file_checks_total", "counter", "Files checked whole before their job is "
         "queued (uploads, and the slicer's G-code), in a worker process.",
         "jobs.file_checks.checks"),
    Spec("hostd_file_checks_refused_total", "counter", "Files the check refused (not G-code, "
         "corrupt STL, ...) or could not finish.", "jobs.file_checks.refused"),
    Spec("hostd_transitions_total", "counter", "Rotate/return transitions run as transactions.",
         "jobs.transitions.total"),
    Spec("hostd_transition_failures_total", "counter", "Transitions whose readback mismatched.",
         "jobs.transitions.failed"),
    Spec("hostd_serial_link_up", "gauge", "1 while the firmware link is connected.",
         "link.connected"),
    Spec("hostd_serial_link_state", "stateset", "State of the firmware link: disconnected "
         "(down, reconnecting by itself), handshake, ready, halted (estop, a firmware kill or "
         "a link too noisy: hostctl firmware-restart).", "link.state", label="state",
         keys=LINK_STATES),
    Spec("hostd_serial_firmware_resets_total", "counter", "Firmware resets seen while the "
         "link was up (the board rebooted under an open port: the job is interrupted).",
         "link.resets"),
    Spec("hostd_serial_lines_sent_total", "counter", "Lines written to the firmware.",
         "link.lines_sent"),
    Spec("hostd_serial_lines_acknowledged_total", "counter", "Lines the firmware acknowledged.",
         "link.lines_acked"),
    Spec("hostd_serial_starve_nudges_total", "counter", "M105 nudges after "
         "serial.starve_timeout without an ok while lines waited for credit (a lost ok, or a "
         "long move).", "link.starve_nudges"),
    Spec("hostd_serial_lines_resent_total", "counter", "Lines sent again after a resend request.",
         "link.lines_resent"),
    Spec("hostd_serial_resyncs_total", "counter", "M110s sent to set the firmware's line "
         "count back after a resend request out of step with the lines it took (or one that "
         "refused lines after the one asked for): transmission goes on from the line after "
         "the last one taken.", "link.resyncs"),
    Spec("hostd_serial_lines_withdrawn_total", "counter", "Job lines taken back unsent by a "
         "pause or cancel (sent again on resume).", "link.lines_withdrawn"),
    Spec("hostd_serial_reads_total", "counter", "Port reads that brought replies (while reads "
         "are held, one read takes in several oks).", "link.reads"),
    Spec("hostd_serial_checksum_errors_total", "counter", "Checksum/line-number errors reported.",
         "link.checksum_errors"),
    Spec("hostd_serial_timeouts_total", "counter", "serial.ok_timeout periods that passed "
         "without an ok: each M105 nudge, and the last one after which the link is lost "
         "(serial.nudges: 1 gives 2 for a board gone silent).", "link.timeouts"),
    Spec("hostd_serial_reconnects_total", "counter", "Times the port was reopened after the "
         "link was lost; a firmware reset on an open port is counted in "
         "hostd_serial_firmware_resets_total instead.", "link.reconnects"),
    Spec("hostd_serial_window_bytes", "gauge", "Bytes the send window may hold in flight.",
         "link.window_bytes"),
    Spec("hostd_serial_ok_roundtrip_seconds", "histogram", "Time from a line's send to its ok.",
         "link.ok_rtt.histogram"),
    Spec("hostd_temperature_celsius", "gauge", "Measured heater temperature.",
         "link.temperatures", label="heater", field="actual"),
    Spec("hostd_temperature_target_celsius", "gauge", "Heater set point.",
         "link.temperatures", label="heater", field="target"),
    Spec("hostd_connections_open", "gauge", "Client connections open, by listener (control: "
         "the JSON-RPC socket, at most daemon.max_connections; metrics: this endpoint, at "
         "most metrics.max_connections).", "connections.open", label="listener",
         keys=LISTENERS),
    Spec("hostd_connections_refused_total", "counter", "Connections turned away at the cap, "
         "by listener: every place held by a connection that has sent a request (a silent "
         "one is closed to make room instead, and counted in hostd_connections_dropped_total "
         "as room).", "connections.refused", label="listener", keys=LISTENERS),
    Spec("hostd_connections_dropped_total", "counter", "Control connections closed by a "
         "limit, by reason: idle (daemon.idle_timeout without a whole request), too_large "
         "(a request over daemon.max_request_bytes), budget (holding the most when "
         "daemon.max_buffered_bytes ran out), slow_reader (a subscriber not reading its "
         "events), room (silent, closed for a new connection at the cap).",
         "connections.dropped", label="reason", keys=DROP_REASONS),
    Spec("hostd_events_dropped_total", "counter", "Pushed events a subscriber never got "
         "because it was dropped for not reading them (the one that found its queue full, "
         "and those still queued).", "connections.events_dropped"),
    Spec("hostd_axis_position_degrees", "gauge",
         "Rotary axis position after the job's acknowledged lines (A tilt, C rotation).",
         "jobs.latest.axes", label="axis", keys=("A", "C")),
)
