"""The job database: SQLite in WAL mode in the state directory.

The schema is versioned with ``PRAGMA user_version``: a database of an older version is
brought up to date when opened (:data:`MIGRATIONS`: columns added with their defaults, so
its jobs read as before), one of a newer version is refused with a clear error. Writes are
single small statements, each its own transaction, so a SIGKILL leaves the last committed
progress and state on disk.

No commit copies the write-ahead log back into the database: SQLite's automatic checkpoint
would do so inside the commit that fills a thousand pages, on the event loop, with an fsync
of the database file, while a job streams (`bench/store.py`: such a commit took 18–23 ms on
the project's VM, where hostd's longest took 0.8–1.2 ms; an SD card syncs far more slowly).
The owner asks :meth:`JobStore.claim_checkpoint` after its writes and runs
:meth:`JobStore.checkpoint`, which uses a connection of its own, on a worker thread.

A write the disk refuses (full, read-only, an I/O error) is no crash: a job's state, its
progress and the settings are kept in memory as *pending* (reads show them), :attr:`failure`
names the error in one line, and :meth:`flush` writes them once the disk takes them again.
What cannot wait (a new job, a deletion, a checkpoint row) raises :class:`StorageError`.
"""

from __future__ import annotations

import builtins
import contextlib
import json
import sqlite3
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from hostd.jobs.states import ACTIVE, TERMINAL, WAITING, JobState, check_transition

SCHEMA_VERSION = 2
CHECKPOINT_CHANGES = 500
"""Rows written between two checkpoints (a page of the log or so each: 2 MB of log)."""

_DDL = """
CREATE TABLE IF NOT EXISTS jobs (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    name TEXT NOT NULL,
    kind TEXT NOT NULL CHECK (kind IN ('stl', 'gcode')),
    upload_sha TEXT NOT NULL,
    gcode_sha TEXT,
    state TEXT NOT NULL,
    reason TEXT NOT NULL DEFAULT '',
    created_at REAL NOT NULL,
    updated_at REAL NOT NULL,
    started_at REAL,
    finished_at REAL,
    total_lines INTEGER NOT NULL DEFAULT 0,
    acked_lines INTEGER NOT NULL DEFAULT 0,
    subpart INTEGER,
    layer INTEGER,
    filament_mm REAL NOT NULL DEFAULT 0,
    print_seconds REAL NOT NULL DEFAULT 0,
    modal TEXT NOT NULL DEFAULT '{}',
    estimate TEXT NOT NULL DEFAULT '{}',
    info TEXT NOT NULL DEFAULT '{}',
    resume TEXT NOT NULL DEFAULT '{}',
    allow_overhang INTEGER NOT NULL DEFAULT 0,
    slice_options TEXT NOT NULL DEFAULT '{}'
);
CREATE TABLE IF NOT EXISTS history (
    job_id INTEGER NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    at REAL NOT NULL,
    old TEXT,
    new TEXT NOT NULL,
    reason TEXT NOT NULL DEFAULT ''
);
CREATE INDEX IF NOT EXISTS history_job ON history(job_id);
CREATE TABLE IF NOT EXISTS checkpoints (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    job_id INTEGER NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    at REAL NOT NULL,
    subpart INTEGER NOT NULL,
    parent INTEGER,
    a REAL NOT NULL,
    c REAL NOT NULL,
    line INTEGER NOT NULL,
    pose TEXT NOT NULL DEFAULT '{}'
);
CREATE INDEX IF NOT EXISTS checkpoints_job ON checkpoints(job_id);
CREATE TABLE IF NOT EXISTS settings (
    key TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
"""

MIGRATIONS: dict[int, tuple[str, ...]] = {
    1: ("ALTER TABLE jobs ADD COLUMN allow_overhang INTEGER NOT NULL DEFAULT 0",
        "ALTER TABLE jobs ADD COLUMN slice_options TEXT NOT NULL DEFAULT '{}'"),
}
"""Statements that take a database of version ``v`` to ``v + 1``."""

_JSON_COLUMNS = ("modal", "estimate", "info", "resume", "slice_options")
_WRITABLE = frozenset({"gcode_sha", "total_lines", "acked_lines", "subpart", "layer",
                       "filament_mm", "print_seconds", "modal", "estimate", "info", "resume",
                       "started_at", "reason"})


class StoreError(Exception):
    """The job database cannot be opened or a request names no job."""


