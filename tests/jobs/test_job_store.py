from __future__ import annotations

import errno
import hashlib
import os
import sqlite3
import threading

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hostd.jobs import JobNotFound, JobState, JobStateError, JobStore, Spool, SpoolError
from hostd.jobs.states import ALLOWED, TERMINAL, can_transition, check_transition
from hostd.jobs.store import SCHEMA_VERSION, StoreError

SHA = "a" * 64


@pytest.fixture
def store(tmp_path):
    s = JobStore(tmp_path / "jobs.db")
    yield s
    s.close()


def test_add_get_list_and_history(store):
    job = store.add("part.gcode", "gcode", SHA, gcode_sha=SHA)
    assert job.state is JobState.QUEUED and job.id == 1
    store.transition(job.id, JobState.READY, "g-code needs no slicing")
    store.transition(job.id, JobState.PRINTING)
    got = store.get(job.id)
    assert got.state is JobState.PRINTING and got.started_at is not None
    hist = [(h["old"], h["new"]) for h in store.history(job.id)]
    assert hist == [(None, "queued"), ("queued", "ready"), ("ready", "printing")]
    assert [j.id for j in store.list()] == [1]
    assert store.list([JobState.QUEUED]) == []


def test_illegal_transition_raises_and_changes_nothing(store):
    job = store.add("x.stl", "stl", SHA)
    with pytest.raises(JobStateError):
        store.transition(job.id, JobState.PAUSED)
    assert store.get(job.id).state is JobState.QUEUED
    assert len(store.history(job.id)) == 1


def test_terminal_states_have_no_exit():
    for s in TERMINAL:
        for t in JobState:
            assert not can_transition(s, t)
    assert {JobState.COMPLETED, JobState.FAILED, JobState.CANCELLED} == set(TERMINAL)


@given(st.lists(st.sampled_from(list(JobState)), max_size=12))
def test_state_machine_walk_follows_table(steps):
    state = JobState.QUEUED
    for nxt in steps:
        if nxt in ALLOWED[state]:
            check_transition(state, nxt)
            state = nxt
        else:
            with pytest.raises(JobStateError):
                check_transition(state, nxt)


def test_progress_json_columns_and_checkpoints(store):
    job = store.add("x.gcode", "gcode", SHA, estimate={"time_s": 12.0})
    store.update(job.id, acked_lines=10, total_lines=40, subpart=1, layer=3,
                 modal={"X": 1.0, "absolute": True})
    got = store.get(job.id)
    assert got.to_dict()["progress"] == 0.25 and got.modal["X"] == 1.0
    assert got.estimate == {"time_s": 12.0}
    store.add_checkpoint(job.id, 1, 0, 30.0, 90.0, 17, {"x": 1.0, "y": 2.0, "z": 3.0})
    store.add_checkpoint(job.id, 2, 0, 45.0, 180.0, 33)
    cp = store.last_checkpoint(job.id)
    assert cp is not None and (cp.subpart, cp.a, cp.c, cp.line) == (2, 45.0, 180.0, 33)
    assert [c.subpart for c in store.checkpoints(job.id)] == [1, 2]


def test_recover_marks_printing_interrupted_and_requeues_slicing(tmp_path):
    path = tmp_path / "jobs.db"
    s = JobStore(path)
    a = s.add("a.gcode", "gcode", SHA)
    b = s.add("b.stl", "stl", SHA)
    c = s.add("c.gcode", "gcode", SHA)
    s.transition(a.id, JobState.READY)
    s.transition(a.id, JobState.PRINTING)
    s.update(a.id, acked_lines=123, subpart=2, layer=7)
    s.transition(b.id, JobState.SLICING)
    # no close: simulate a crash; a new connection must see every committed write
    s2 = JobStore(path)
    changed = {j.id: j.state for j in s2.recover()}
    assert changed == {a.id: JobState.INTERRUPTED, b.id: JobState.QUEUED}
    got = s2.get(a.id)
    assert got.acked_lines == 123 and "line 123" in got.reason
    assert s2.get(c.id).state is JobState.QUEUED
    s.close()
    s2.close()


def test_delete_refuses_active_job(store):
    job = store.add("a.gcode", "gcode", SHA)
    store.transition(job.id, JobState.READY)
    store.transition(job.id, JobState.PRINTING)
    with pytest.raises(Exception, match="cancel it first"):
        store.delete(job.id)
    store.transition(job.id, JobState.CANCELLED, "operator")
    store.delete(job.id)
    with pytest.raises(JobNotFound):
        store.get(job.id)


def test_wal_mode_and_schema_version(tmp_path):
    path = tmp_path / "jobs.db"
    JobStore(path).close()
    db = sqlite3.connect(path)
    assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert db.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION == 2
    db.execute("PRAGMA user_version=99")
    db.close()
    with pytest.raises(Exception, match="schema 99"):
        JobStore(path)


