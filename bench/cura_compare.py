"""``hostctl slice`` against CuraEngine on the hard models: time, filament, print time, lines.

Run: ``.venv/bin/python bench/cura_compare.py [--models pipe3_15 tee_low ...] [--faces 50000]
[--height 0.2] [--repeat 1] [--no-double] [--definitions DIR] [--keep DIR]``.

Each model of ``../shared/models/hard`` is made :func:`harness.finer` to ``--faces`` faces
(and to twice that for the doubling cost) and written as an STL; then, in the same run and
alternately, whole processes slice it: ``hostctl slice MODEL.stl --layer-height H
--allow-overhang`` (the default config; a file with walls over air is written, not refused,
and its warning shown) and CuraEngine 4.13 without and with normal supports, on a printer
definition of this project's (``bench/cura/hostd.def.json``, over Cura's own
``fdmprinter.def.json``) and settings that match the default ``process`` section (line
width, walls, skins, infill spacing and angle, speeds, retraction and hop; no skirt, no
minimum layer time). CuraEngine reads the definitions' default values only (it does not
evaluate their formulas), so every setting that a formula derives in Cura is given here.

Printed per model: wall and CPU seconds of each process (CPU: user + system of the process
and its waited-for children: our layer workers, Cura's threads) and their ratios; filament
(mm) and print time of the three files, all three by one estimator
(:func:`slicer.gcode.estimate.estimate_moves`, the time model of our ``;HOSTD_ESTIMATE``,
with the default machine limits; ours includes its rotate/return moves and transitions),
and the ratios of ours to Cura's without and with supports; the files' command lines and
lines per minute of print time (with the share of a 115200-baud wire those lines need at
the framing of ``hostd``'s link, ``N<n> ... *<cs>``); the doubling cost, our slice's wall
and CPU time at twice the faces over the time at ``--faces``; our per-stage seconds (the
``seconds …`` line of ``hostctl slice``) and the seconds of its total that no stage lists
(:func:`unlisted`).

CuraEngine: Debian's package ``cura-engine`` (``apt-get install cura-engine``). Its
definitions come with Debian's ``cura`` package: found in ``--definitions DIR``, in
``$CURA_ENGINE_SEARCH_PATH``, in ``/usr/share/cura/resources/definitions`` (``apt-get install
cura``) or in ``.cache/cura`` of this checkout; where none has them, the bench fetches the
package without its GUI dependencies (``apt-get download cura && dpkg -x cura_*.deb
.cache/cura``, printing the commands) and reads them from
``.cache/cura/usr/share/cura/resources/definitions``. No test asserts a time: this prints
figures.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from cli_slice import children_cpu, hostctl
from harness import HARD, finer, hard_model

from slicer.gcode import MotionLimits, estimate_moves, filament_area, read_gcode
from slicer.settings import ProcessSettings

HERE = Path(__file__).resolve().parent
DEFINITION = HERE / "cura" / "hostd.def.json"
FOLDER = "usr/share/cura/resources/definitions"  # in Debian's cura package
SEARCH = (Path("/") / FOLDER,)
CACHE = HERE.parent / ".cache" / "cura"  # where the bench unpacks the package
MODELS = ("pipe3_15", "tee_low", "pipe2_25", "down15", "ytree_20", "elbow1", "arms3")
BAUD = 115200
DENSITY = 1.24e-3  # g/mm³, PLA (the estimate's mass only)


@dataclass
class Run:
    """One slicing process: its seconds, its file's figures, or why it failed."""

    wall: float = math.nan
    cpu: float = math.nan
    filament: float = math.nan  # mm of filament
    time_s: float = math.nan  # estimated print time
    lines: int = 0  # command lines
    wire: float = math.nan  # bytes/s of framed lines over the print time
    note: str = ""
    stages: str = ""  # ours: the ``seconds …`` line of ``hostctl slice``

    @property
    def ok(self) -> bool:
        """The process wrote a file."""
        return not math.isnan(self.time_s)


@dataclass
class Case:
    """One model's runs: ours and Cura's without / with supports, at both face counts."""

    name: str
    faces: int
    runs: dict[str, list[Run]] = field(default_factory=dict)

    def add(self, kind: str, run: Run) -> None:
        self.runs.setdefault(kind, []).append(run)

    def best(self, kind: str) -> Run:
        """The run of ``kind`` with the least CPU time (the steadiest figure here)."""
        runs = self.runs.get(kind) or [Run(note="not run")]
        done = [r for r in runs if not math.isnan(r.cpu)]
        return min(done, key=lambda r: r.cpu) if done else runs[-1]


