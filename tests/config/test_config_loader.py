from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from hostd.config import ConfigError, defaults, load, loads
from hostd.config.docs import render_markdown, render_yaml
from hostd.config.paths import DEFAULT_CONFIG
from hostd.config.placeholders import filled
from hostd.config.schema import SCHEMA

ROOT = Path(__file__).resolve().parents[2]


def test_shipped_default_is_the_rendered_schema() -> None:
    assert (ROOT / "config" / "hostd.yaml").read_text() == render_yaml()


def test_shipped_default_loads_to_the_schema_defaults() -> None:
    cfg = load(ROOT / "config" / "hostd.yaml")
    assert dict(cfg) == dict(defaults())
    assert cfg["machine.a_limits"] == (-90.0, 90.0)
    assert cfg["serial.port"] == "sim://"


def test_packaged_default_points_at_the_shipped_file() -> None:
    assert DEFAULT_CONFIG.read_text() == (ROOT / "config" / "hostd.yaml").read_text()


def test_every_schema_key_is_documented_in_markdown() -> None:
    table = render_markdown()
    for section, fields in SCHEMA.items():
        for key in fields:
            assert f"`{section}.{key}`" in table


def test_empty_file_gives_defaults() -> None:
    assert dict(loads("", "x.yaml")) == dict(defaults())


def test_a_config_is_a_whole_mapping() -> None:
    cfg = loads("serial:\n  baud: 250000\n", "m.yaml")
    assert list(cfg.values()) == [cfg[k] for k in cfg]  # values() was hidden by a field
    assert dict(cfg.items())["serial.baud"] == 250000 and len(cfg) == len(list(cfg.keys()))


def test_partial_file_overrides_only_what_it_states() -> None:
    cfg = loads("machine:\n  a_limits: [-45, 60]\nserial:\n  baud: 250000\n", "p.yaml")
    assert cfg["machine.a_limits"] == (-45.0, 60.0)
    assert cfg["serial.baud"] == 250000
    assert cfg["machine.nozzle_diameter"] == defaults()["machine.nozzle_diameter"]


