"""``make demo``: the main job end to end on the built-in emulator.

Starts ``hostd`` on ``sim://`` with a temporary state directory, runs
``hostctl print <branched pipe> --wait`` (live progress to the end), shows the job list and
stops the daemon with SIGTERM. The bundled three-branched pipe is uploaded as STL and sliced by
the daemon's worker process (decomposition, five-axis slicing, replay check) before it prints.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import yaml

from hostd.cli.main import main as hostctl

READY = "ready (socket"


def sample_file(tmp: Path) -> Path:
    """The bundled three-branched pipe as an STL file; the daemon's worker slices it."""
    from slicer.mesh import pipe3

    path = tmp / "pipe3.stl"
    pipe3().export(path)
    return path


def write_config(tmp: Path) -> Path:
    cfg = {
        "daemon": {"socket": str(tmp / "hostd.sock"), "state_dir": str(tmp / "state"),
                   "log_level": "info"},
        "metrics": {"enabled": False},
        "serial": {"port": "sim://", "baud": 250000},
        "sim": {"throttle": False},  # as fast as the host streams: a watchable demo
        "process": {"layer_height": 0.3, "infill_density": 0.1},
    }
    path = tmp / "hostd.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def start_daemon(config: Path) -> tuple[subprocess.Popen[str], threading.Thread, list[str]]:
    """hostd, once ready; its log from then on is collected by a thread (a pipe left unread
    would stop the daemon at its first 64 KB of log) and shown when it stops."""
    proc = subprocess.Popen([sys.executable, "-m", "hostd.main", "--config", str(config)],
                            stderr=subprocess.PIPE, text=True)
    assert proc.stderr is not None
    for line in proc.stderr:
        sys.stderr.write(line)
        if READY in line:
            log: list[str] = []
            reader = threading.Thread(target=log.extend, args=(proc.stderr,), daemon=True)
            reader.start()
            return proc, reader, log
    raise SystemExit(f"demo: hostd exited with {proc.wait()}")


def main() -> int:
    with tempfile.TemporaryDirectory(prefix="hostd-demo-") as name:
        tmp = Path(name)
        config = write_config(tmp)
        sample = sample_file(tmp)
        print(f"demo: starting hostd on the emulator (state in {tmp})")
        proc, reader, log = start_daemon(config)
        try:
            sock = str(tmp / "hostd.sock")
            print(f"demo: hostctl print {sample.name} --wait")
            rc = hostctl(["--socket", sock, "print", str(sample), "--wait"])
            hostctl(["--socket", sock, "jobs"])
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait()
            reader.join()
            sys.stderr.write("demo: hostd's log while it ran:\n" + "".join(log))
        print(f"demo: hostd stopped (exit {proc.returncode}); print exit status {rc}")
        return rc if proc.returncode == 0 else 1


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