def definitions(given: str | None) -> Path:
    """The folder holding Cura's ``fdmprinter.def.json``: found, or fetched into ``CACHE``."""
    places = [Path(given)] if given else [
        *(Path(p) for p in os.environ.get("CURA_ENGINE_SEARCH_PATH", "").split(":") if p),
        *SEARCH, CACHE / FOLDER]
    for place in places:
        if (place / "fdmprinter.def.json").is_file():
            return place
    if given:
        sys.exit(f"cura_compare: no fdmprinter.def.json in {given}")
    return fetch_definitions()


def fetch_definitions() -> Path:
    """Debian's ``cura`` package unpacked into ``CACHE`` (no GUI dependencies installed)."""
    CACHE.mkdir(parents=True, exist_ok=True)
    for cmd in (["apt-get", "download", "cura"], ["sh", "-c", "dpkg -x cura_*.deb ."]):
        print(f"cura_compare: no Cura definitions found; in {CACHE}: {' '.join(cmd)}",
              flush=True)
        if subprocess.run(cmd, cwd=CACHE, check=False).returncode != 0:
            sys.exit("cura_compare: could not fetch Cura's definitions: apt-get install cura "
                     "(or --definitions DIR, the folder of fdmprinter.def.json)")
    return CACHE / FOLDER


def cura_engine() -> str:
    """The CuraEngine executable, or exit saying how to install it."""
    found = shutil.which("CuraEngine")
    if found is None:
        sys.exit("cura_compare: no CuraEngine on PATH: apt-get install cura-engine")
    return found


def cura_settings(s: ProcessSettings, support: bool) -> dict[str, str]:
    """CuraEngine settings matching the process ``s`` (every derived one given)."""
    w, h = s.line_width, s.layer_height
    skins = max(s.solid_layers, math.ceil(round(s.min_shell_thickness / h, 4)))
    widths = ("line_width", "wall_line_width", "wall_line_width_0", "wall_line_width_x",
              "skin_line_width", "infill_line_width", "support_line_width",
              "support_interface_line_width", "support_roof_line_width",
              "support_bottom_line_width", "skirt_brim_line_width", "roofing_line_width")
    speeds = {"speed_print": s.print_speed, "speed_infill": s.print_speed,
              "speed_wall": s.perimeter_speed, "speed_wall_0": s.perimeter_speed,
              "speed_wall_x": s.perimeter_speed, "speed_topbottom": s.print_speed,
              "speed_roofing": s.print_speed, "speed_support": s.print_speed,
              "speed_support_infill": s.print_speed, "speed_support_interface": s.print_speed,
              "speed_support_roof": s.print_speed, "speed_support_bottom": s.print_speed,
              "speed_travel": s.travel_speed, "speed_layer_0": s.first_layer_speed,
              "speed_print_layer_0": s.first_layer_speed,
              "speed_travel_layer_0": s.travel_speed}
    spacing = w / s.infill_density if s.infill_density > 0 else 0.0
    out = {"layer_height": h, "layer_height_0": h, "machine_nozzle_size": s.nozzle_diameter,
           "material_diameter": s.filament_diameter, "wall_line_count": s.perimeters,
           "top_layers": skins, "bottom_layers": skins,
           "infill_sparse_density": 100 * s.infill_density, "infill_pattern": "lines",
           "infill_line_distance": spacing, "infill_overlap_mm": 0.5 * w * 0.15 * 2,
           "skin_overlap_mm": 0.5 * w * 0.15 * 2, "speed_slowdown_layers": 1,
           "retraction_amount": s.retract_length, "retraction_speed": s.retract_speed,
           "retraction_retract_speed": s.retract_speed,
           "retraction_prime_speed": s.retract_speed,
           "retraction_hop_enabled": "true" if s.z_hop > 0 else "false",
           "retraction_hop": s.z_hop, "material_print_temperature": s.nozzle_temperature,
           "material_print_temperature_layer_0": s.nozzle_temperature,
           "material_initial_print_temperature": s.nozzle_temperature,
           "material_final_print_temperature": s.nozzle_temperature,
           "material_bed_temperature": s.bed_temperature,
           "material_bed_temperature_layer_0": s.bed_temperature,
           "adhesion_type": "none", "cool_min_layer_time": 0,
           **{k: w for k in widths}, **speeds,
           "support_enable": "true" if support else "false", "support_structure": "normal",
           "support_type": "everywhere", "support_pattern": "zigzag",
           "support_infill_rate": 15, "support_line_distance": 100 * w / 15,
           "support_initial_layer_line_distance": 100 * w / 15,
           "support_z_distance": h, "support_top_distance": h, "support_bottom_distance": h,
           "support_wall_count": 0}
    return {k: f"{v:g}" if isinstance(v, float | int) else str(v) for k, v in out.items()}