def _error(text: str) -> str:
    with pytest.raises(ConfigError) as info:
        loads(text, "config/hostd.yaml")
    return str(info.value)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("machine:\n  a_limits: [-120, 90]\n",
         "config/hostd.yaml:2: machine.a_limits: -120 is below -90"),
        ("machine:\n  nozzle_diameter: 0.4\n  bogus: 1\n",
         "config/hostd.yaml:3: machine.bogus: unknown key"),
        ("serial:\n  baud: fast\n", "config/hostd.yaml:2: serial.baud: 'fast' is not an integer"),
        ("metrics:\n  port: 70000\n", "config/hostd.yaml:2: metrics.port: 70000 is above 65535"),
        ("serial:\n  flow_control: turbo\n",
         "config/hostd.yaml:2: serial.flow_control: 'turbo' is not one of window, pingpong"),
        ("machine:\n  table_origin: [1, 2]\n",
         "config/hostd.yaml:2: machine.table_origin: expected 3 numbers, got 2"),
        ("machine:\n  a_limits: [60, -60]\n",
         "config/hostd.yaml:2: machine.a_limits: [60.0, -60.0] must be in ascending order"),
        ("nonsense:\n  x: 1\n", "config/hostd.yaml:1: nonsense: unknown section"),
        ("metrics:\n  enabled: 1\n",
         "config/hostd.yaml:2: metrics.enabled: 1 is not true or false"),
        ("process:\n  layer_height: .nan\n",
         "config/hostd.yaml:2: process.layer_height: nan is not a finite number"),
        ("serial:\n  baud: 9600\n  baud: 19200\n",
         "config/hostd.yaml:3: serial.baud: duplicate key"),
        ("machine: [1, 2]\n", "config/hostd.yaml:1: machine: expected a mapping of keys"),
        ("- a\n- b\n", "config/hostd.yaml:1: the top level must be a mapping"),
        ("machine:\n  a_limits: [1, 2\n", "config/hostd.yaml:3: invalid YAML"),
        ("serial:\n  reconnect_min: 5\n  reconnect_max: 1\n",
         "config/hostd.yaml:2: serial.reconnect_min: 5 is above serial.reconnect_max (1)"),
        ("process:\n  layer_height: 0.5\n",
         "config/hostd.yaml:2: process.layer_height: 0.5 is above 0.8 × "
         "machine.nozzle_diameter (0.32)"),
        ("machine:\n  nozzle_diameter: 0.6\nprocess:\n  line_width: 0.45\n",
         "config/hostd.yaml:4: process.line_width: 0.45 is narrower than 0.8 × "
         "machine.nozzle_diameter (0.48)"),
        ("process:\n  start_gcode: \"G28\\nM104 S{nozzle_temp}\\n\"\n",
         "config/hostd.yaml:2: process.start_gcode: unknown placeholder {nozzle_temp} "
         "(a bare name of: "),
        ("process:\n  end_gcode: \"G0 Z{safe_z F3000\"\n",
         "config/hostd.yaml:2: process.end_gcode: expected '}' before end of string (write "
         "{{ and }} for literal braces)"),
        ("process:\n  start_gcode: \"G28\\nM104 S300\\n\"\n",
         "config/hostd.yaml:2: process.start_gcode: script line 2: M104 S300 is above the "
         "hotend's limit 285 °C (machine.max_hotend_temp)"),
        ("process:\n  end_gcode: \"M112\"\n",
         "config/hostd.yaml:2: process.end_gcode: script line 1: M112 is not allowed"),
        ("process:\n  start_gcode: \"hello\"\n",
         "config/hostd.yaml:2: process.start_gcode: script line 1: 'HELLO' is not a G-code"),
        ("process:\n  start_gcode: \"M104 S{nozzle_temperature[0]}\"\n",
         "config/hostd.yaml:2: process.start_gcode: unknown placeholder "
         "{nozzle_temperature[0]} (a bare name of: "),
        ("process:\n  end_gcode: \"G0 Z{safe_z:x} F3000\"\n",
         "config/hostd.yaml:2: process.end_gcode: placeholder {safe_z:x}: Unknown format code "
         "'x' for object of type 'float'"),
        ("process:\n  end_gcode: \"G0 Z{safe_z:{w}} F3000\"\n",
         "config/hostd.yaml:2: process.end_gcode: placeholder {safe_z:{w}}: a format spec "
         "cannot hold a placeholder"),
        ("sim:\n  silence_at_line: 40\n",
         "config/hostd.yaml:2: sim.silence_at_line: silences nothing with sim.silence_lines 0"),
        ("machine:\n  max_hotend_temp: 200\n",
         "config/hostd.yaml: process.nozzle_temperature: 210 is above "
         "machine.max_hotend_temp (200)"),
        ("process:\n  bed_temperature: 130\n",
         "config/hostd.yaml:2: process.bed_temperature: 130 is above machine.max_bed_temp "
         "(120)"),
        ("printhead:\n  segments:\n    - {start: 0, end: 5, r_start: 1}\n",
         "config/hostd.yaml:3: printhead.segments: item 0: missing r_end"),
        ("printhead:\n  segments:\n    - {start: 0, end: 5, r_start: 1, r_end: 2}\n"
         "    - {start: 6, end: 9, r_start: 1, r_end: 2}\n",
         "config/hostd.yaml:3: printhead.segments: item 1: start 6 leaves a gap"),
    ],
)
def test_bad_values_are_fatal_with_file_line_and_key(text: str, expected: str) -> None:
    message = _error(text)
    assert message.startswith(expected), message
    assert "\n" not in message