# the jobs table as version 1 of the schema made it (before allow_overhang, slice_options)
V1_JOBS = """CREATE TABLE jobs (
    id INTEGER PRIMARY KEY AUTOINCREMENT, name TEXT NOT NULL,
    kind TEXT NOT NULL CHECK (kind IN ('stl', 'gcode')), upload_sha TEXT NOT NULL,
    gcode_sha TEXT, state TEXT NOT NULL, reason TEXT NOT NULL DEFAULT '',
    created_at REAL NOT NULL, updated_at REAL NOT NULL, started_at REAL, finished_at REAL,
    total_lines INTEGER NOT NULL DEFAULT 0, acked_lines INTEGER NOT NULL DEFAULT 0,
    subpart INTEGER, layer INTEGER, filament_mm REAL NOT NULL DEFAULT 0,
    print_seconds REAL NOT NULL DEFAULT 0, modal TEXT NOT NULL DEFAULT '{}',
    estimate TEXT NOT NULL DEFAULT '{}', info TEXT NOT NULL DEFAULT '{}',
    resume TEXT NOT NULL DEFAULT '{}')"""


def test_a_version_1_database_is_migrated_and_its_jobs_kept(tmp_path):
    path = tmp_path / "jobs.db"
    db = sqlite3.connect(path)
    db.execute(V1_JOBS)
    db.execute("INSERT INTO jobs (name, kind, upload_sha, state, reason, created_at, "
               "updated_at, acked_lines) VALUES ('old.stl', 'stl', ?, 'completed', 'done', "
               "1.0, 2.0, 42)", (SHA,))
    db.execute("PRAGMA user_version=1")
    db.commit()
    db.close()
    store = JobStore(path)
    old = store.get(1)
    assert (old.name, old.state, old.reason, old.acked_lines) == ("old.stl",
                                                                  JobState.COMPLETED, "done", 42)
    assert old.allow_overhang is False and old.slice_options == {}
    new = store.add("new.stl", "stl", SHA, allow_overhang=True, slice_options={"seed": 3})
    store.close()
    again = JobStore(path)  # opened once more: version 2 now, nothing to migrate
    assert again.get(new.id).allow_overhang is True
    assert again.get(new.id).slice_options == {"seed": 3}
    assert again.get(new.id).to_dict()["allow_overhang"] is True
    again.close()
    assert sqlite3.connect(path).execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION


def test_counts_and_queue_length(store):
    for i in range(3):
        store.add(f"{i}.gcode", "gcode", SHA)
    store.transition(1, JobState.CANCELLED)
    assert store.counts()["queued"] == 2 and store.counts()["cancelled"] == 1
    assert store.queue_length() == 2


@settings(max_examples=40, deadline=None)
@given(n=st.integers(0, 12), limit=st.integers(0, 14), cancelled=st.sets(st.integers(1, 12)))
def test_list_takes_the_oldest_or_newest_jobs_in_id_order(tmp_path_factory, n, limit,
                                                          cancelled):
    store = JobStore(tmp_path_factory.mktemp("list") / "jobs.db")
    for i in range(n):
        store.add(f"{i}.gcode", "gcode", SHA)
    for job_id in sorted(c for c in cancelled if c <= n):
        store.transition(job_id, JobState.CANCELLED)
    for states in (None, [JobState.CANCELLED], [JobState.QUEUED, JobState.CANCELLED]):
        ids = [j.id for j in store.list(states, 0)]
        assert ids == sorted(ids) and store.count(states) == len(ids)
        assert [j.id for j in store.list(states, limit)] == ids[:limit or None]
        assert [j.id for j in store.list(states, limit, newest=True)] == (
            ids[-limit:] if limit else ids)
    store.close()


def test_spool_content_addressed(tmp_path):
    sp = Spool(tmp_path / "spool", max_bytes=2048)
    data = b"G1 X1\n"
    digest = sp.put(data, ".gcode")
    assert digest == hashlib.sha256(data).hexdigest()
    assert sp.put(data, ".gcode") == digest
    assert sp.read(digest, ".gcode") == data
    assert sp.usage() == {"files": 1, "bytes": len(data)}
    with pytest.raises(SpoolError, match="empty"):
        sp.put(b"", ".gcode")
    with pytest.raises(SpoolError, match="exceeds"):
        sp.put(b"x" * 2049, ".gcode")
    with pytest.raises(SpoolError, match="bad spool name"):
        sp.path("../../etc/passwd", ".gcode")
    sp.remove(digest, ".gcode")
    with pytest.raises(SpoolError, match="missing"):
        sp.read(digest, ".gcode")