def command_lines(path: Path) -> tuple[int, int]:
    """(command lines, their bytes framed as the link sends them) of a G-code file."""
    count = size = number = 0
    with path.open(encoding="utf-8") as f:
        for raw in f:
            body = raw.split(";", 1)[0].strip()
            if body:
                count += 1
                number += 1
                size += len(body) + len(str(number)) + 6  # "N<n> " + "*<cs>" + newline
    return count, size


def figures(path: Path, limits: MotionLimits, area: float) -> Run:
    """The estimate and line figures of a written file (seconds left unset)."""
    parsed = read_gcode(path)
    est = estimate_moves(parsed.start, parsed.end, parsed.feed, parsed.e, parsed.g, limits,
                         area, DENSITY)
    lines, size = command_lines(path)
    return Run(filament=est.filament_mm, time_s=est.time_s, lines=lines,
               wire=size / est.time_s if est.time_s > 0 else math.nan)


def timed(cmd: list[str], env: dict[str, str] | None = None
          ) -> tuple[float, float, subprocess.CompletedProcess[str]]:
    """(wall s, CPU s with children, the finished process) of one command."""
    cpu, wall = children_cpu(), time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, check=False, env=env)
    return time.perf_counter() - wall, children_cpu() - cpu, done


def ours(stl: Path, out: Path, s: ProcessSettings, limits: MotionLimits) -> Run:
    """``hostctl slice`` of ``stl`` (walls over air allowed), timed, with its figures."""
    wall, cpu, done = timed([*hostctl(), "slice", str(stl), "-o", str(out), "--layer-height",
                             f"{s.layer_height:g}", "--allow-overhang"])
    if done.returncode != 0 or not out.exists():
        last = (done.stderr.strip() or done.stdout.strip()).splitlines()
        return Run(wall, cpu, note=f"refused: {last[-1][:140] if last else done.returncode}")
    run = figures(out, limits, filament_area(s))
    run.wall, run.cpu, run.note = wall, cpu, wall_note(done.stdout)
    run.stages = next((ln for ln in done.stdout.splitlines() if ln.startswith("seconds ")), "")
    return run


WALL_FIGURES = re.compile(r"(\d+) unsupported wall layers?, (\d+) over air")


def wall_note(stdout: str) -> str:
    """What the replay line of ``hostctl slice`` says of the walls: ``N wall layers over
    air``, ``N unsupported wall layers (bridging sparse infill)``, or nothing when every
    wall layer holds."""
    found = WALL_FIGURES.search(stdout)
    if found is None:
        return "no replay figures"
    bad, air = int(found[1]), int(found[2])
    if air:
        return f"{air} wall layers over air"
    return f"{bad} unsupported wall layers (bridging sparse infill)" if bad else ""


def cura(stl: Path, out: Path, s: ProcessSettings, limits: MotionLimits, defs: Path,
         support: bool) -> Run:
    """CuraEngine on ``stl`` (with normal supports or none), timed, with its figures."""
    pairs = [a for k, v in cura_settings(s, support).items() for a in ("-s", f"{k}={v}")]
    cmd = [cura_engine(), "slice", "-j", str(DEFINITION), *pairs, "-e0", *pairs,
           "-l", str(stl), "-o", str(out)]
    env = {**os.environ, "CURA_ENGINE_SEARCH_PATH": str(defs)}
    wall, cpu, done = timed(cmd, env)
    if done.returncode != 0 or not out.exists():
        return Run(wall, cpu, note=f"CuraEngine failed ({done.returncode})")
    run = figures(out, limits, filament_area(s))
    run.wall, run.cpu = wall, cpu
    return run


def unlisted(line: str) -> float:
    """Seconds of a ``seconds T (stage t, …)`` line that no stage lists.

    The stages' sum leaves out the text (formatted beside the replay) and the repair's count
    of rounds; what remains of the total is the load and plan of a slice whose kept try is a
    repair round's (its timings start at the G-code), else rounding. When another
    decomposition's try is kept, its own stages ran inside ``alternatives`` and are not
    added again (the first decomposition's tries are ``first_decomposition``).
    """
    head, _, body = line.removeprefix("seconds ").partition(" (")
    items = [item.partition(" ") for item in body.rstrip(")").split(", ")]
    inside = {"plan", "gcode", "read", "replay", "repair"} if any(
        name == "alternatives" for name, _, _ in items) else set()
    listed = 0.0
    for name, _, value in items:
        if name not in ("text", "repair_rounds", *inside) and value:
            listed += float(value.split()[0])
    return float(head) - listed


def _ratio(a: float, b: float) -> str:
    return f"{a / b:5.2f}x" if b > 0 and not (math.isnan(a) or math.isnan(b)) else "    -"


