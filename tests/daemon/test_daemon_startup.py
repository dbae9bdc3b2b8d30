"""hostd at start and under its watchdog: a state directory it cannot use is one line naming
it (exit 1); a dead task withholds the watchdog ping, and the log names what killed it."""

from __future__ import annotations

import asyncio
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.timeout(60)
@pytest.mark.parametrize(("state_dir", "blocked"), [
    ("state", "state/spool"), ("state", "state/cache"),  # the directories hostd makes in it
    ("state", "state"),  # the state directory itself
    ("file/state", "file"),  # a directory above it
])
def test_a_file_where_a_state_directory_belongs_is_a_one_line_error(
        tmp_path: Path, state_dir: str, blocked: str):
    (tmp_path / blocked).parent.mkdir(parents=True, exist_ok=True)
    (tmp_path / blocked).write_text("not a directory")
    config = tmp_path / "hostd.yaml"
    config.write_text(yaml.safe_dump({
        "daemon": {"socket": str(tmp_path / "hostd.sock"),
                   "state_dir": str(tmp_path / state_dir)},
        "metrics": {"enabled": False}, "serial": {"port": "sim://"}}))
    done = subprocess.run([sys.executable, "-m", "hostd.main", "--config", str(config)],
                          cwd=ROOT, capture_output=True, text=True, timeout=50, check=False)
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr
    errors = [line for line in done.stderr.splitlines() if "ERROR" in line]
    assert len(errors) == 1
    where = "" if blocked == state_dir else f"cannot use {tmp_path / state_dir}: "
    assert errors[0].endswith(f"daemon.state_dir: {where}{tmp_path / blocked} is a file, "
                              "not a directory")
    assert not (tmp_path / "hostd.sock").exists()


class Loops:
    """Stands in for the job manager: its loops alive or not."""

    def __init__(self, tasks: list[asyncio.Task[None]]) -> None:
        self._tasks = tasks

    def alive(self) -> bool:
        return not any(t.done() for t in self._tasks)

    def tasks(self) -> list[asyncio.Task[None]]:
        return self._tasks


async def _fails() -> None:
    raise RuntimeError("loop broke")


async def _returns() -> None:
    return None


@pytest.mark.asyncio
@pytest.mark.timeout(30)
async def test_the_watchdog_is_withheld_naming_what_killed_a_task(tmp_path: Path):
    from hostd.config.loader import defaults
    from hostd.daemon import Daemon

    daemon = Daemon(defaults())
    forever = asyncio.Event()
    running = asyncio.create_task(forever.wait(), name="temps")
    linked = asyncio.create_task(_returns(), name="link")  # connected: its work is done
    daemon._tasks = [running, linked]
    daemon._jobs = Loops([asyncio.create_task(forever.wait(), name="print-loop")])  # type: ignore[assignment]
    await asyncio.gather(linked)
    assert daemon.healthy() and daemon.dead_tasks() == []
    broken = asyncio.create_task(_fails(), name="slice-loop")
    await asyncio.gather(broken, return_exceptions=True)
    daemon._jobs = Loops([broken])  # type: ignore[assignment]
    assert not daemon.healthy()
    assert daemon.dead_tasks() == ["slice-loop: RuntimeError('loop broke')"]
    running.cancel()
    await asyncio.gather(running, return_exceptions=True)
    assert daemon.dead_tasks() == ["temps: cancelled", "slice-loop: RuntimeError('loop broke')"]


class _Link:
    """Stands in for the serial link: connected already, counting connect calls."""

    def __init__(self) -> None:
        from hostd.link.settings import LinkSettings

        self.settings = LinkSettings(reconnect_min=0.01, reconnect_max=0.01)
        self.connected = True
        self.connects = 0

    async def connect(self) -> None:
        self.connects += 1


@pytest.mark.asyncio
@pytest.mark.timeout(30)
async def test_the_link_supervisor_does_not_reset_a_link_a_restart_connected():
    """The first connection failed and the supervisor retries; meanwhile the operator's
    firmware-restart connected the link. The supervisor must not connect (reset the board)
    a second time, maybe under a job that has started since."""
    from hostd.config.loader import defaults
    from hostd.daemon import Daemon

    daemon = Daemon(defaults())
    link = _Link()
    daemon.link = link  # type: ignore[assignment]
    async with asyncio.timeout(10):
        await daemon._link_supervisor()
    assert link.connects == 0