def test_a_script_may_format_its_placeholders() -> None:
    cfg = loads("process:\n  end_gcode: \"G0 Z{safe_z:.1f} F3000\\nM140 S{bed_temperature:.0f}\"\n",
                "f.yaml")
    assert filled(cfg, cfg["process.end_gcode"]) == "G0 Z0.0 F3000\nM140 S60"


def test_missing_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"nope\.yaml: no such file"):
        load(tmp_path / "nope.yaml")


def _check(path: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hostd.main", "--check-config", str(path)],
                          capture_output=True, text=True, timeout=60)


def test_check_config_cli_ok_and_error(tmp_path: Path) -> None:
    good = _check(ROOT / "config" / "hostd.yaml")
    assert (good.returncode, good.stdout.strip()) == (0, "ok")
    bad = tmp_path / "bad.yaml"
    bad.write_text("# a comment\nmachine:\n  a_limits: [-120, 90]\n")
    res = _check(bad)
    assert res.returncode == 2
    assert res.stdout.strip() == f"{bad}:3: machine.a_limits: -120 is below -90"
    assert "Traceback" not in res.stderr


def test_readme_tables_are_generated_from_the_schema_and_metrics() -> None:
    from hostd.config.docs import readme_blocks, sync_readme

    readme = (ROOT / "README.md").read_text()
    assert sync_readme(readme) == readme, "run `make docs` to regenerate the README tables"
    for name in readme_blocks():
        assert f"<!-- BEGIN {name} -->" in readme


def test_every_placeholder_the_loader_accepts_is_one_the_daemon_can_fill() -> None:
    """The end script runs from the daemon at a cancel: a placeholder the loader lets through
    but the daemon cannot fill would fail only then, mid-print."""
    from hostd.config.loader import defaults
    from hostd.config.placeholders import known_names, script_problem
    from hostd.printer.settings import stream_settings_from_config as stream_settings

    settings = stream_settings(defaults())
    for name in sorted(known_names()):
        script = f"M117 {{{name}}}\n"
        assert script_problem(script) is None
        text = script.format_map({**settings.end_values, "safe_z": "1.000"})
        assert "{" not in text and text != script, name
    assert settings.end_values["nozzle_temperature"] == defaults()["process.nozzle_temperature"]


def test_integer_ranges_are_written_in_full_in_the_docs() -> None:
    """The generated table shows 2147483647 and 4000000, not 2.14748e+09 and 4e+06."""
    from hostd.config.docs import render_markdown
    from hostd.config.schema import SCHEMA

    assert SCHEMA["serial"]["baud"].describe() == "integer in [1200, 4000000]"
    assert SCHEMA["sim"]["seed"].describe() == "integer in [0, 2147483647]"
    assert "e+" not in render_markdown()


def test_the_scripts_name_every_placeholder_outside_the_process_section() -> None:
    """process.start_gcode's meaning names the placeholders that are not process keys (the
    machine keys, {safe_z}); end_gcode points at it and says what {safe_z} is there."""
    from hostd.config.placeholders import known_names

    start = SCHEMA["process"]["start_gcode"].doc
    others = known_names() - set(SCHEMA["process"])
    assert others and all(re.search(rf"\b{name}\b", start) for name in others)
    assert "key of this section" in start and "machine keys" in start
    end = SCHEMA["process"]["end_gcode"].doc
    assert "start_gcode" in end and "{safe_z}" in end


@pytest.mark.parametrize(("process", "machine"), [
    ("nozzle_temperature", "machine.max_hotend_temp"), ("bed_temperature", "machine.max_bed_temp")])
def test_a_temperature_names_the_machine_limit_it_may_not_pass(process: str,
                                                               machine: str) -> None:
    """The table's range is the schema's; a temperature above the machine's limit is refused
    too, and its meaning says so."""
    assert machine in SCHEMA["process"][process].doc
    with pytest.raises(ConfigError, match=f"process.{process}: .* is above {machine}"):
        loads(f"process:\n  {process}: {SCHEMA['process'][process].hi}\n")