def report(case: Case, double: Case | None) -> list[str]:
    """The printed lines of one model."""
    o, n, sup = case.best("ours"), case.best("cura"), case.best("cura+support")
    rows = [f"{case.name} ({case.faces} faces){': ' + o.note if o.note else ''}"]
    for label, r in (("ours", o), ("cura", n), ("cura+support", sup)):
        rows.append(
            f"  {label:<13} {r.wall:7.2f} s wall {r.cpu:7.2f} s CPU  {r.filament:9.0f} mm "
            f"{r.time_s / 60:7.1f} min  {r.lines:7d} lines "
            f"{r.lines / (r.time_s / 60) if r.ok else math.nan:6.0f} lines/min "
            f"{100 * r.wire / (BAUD / 10) if r.ok else math.nan:5.1f} % of {BAUD} baud"
            + ("" if r.ok or label == "ours" else f"  {r.note}"))
    rows.append(f"  ours / cura:         wall {_ratio(o.wall, n.wall)} CPU {_ratio(o.cpu, n.cpu)}"
                f"  filament {_ratio(o.filament, n.filament)} time {_ratio(o.time_s, n.time_s)}"
                f"  lines {_ratio(o.lines, n.lines)}")
    rows.append(f"  ours / cura+support: wall {_ratio(o.wall, sup.wall)} "
                f"CPU {_ratio(o.cpu, sup.cpu)}  filament {_ratio(o.filament, sup.filament)} "
                f"time {_ratio(o.time_s, sup.time_s)}")
    if o.stages:
        rows.append(f"  ours {o.stages}; not listed {unlisted(o.stages):.2f} s")
    if double is not None:
        d, dc = double.best("ours"), double.best("cura+support")
        cost = (f"doubling costs wall {_ratio(d.wall, o.wall)} CPU {_ratio(d.cpu, o.cpu)}"
                if d.ok and o.ok else "no doubling cost (a file is missing)")
        rows.append(f"  {double.faces} faces: ours {d.wall:.2f} s wall {d.cpu:.2f} s CPU, "
                    f"{cost} (cura+support {_ratio(dc.cpu, sup.cpu)} CPU)"
                    + (f"; {d.note}" if d.note else ""))
    return rows


def run_model(name: str, faces: int, repeat: int, double: bool, s: ProcessSettings,
              defs: Path, tmp: Path) -> tuple[Case, Case | None]:
    """Every run of one model, alternating ours and Cura's, repeated."""
    limits = MotionLimits.from_settings(s)
    mesh = hard_model(name, faces)
    sizes = [(faces, mesh)] + ([(2 * faces, finer(mesh, 2 * faces))] if double else [])
    cases = []
    for count, m in sizes:
        stl = tmp / f"{name}_{count}.stl"
        m.export(stl)
        case = Case(name, count)
        for _ in range(max(1, repeat)):
            case.add("ours", ours(stl, stl.with_suffix(".gcode"), s, limits))
            for kind, support in (("cura", False), ("cura+support", True)):
                if count == faces or support:
                    case.add(kind, cura(stl, stl.with_suffix(f".{kind}.gcode"), s, limits,
                                        defs, support))
        cases.append(case)
    return cases[0], cases[1] if double else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=list(MODELS),
                        help=f"of {HARD} (default: {' '.join(MODELS)})")
    parser.add_argument("--faces", type=int, default=50_000)
    parser.add_argument("--height", type=float, default=0.2)
    parser.add_argument("--repeat", type=int, default=1,
                        help="runs of each process; the least CPU time is shown")
    parser.add_argument("--no-double", action="store_true", help="skip the doubled faces")
    parser.add_argument("--definitions", help="folder of Cura's fdmprinter.def.json")
    parser.add_argument("--keep", help="write the STL and G-code files here")
    args = parser.parse_args()
    missing = [m for m in args.models if not (HARD / f"{m}.stl").is_file()]
    if missing:
        parser.error(f"no {', '.join(missing)} in {HARD}")
    defs = definitions(args.definitions)
    cura_engine()
    s = ProcessSettings(layer_height=args.height)
    print(f"layer height {args.height:g} mm, {args.faces} faces, CuraEngine "
          f"{cura_engine()} with {defs}; time and filament by one estimator", flush=True)
    with tempfile.TemporaryDirectory() as scratch:
        tmp = Path(args.keep or scratch)
        tmp.mkdir(parents=True, exist_ok=True)
        for name in args.models:
            case, double = run_model(name, args.faces, args.repeat, not args.no_double, s,
                                     defs, tmp)
            print("\n".join(report(case, double)), flush=True)


if __name__ == "__main__":
    main()