def _run_hostd(tmp_path: Path, socket: str) -> subprocess.CompletedProcess[str]:
    config = tmp_path / "hostd.yaml"
    config.write_text(yaml.safe_dump({
        "daemon": {"socket": socket, "state_dir": str(tmp_path / "state")},
        "metrics": {"enabled": False}, "serial": {"port": "sim://"}}))
    return subprocess.run([sys.executable, "-m", "hostd.main", "--config", str(config)],
                          cwd=ROOT, capture_output=True, text=True, timeout=50, check=False)


@pytest.mark.timeout(60)
def test_a_socket_path_under_a_regular_file_is_a_one_line_error(tmp_path: Path):
    (tmp_path / "afile").write_text("a file, not a directory")
    sock = tmp_path / "afile" / "h.sock"
    done = _run_hostd(tmp_path, str(sock))
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr
    errors = [line for line in done.stderr.splitlines() if "ERROR" in line]
    assert len(errors) == 1, done.stderr
    assert str(sock) in errors[0] and f"{tmp_path / 'afile'} is not a directory" in errors[0]


@pytest.mark.timeout(60)
@pytest.mark.parametrize("socket", ["", "   ", "/tmp/" + "s" * 120 + ".sock"])
def test_an_empty_or_too_long_socket_path_is_refused_at_config_load(tmp_path: Path,
                                                                    socket: str):
    done = _run_hostd(tmp_path, socket)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "daemon.socket" in lines[0], done.stderr
    assert "must not be empty" in lines[0] if not socket.strip() else "bytes long" in lines[0]


@pytest.mark.timeout(60)
def test_a_metrics_port_in_use_is_a_one_line_start_error(tmp_path: Path):
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        config = tmp_path / "hostd.yaml"
        config.write_text(yaml.safe_dump({
            "daemon": {"socket": str(tmp_path / "hostd.sock"),
                       "state_dir": str(tmp_path / "state")},
            "metrics": {"enabled": True, "host": "127.0.0.1", "port": port},
            "serial": {"port": "sim://"}}))
        done = subprocess.run([sys.executable, "-m", "hostd.main", "--config", str(config)],
                              cwd=ROOT, capture_output=True, text=True, timeout=50,
                              check=False)
    assert done.returncode == 1, done.stderr  # before: it ran on without metrics
    assert "Traceback" not in done.stderr
    errors = [line for line in done.stderr.splitlines() if "ERROR" in line]
    assert len(errors) == 1 and "metrics.port" in errors[0] and str(port) in errors[0], errors
    assert not (tmp_path / "hostd.sock").exists()


@pytest.mark.asyncio
@pytest.mark.timeout(60)
async def test_a_job_a_crash_left_printing_is_interrupted_before_the_socket_opens(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """After a crash the job database still says ``printing``; a client that connects as
    soon as the socket opens must see the job interrupted, never a dead job printing."""
    from hostd.config.loader import defaults
    from hostd.control.server import ControlServer
    from hostd.daemon import Daemon
    from hostd.jobs.states import JobState
    from hostd.jobs.store import JobStore

    state = tmp_path / "state"
    state.mkdir()
    store = JobStore(state / "jobs.db")
    job = store.add("part.gcode", "gcode", "0" * 64, gcode_sha="0" * 64)
    for s in (JobState.READY, JobState.PRINTING):
        store.transition(job.id, s)
    store.update(job.id, acked_lines=120)
    store.close()
    seen: list[str] = []
    opened = ControlServer.start

    async def start(self: ControlServer, *args: object) -> None:
        seen.append(daemon.store.get(job.id).state.value)  # what the first client would see
        await opened(self, *args)  # type: ignore[arg-type]

    monkeypatch.setattr(ControlServer, "start", start)
    daemon = Daemon(defaults().replace(daemon__socket=str(tmp_path / "hostd.sock"),
                                       daemon__state_dir=str(state), metrics__enabled=False))
    try:
        async with asyncio.timeout(30):
            await daemon.start()
    finally:
        await daemon.close()
    assert seen == ["interrupted"]