class JobNotFound(StoreError):
    """No job has the requested id."""


class StorageError(StoreError):
    """The disk refused a write of the job database (full, read-only, an I/O error)."""


_REFUSED = (sqlite3.OperationalError, sqlite3.DatabaseError)
"""What SQLite raises when the disk refuses a write (SQLITE_FULL, SQLITE_IOERR, ...)."""


@dataclass
class Job:
    """One row of ``jobs``, JSON columns decoded."""

    id: int
    name: str
    kind: str
    upload_sha: str
    gcode_sha: str | None
    state: JobState
    reason: str
    created_at: float
    updated_at: float
    started_at: float | None
    finished_at: float | None
    total_lines: int
    acked_lines: int
    subpart: int | None
    layer: int | None
    filament_mm: float
    print_seconds: float
    modal: dict[str, Any] = field(default_factory=dict)
    estimate: dict[str, Any] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)
    resume: dict[str, Any] = field(default_factory=dict)
    allow_overhang: bool = False
    """An STL job whose file may have unsupported wall layers (``--allow-overhang``)."""
    slice_options: dict[str, Any] = field(default_factory=dict)
    """The decomposition settings the job was submitted with (``seed``, ``parts``), over the
    daemon's config."""

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready values. The JSON columns are shared, not copied: each ``Job`` is
        read fresh from the database (``dataclasses.asdict`` deep-copied them, which made
        ``job.list`` three times slower: ``bench/job_list.py``)."""
        d = dict(vars(self))
        d["state"] = self.state.value
        d["progress"] = self.acked_lines / self.total_lines if self.total_lines else 0.0
        return d


@dataclass(frozen=True)
class Checkpoint:
    """A completed transition: sub-part ``subpart`` starts at A/C from file line ``line``."""

    seq: int
    job_id: int
    at: float
    subpart: int
    parent: int | None
    a: float
    c: float
    line: int
    pose: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class JobStore:
    """The jobs table and its history and checkpoints.

    Parameters
    ----------
    path
        The database file; ``":memory:"`` for tests.
    clock
        Seconds since the epoch (injectable for tests).
    checkpoint_changes
        Rows written between two checkpoints (:meth:`claim_checkpoint`).
    """

    def __init__(self, path: str | Path, clock: Any = time.time,
                 checkpoint_changes: int = CHECKPOINT_CHANGES) -> None:
        self.path = str(path)
        self._clock = clock
        self._checkpoint_changes = checkpoint_changes
        self._claimed = 0  # total changes when the last checkpoint was claimed
        self.failure: str | None = None  # the disk's refusal while writes are pending
        self.on_failure: Callable[[], None] = lambda: None  # called as writes start failing
        self._pending: dict[int, dict[str, Any]] = {}  # job → columns not yet written
        self._pending_history: list[tuple[int, float, str, str, str]] = []
        self._pending_settings: dict[str, str | None] = {}
        try:
            self._db = sqlite3.connect(self.path, isolation_level=None,
                                       check_same_thread=False)
            self._db.row_factory = sqlite3.Row
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=NORMAL")
            self._db.execute("PRAGMA wal_autocheckpoint=0")  # see the module docstring
            self._db.execute("PRAGMA foreign_keys=ON")
            self._init_schema()
        except sqlite3.Error as exc:
            raise StoreError(f"{self.path}: cannot open the job database: {exc}") from None

    def _init_schema(self) -> None:
        version = self._db.execute("PRAGMA user_version").fetchone()[0]
        if version > SCHEMA_VERSION or version < 0:
            raise StoreError(f"{self.path}: job database schema {version} is not "
                             f"{SCHEMA_VERSION}; move it away to start afresh")
        with self._db:  # one transaction: a database is migrated whole or not at all
            self._db.execute("BEGIN")
            for v in range(version or SCHEMA_VERSION, SCHEMA_VERSION):  # none when new
                for statement in MIGRATIONS[v]:
                    self._db.execute(statement)
            for statement in _DDL.split(";"):  # what is missing (all of a new database)
                if statement.strip():
                    self._db.execute(statement)
            self._db.execute(f"PRAGMA user_version={SCHEMA_VERSION}")

    def close(self) -> None:
        self._db.close()

    def claim_checkpoint(self) -> bool:
        """True, once, when ``checkpoint_changes`` rows were written since the last claim:
        the caller then runs :meth:`checkpoint` off the event loop."""
        changes = self._db.total_changes
        if changes - self._claimed < self._checkpoint_changes:
            return False
        self._claimed = changes
        return True

    def checkpoint(self) -> tuple[int, int]:
        """Copy the write-ahead log into the database (``wal_checkpoint(PASSIVE)``: it waits
        for no lock, and what it cannot copy now waits for the next one).

        It opens a connection of its own, so it may run on a worker thread while this store
        writes on. Returns the frames in the log and those copied ((0, 0) in memory).

        Raises
        ------
        StoreError
            The database cannot be opened or checkpointed.
        """
        if self.path == ":memory:":
            return 0, 0
        try:
            db = sqlite3.connect(self.path, isolation_level=None)
            try:
                _busy, frames, copied = db.execute("PRAGMA wal_checkpoint(PASSIVE)").fetchone()
            finally:
                db.close()
        except sqlite3.Error as exc:
            raise StoreError(f"{self.path}: checkpoint failed: {exc}") from None
        return int(frames), int(copied)

    # -- jobs ------------------------------------------------------------------------------

    def add(self, name: str, kind: str, upload_sha: str, gcode_sha: str | None = None,
            estimate: dict[str, Any] | None = None, allow_overhang: bool = False,
            slice_options: dict[str, Any] | None = None) -> Job:
        """Insert a new ``queued`` job and return it (:class:`StorageError` while the disk
        refuses writes)."""
        now = self._clock()
        with self._refused("a new job"), self._db:
            cur = self._db.execute(
                "INSERT INTO jobs (name, kind, upload_sha, gcode_sha, state, created_at,"
                " updated_at, estimate, allow_overhang, slice_options)"
                " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (name, kind, upload_sha, gcode_sha, JobState.QUEUED.value, now, now,
                 json.dumps(estimate or {}), int(allow_overhang),
                 json.dumps(slice_options or {})))
            job_id = int(cur.lastrowid or 0)
            self._db.execute("INSERT INTO history (job_id, at, old, new, reason)"
                             " VALUES (?, ?, NULL, ?, 'submitted')",
                             (job_id, now, JobState.QUEUED.value))
        return self.get(job_id)

    def get(self, job_id: int) -> Job:
        row = self._db.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()
        if row is None:
            raise JobNotFound(f"no job {job_id}")
        return self._overlaid(_job(row))

    def _overlaid(self, job: Job) -> Job:
        """``job`` with the columns still pending (as written)."""
        pending = self._pending.get(job.id)
        if pending:
            for column, value in pending.items():
                setattr(job, column, JobState(value) if column == "state" else value)
        return job

    def _pending_jobs(self, states: Iterable[JobState] | None) -> builtins.list[Job]:
        """Every job (in ``states``) as reads show it while writes are pending, oldest first:
        the pending states decide, not the database's."""
        wanted = None if states is None else set(states)
        rows = self._db.execute("SELECT * FROM jobs ORDER BY id").fetchall()
        jobs = [self._overlaid(_job(r)) for r in rows]
        return [j for j in jobs if wanted is None or j.state in wanted]

    def list(self, states: Iterable[JobState] | None = None, limit: int = 1000,
             newest: bool = False) -> list[Job]:
        """Jobs oldest first, optionally only those in ``states``: the oldest ``limit`` of
        them, or with ``newest`` the newest ``limit`` (still oldest first); ``limit`` 0: all.
        """
        if self._pending:
            jobs = self._pending_jobs(states)
            if limit:
                jobs = jobs[-limit:] if newest else jobs[:limit]
            return jobs
        where, args = self._where(states)
        order = "DESC" if newest else "ASC"
        rows = self._db.execute(f"SELECT * FROM jobs{where} ORDER BY id {order} LIMIT ?",
                                (*args, limit or -1)).fetchall()
        jobs = [_job(r) for r in rows]
        return jobs[::-1] if newest else jobs

    def count(self, states: Iterable[JobState] | None = None) -> int:
        """How many jobs there are (in ``states``)."""
        if self._pending:
            return len(self._pending_jobs(states))
        where, args = self._where(states)
        return int(self._db.execute(f"SELECT COUNT(*) FROM jobs{where}", args).fetchone()[0])

    @staticmethod
    def _where(states: Iterable[JobState] | None) -> tuple[str, tuple[str, ...]]:
        if states is None:
            return "", ()
        names = tuple(s.value for s in states)
        return f" WHERE state IN ({','.join('?' * len(names))})", names

    def first(self, state: JobState) -> Job | None:
        """The oldest job in ``state`` (the head of that queue)."""
        if self._pending:
            return next(iter(self._pending_jobs([state])), None)
        row = self._db.execute("SELECT * FROM jobs WHERE state = ? ORDER BY id LIMIT 1",
                               (state.value,)).fetchone()
        return None if row is None else _job(row)

    def transition(self, job_id: int, new: JobState, reason: str = "") -> Job:
        """Move a job to ``new`` (checked against the state machine) and log it."""
        job = self.get(job_id)
        check_transition(job.state, new)
        now = self._clock()
        sets = ["state = ?", "reason = ?", "updated_at = ?"]
        args: list[Any] = [new.value, reason, now]
        if new is JobState.PRINTING and job.started_at is None:
            sets.append("started_at = ?")
            args.append(now)
        if new in TERMINAL:
            sets.append("finished_at = ?")
            args.append(now)
        columns = dict(zip((s.split(" ")[0] for s in sets), args, strict=True))
        self._pending_history.append((job_id, now, job.state.value, new.value, reason))
        self._write(job_id, columns)
        return self.get(job_id)

    def update(self, job_id: int, **fields: Any) -> None:
        """Set some writable columns (one small transaction; JSON columns take dicts)."""
        bad = set(fields) - _WRITABLE
        if bad:
            raise StoreError(f"not writable: {', '.join(sorted(bad))}")
        self._write(job_id, {**fields, "updated_at": self._clock()})

    def _write(self, job_id: int, columns: dict[str, Any]) -> None:
        """Write ``columns`` of a job (and the history rows pending) in one transaction; if
        the disk refuses, keep them pending (see the module docstring)."""
        self._pending.setdefault(job_id, {}).update(columns)
        self.flush()

    def flush(self) -> bool:
        """Write everything pending, in one transaction; whether the disk took it (then
        :attr:`failure` is cleared), else :attr:`failure` names why."""
        if not (self._pending or self._pending_history or self._pending_settings):
            return True
        try:
            with self._db:
                for job_id, columns in self._pending.items():
                    self._update(job_id, columns)
                self._db.executemany("INSERT INTO history (job_id, at, old, new, reason)"
                                     " VALUES (?, ?, ?, ?, ?)", self._pending_history)
                for key, value in self._pending_settings.items():
                    self._put_setting(key, value)
        except _REFUSED as exc:
            self._failed(exc)
            return False
        self._pending.clear()
        self._pending_history.clear()
        self._pending_settings.clear()
        self.failure = None
        return True

    def _failed(self, exc: Exception) -> None:
        first = self.failure is None
        self.failure = f"job database {self.path}: {exc}"
        if first:
            self.on_failure()

    def _update(self, job_id: int, columns: dict[str, Any]) -> None:
        cols = list(columns)
        vals = [json.dumps(columns[c]) if c in _JSON_COLUMNS else columns[c] for c in cols]
        vals = [v.value if isinstance(v, JobState) else v for v in vals]
        sets = ", ".join(f"{c} = ?" for c in cols)
        self._db.execute(f"UPDATE jobs SET {sets} WHERE id = ?", (*vals, job_id))

    @contextlib.contextmanager
    def _refused(self, what: str) -> Iterator[None]:
        """A write that cannot wait: :class:`StorageError` when the disk refuses it, or
        while other writes are still pending (they go first)."""
        if self.failure is not None and not self.flush():
            raise StorageError(f"{what} cannot be stored: {self.failure}")
        try:
            yield
        except _REFUSED as exc:
            self._failed(exc)
            raise StorageError(f"{what} cannot be stored: {self.failure}") from None

    def delete(self, job_id: int) -> Job:
        """Remove a job that does not own the printer; returns the removed row."""
        job = self.get(job_id)
        if job.state in ACTIVE:
            raise StoreError(f"job {job_id} is {job.state}; cancel it first")
        with self._refused(f"the deletion of job {job_id}"), self._db:
            self._db.execute("DELETE FROM jobs WHERE id = ?", (job_id,))
        return job

    def setting(self, key: str) -> str | None:
        """A persisted daemon setting (the queue hold), ``None`` when unset."""
        if key in self._pending_settings:
            return self._pending_settings[key]
        row = self._db.execute("SELECT value FROM settings WHERE key = ?", (key,)).fetchone()
        return None if row is None else str(row[0])

    def set_setting(self, key: str, value: str | None) -> None:
        """Persist ``value`` under ``key`` (``None`` removes it; pending while the disk
        refuses writes)."""
        self._pending_settings[key] = value
        self.flush()

    def _put_setting(self, key: str, value: str | None) -> None:
        if value is None:
            self._db.execute("DELETE FROM settings WHERE key = ?", (key,))
        else:
            self._db.execute("INSERT INTO settings (key, value) VALUES (?, ?) ON CONFLICT(key)"
                             " DO UPDATE SET value = excluded.value", (key, value))

    def references(self, sha: str) -> int:
        """How many jobs use ``sha`` as upload or G-code."""
        row = self._db.execute("SELECT COUNT(*) FROM jobs WHERE upload_sha = ? OR gcode_sha = ?",
                               (sha, sha)).fetchone()
        return int(row[0])

    def history(self, job_id: int) -> builtins.list[dict[str, Any]]:
        rows = self._db.execute("SELECT at, old, new, reason FROM history WHERE job_id = ?"
                                " ORDER BY rowid", (job_id,)).fetchall()
        return [dict(r) for r in rows]

    def counts(self) -> dict[str, int]:
        """Number of jobs in every state (all states present, zeros included)."""
        out = {s.value: 0 for s in JobState}
        if self._pending:
            for job in self._pending_jobs(None):
                out[job.state.value] += 1
            return out
        for row in self._db.execute("SELECT state, COUNT(*) FROM jobs GROUP BY state"):
            out[row[0]] = int(row[1])
        return out

    def queue_length(self) -> int:
        names = [s.value for s in WAITING]
        row = self._db.execute(f"SELECT COUNT(*) FROM jobs WHERE state IN "
                               f"({','.join('?' * len(names))})", names).fetchone()
        return int(row[0])

    def recover(self) -> builtins.list[Job]:
        """After a restart: printing/paused jobs become ``interrupted``, slicing ``queued``.

        Returns the jobs that changed.
        """
        changed = []
        for job in self.list([JobState.PRINTING, JobState.PAUSED]):
            line = job.acked_lines
            changed.append(self.transition(
                job.id, JobState.INTERRUPTED,
                f"daemon stopped during the print at line {line}"
                f" (sub-part {job.subpart}, layer {job.layer})"))
        for job in self.list([JobState.SLICING]):
            changed.append(self.transition(job.id, JobState.QUEUED,
                                           "daemon stopped while slicing; re-queued"))
        return changed

    # -- checkpoints -----------------------------------------------------------------------

    def add_checkpoint(self, job_id: int, subpart: int, parent: int | None, a: float, c: float,
                       line: int, pose: dict[str, float] | None = None) -> Checkpoint:
        with self._refused(f"a checkpoint of job {job_id}"):
            cur = self._db.execute(
                "INSERT INTO checkpoints (job_id, at, subpart, parent, a, c, line, pose)"
                " VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (job_id, self._clock(), subpart, parent, a, c, line, json.dumps(pose or {})))
        row = self._db.execute("SELECT * FROM checkpoints WHERE seq = ?",
                               (cur.lastrowid,)).fetchone()
        return _checkpoint(row)

    def checkpoints(self, job_id: int) -> builtins.list[Checkpoint]:
        rows = self._db.execute("SELECT * FROM checkpoints WHERE job_id = ? ORDER BY seq",
                                (job_id,)).fetchall()
        return [_checkpoint(r) for r in rows]

    def last_checkpoint(self, job_id: int) -> Checkpoint | None:
        row = self._db.execute("SELECT * FROM checkpoints WHERE job_id = ? ORDER BY seq DESC"
                               " LIMIT 1", (job_id,)).fetchone()
        return None if row is None else _checkpoint(row)


def _job(row: sqlite3.Row) -> Job:
    d = dict(row)
    for c in _JSON_COLUMNS:
        d[c] = json.loads(d[c] or "{}")
    d["state"] = JobState(d["state"])
    d["allow_overhang"] = bool(d["allow_overhang"])
    return Job(**d)


def _checkpoint(row: sqlite3.Row) -> Checkpoint:
    d = dict(row)
    d["pose"] = json.loads(d["pose"] or "{}")
    return Checkpoint(**d)