@settings(max_examples=50, deadline=None)
@given(st.lists(st.binary(max_size=300), max_size=8), st.booleans())
def test_a_staged_upload_is_stored_whole_or_not_at_all(tmp_path_factory, parts, keep):
    """Written in parts and committed, it is what one put stores; discarded, or refused when
    empty, it leaves nothing; the temporary file is gone either way."""
    sp = Spool(tmp_path_factory.mktemp("spool"), max_bytes=1200)
    data = b"".join(parts)
    staged = sp.stage()
    try:
        for part in parts:
            staged.write(part)
    except SpoolError as exc:
        assert len(data) > 1200 and "exceeds the limit of 1200 bytes" in str(exc)
    else:
        assert staged.size == len(data)
        if keep and data:
            digest = sp.commit(staged, ".gcode")
            assert digest == hashlib.sha256(data).hexdigest()
            assert sp.read(digest, ".gcode") == data
        elif keep:
            with pytest.raises(SpoolError, match="empty"):
                sp.commit(staged, ".gcode")
    staged.discard()
    assert not staged.path.exists()
    stored = 1 if keep and data and len(data) <= 1200 else 0
    assert sp.usage()["files"] == stored
    assert sorted(p.name for p in sp.root.iterdir() if p.name.startswith(".")) == []


def test_a_restart_clears_what_a_killed_daemon_left_staged(tmp_path):
    sp = Spool(tmp_path / "spool", max_bytes=2048)
    staged = sp.stage()
    staged.write(b"G1 X1\n")  # the daemon is killed here
    digest = sp.put(b"G28\n", ".gcode")
    sp = Spool(tmp_path / "spool", max_bytes=2048)
    assert not staged.path.exists()
    assert sp.read(digest, ".gcode") == b"G28\n"


class FullDisk:
    """A file on a disk with no room left."""

    def write(self, data: bytes) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def close(self) -> None:
        pass


def test_a_full_disk_is_a_refusal_naming_it_and_leaves_nothing(tmp_path):
    sp = Spool(tmp_path / "spool", max_bytes=2048)
    staged = sp.stage()
    staged._fh.close()
    staged._fh = FullDisk()  # type: ignore[assignment]
    with pytest.raises(SpoolError, match="cannot store the upload: No space left on device"):
        staged.write(b"G28\n")
    staged.discard()
    assert list(sp.root.iterdir()) == []


def _progress(store: JobStore, job_id: int, count: int, start: int = 0) -> None:
    for n in range(start, start + count):
        store.update(job_id, acked_lines=n, layer=n // 10, modal={"position": {"X": n / 10}})


def test_commits_leave_the_log_to_the_checkpoint(tmp_path):
    """No commit copies the write-ahead log back (SQLite's own checkpoint would, at 1000
    pages, inside a commit on the event loop): the log holds every write until checkpoint()
    copies it all, and then starts afresh."""
    store = JobStore(tmp_path / "jobs.db")
    job = store.add("part.gcode", "gcode", SHA, gcode_sha=SHA)
    _progress(store, job.id, 1500)
    frames, copied = store.checkpoint()
    assert frames >= 1500 and copied == frames
    _progress(store, job.id, 10, start=1500)
    frames, copied = store.checkpoint()
    assert 10 <= frames < 100 and copied == frames  # the log restarted after the copy
    store.close()
    assert JobStore(tmp_path / "jobs.db").get(job.id).acked_lines == 1509


def test_a_checkpoint_is_claimed_once_per_batch_of_writes(tmp_path):
    store = JobStore(tmp_path / "jobs.db", checkpoint_changes=50)
    job = store.add("part.gcode", "gcode", SHA, gcode_sha=SHA)
    claims = []
    for n in range(200):
        _progress(store, job.id, 1, start=n)
        claims.append(store.claim_checkpoint())
    # the add wrote two rows (the job and its history), then one row per update
    assert [n for n, claimed in enumerate(claims) if claimed] == [47, 97, 147, 197]
    assert JobStore(":memory:").checkpoint() == (0, 0)
    store.close()


def test_a_checkpoint_on_another_thread_loses_no_write(tmp_path):
    """The checkpoint uses a connection of its own, so it runs on a worker thread while the
    store's connection writes on; every write is there afterwards."""
    store = JobStore(tmp_path / "jobs.db")
    job = store.add("part.gcode", "gcode", SHA, gcode_sha=SHA)
    done: list[tuple[int, int]] = []
    errors: list[BaseException] = []

    def checkpoints() -> None:
        try:
            for _ in range(20):
                done.append(store.checkpoint())
        except BaseException as exc:  # reported by the assertion below
            errors.append(exc)

    worker = threading.Thread(target=checkpoints)
    worker.start()
    _progress(store, job.id, 2000)
    worker.join(timeout=60)
    assert not worker.is_alive() and errors == [] and len(done) == 20
    store.close()
    reopened = JobStore(tmp_path / "jobs.db")
    assert reopened.get(job.id).acked_lines == 1999
    frames, copied = reopened.checkpoint()
    assert copied == frames  # no lock or reader was left behind
    reopened.close()


def test_a_failed_checkpoint_is_a_store_error(tmp_path):
    store = JobStore(tmp_path / "jobs.db")
    store.path = str(tmp_path / "missing" / "jobs.db")  # cannot be opened
    with pytest.raises(StoreError, match="checkpoint failed"):
        store.checkpoint()
    store.close()
