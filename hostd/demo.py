"""``make demo``: the main job end to end on the built-in emulator.

Starts ``hostd`` on ``sim://`` with a temporary state directory, runs
``hostctl print <branched pipe> --wait`` (live progress to the end), shows the job list and
stops the daemon with SIGTERM. The bundled three-branched pipe is sliced by the daemon's worker
when the slicing pipeline is installed; otherwise a pre-sliced synthetic three-branch G-code
(same markers: sub-parts, layers, transitions) is printed instead.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

from hostd.cli.main import main as hostctl

READY = "ready (socket"


def synthetic_gcode(subparts: int = 3, layers: int = 6, per_layer: int = 120) -> str:
    """A sliced-looking file: start script, sub-parts, layers, HOSTD transitions."""
    out = [';HOSTD_ESTIMATE {"filament_mm": 250.0, "time_s": 900.0}',
           "G28", "M140 S60", "M104 S210", "M190 S60", "M109 S210", "G90", "M83", "G92 E0"]
    for k in range(subparts):
        if k:
            a, c = 35.0, 120.0 * k
            out += [f';HOSTD_TRANSITION {{"from": 0, "to": {k}, "a": {a}, "c": {c}, '
                    '"x": 250.0, "y": 250.0, "z": 140.0}',
                    "G0 Z140 F3000", f"G0 A{a:g} C{c:g} F3000", "G0 X250 Y250 F6000",
                    ";HOSTD_TRANSITION_END"]
        out.append(f';HOSTD_SUBPART {{"index": {k}, "parent": {0 if k else "null"}}}')
        for layer in range(layers):
            out.append(f';HOSTD_LAYER {{"subpart": {k}, "index": {layer}}}')
            z = (140.0 if k else 100.0) + 0.2 * (layer + 1)
            for i in range(per_layer):
                out.append(f"G1 X{245 + (i % 10):g} Y{245 + (i % 9):g} Z{z:.1f} E0.04 F1800")
    out += ["M104 S0", "M140 S0", "M107", "G0 Z300 F3000", "G0 A0 C0 F3000", "M84"]
    return "\n".join(out) + "\n"


def sample_file(tmp: Path) -> Path:
    """The branched pipe as STL if the pipeline can slice it, else synthetic G-code."""
    try:
        import slicer.pipeline  # noqa: F401

        from slicer.samples import pipe3
    except ImportError:
        path = tmp / "pipe3-presliced.gcode"
        path.write_text(synthetic_gcode())
        print("demo: slicer.pipeline not available; printing a pre-sliced three-branch file")
        return path
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


def start_daemon(config: Path) -> subprocess.Popen[str]:
    proc = subprocess.Popen([sys.executable, "-m", "hostd.main", "--config", str(config)],
                            stderr=subprocess.PIPE, text=True)
    assert proc.stderr is not None
    for line in proc.stderr:
        sys.stderr.write(line)
        if READY in line:
            return proc
    raise SystemExit(f"demo: hostd exited with {proc.wait()}")


def main() -> int:
    with tempfile.TemporaryDirectory(prefix="hostd-demo-") as name:
        tmp = Path(name)
        config = write_config(tmp)
        sample = sample_file(tmp)
        print(f"demo: starting hostd on the emulator (state in {tmp})")
        proc = start_daemon(config)
        try:
            sock = str(tmp / "hostd.sock")
            print(f"demo: hostctl print {sample.name} --wait")
            rc = hostctl(["--socket", sock, "print", str(sample), "--wait"])
            hostctl(["--socket", sock, "jobs"])
        finally:
            proc.send_signal(signal.SIGTERM)
            assert proc.stderr is not None
            for line in proc.stderr:
                sys.stderr.write(line)
            proc.wait()
        print(f"demo: hostd stopped (exit {proc.returncode}); print exit status {rc}")
        return rc if proc.returncode == 0 else 1


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
