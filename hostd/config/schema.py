"""The configuration schema: every key hostd accepts, its type, bounds, default and meaning.

This table is the single source of truth: the loader validates against it, ``config/hostd.yaml``
is checked against it in the tests, and the README's key reference is generated from it
(``python -m hostd.config.docs``).
"""

from __future__ import annotations

from hostd.config.fields import Field, Flag, Number, Records, Text, Vector

UNIX_SOCKET_PATH_MAX = 108
"""Bytes of a Unix socket path on Linux (``sun_path``); a longer one cannot be bound."""

DEFAULT_START_GCODE = """\
G28
M140 S{bed_temperature}
M104 S{nozzle_temperature}
M190 S{bed_temperature}
M109 S{nozzle_temperature}
G92 E0
"""

DEFAULT_END_GCODE = """\
M104 S0
M140 S0
M107
G0 Z{safe_z} F3000
G0 A0 C0 F3000
M84
"""

SCHEMA: dict[str, dict[str, Field]] = {
    "machine": {
        "name": Text("Printer name shown in status and metrics.", "five-axis"),
        "x_range": Vector("Machine X travel [min, max], mm.", (0.0, 500.0), length=2,
                          lo=-2000, hi=2000, ordered=True),
        "y_range": Vector("Machine Y travel [min, max], mm.", (0.0, 500.0), length=2,
                          lo=-2000, hi=2000, ordered=True),
        "z_range": Vector("Machine Z travel [min, max], mm.", (0.0, 700.0), length=2,
                          lo=-2000, hi=2000, ordered=True),
        "a_limits": Vector("Tilt (A) range [min, max], degrees.", (-90.0, 90.0), length=2,
                           lo=-90, hi=90, ordered=True),
        "c_limits": Vector("Rotation (C) range [min, max], degrees; null = continuous.",
                           None, nullable=True, length=2, lo=-3600, hi=3600, ordered=True),
        "table_origin": Vector("Machine position of the platform origin at A = C = 0, mm.",
                               (250.0, 250.0, 100.0), lo=-2000, hi=2000),
        "a_pivot": Vector("A point on the A axis in machine coordinates, mm.",
                          (250.0, 250.0, 80.0), lo=-2000, hi=2000),
        "platform_radius": Number("Radius of the round build platform, mm.", 150.0, lo=10,
                                  hi=1000),
        "linearize_tolerance": Number(
            "Largest tool-tip deviation allowed when A/C move with a straight line, and "
            "where the slicer merges short moves of a path into longer ones, mm.",
            0.01, lo=0.0005, hi=1.0),
        "nozzle_diameter": Number("Nozzle diameter, mm.", 0.4, lo=0.1, hi=2.0),
        "filament_diameter": Number("Filament diameter, mm.", 1.75, lo=1.0, hi=3.5),
        "max_velocity": Number("Linear axes top speed, mm/s.", 200.0, lo=1, hi=2000),
        "max_accel": Number("Linear axes acceleration, mm/s².", 1000.0, lo=10, hi=50000),
        "max_rotary_velocity": Number("A/C top speed, degrees/s.", 90.0, lo=1, hi=3600),
        "max_rotary_accel": Number("A/C acceleration, degrees/s².", 360.0, lo=1, hi=100000),
        "max_hotend_temp": Number("Highest hotend target (M104/M109 S) a job or raw G-code "
                                  "may set, °C; a higher one is refused.", 285.0, lo=0,
                                  hi=500),
        "max_bed_temp": Number("Highest platform target (M140/M190 S) a job or raw G-code "
                               "may set, °C; a higher one is refused.", 120.0, lo=0, hi=200),
    },
    "printhead": {
        "segments": Records(
            "Printhead as solids of revolution about the nozzle axis, from the tip up: "
            "each segment has start/end height above the tip and radius at each end (mm).",
            ({"start": 0.0, "end": 12.0, "r_start": 0.5, "r_end": 7.43},
             {"start": 12.0, "end": 50.0, "r_start": 15.0, "r_end": 15.0}),
            keys=("start", "end", "r_start", "r_end"), lo=0.0, hi=1000.0),
    },
    "process": {
        "layer_height": Number("Nominal layer thickness t along the skeleton, mm; at most 0.8 × "
                               "machine.nozzle_diameter.", 0.2,
                               lo=0.04, hi=1.0),
        "line_width": Number("Extrusion width, mm; at least 0.8 × machine.nozzle_diameter.",
                             0.45, lo=0.1, hi=2.0),
        "perimeters": Number("Number of perimeter loops.", 2, lo=1, hi=20, integer=True),
        "infill_density": Number("Sparse infill density, 0..1.", 0.2, lo=0.0, hi=1.0),
        "infill_angle": Number("Infill direction of even layers, degrees.", 45.0, lo=-180,
                               hi=180),
        "solid_layers": Number("Solid layers at the bottom and top of every sub-part.", 3,
                               lo=0, hi=50, integer=True),
        "min_shell_thickness": Number("Bottom and top skins at least this thick, mm: thin "
                                      "layers get more than solid_layers.", 0.6, lo=0,
                                      hi=10),
        "print_speed": Number("Infill speed, mm/s.", 40.0, lo=1, hi=500),
        "perimeter_speed": Number("Perimeter speed, mm/s.", 30.0, lo=1, hi=500),
        "first_layer_speed": Number("Speed of a sub-part's first layer, mm/s.", 15.0, lo=1,
                                    hi=500),
        "travel_speed": Number("Travel speed, mm/s.", 120.0, lo=1, hi=1000),
        "retract_length": Number("Retraction length, mm of filament.", 1.0, lo=0, hi=20),
        "retract_speed": Number("Retraction speed, mm/s.", 35.0, lo=1, hi=200),
        "z_hop": Number("Lift along the nozzle axis on travel, mm.", 0.4, lo=0, hi=10),
        "safe_height": Number("Clearance above the part for rotate/return moves, mm.", 60.0,
                              lo=1, hi=700),
        "min_layer_factor": Number("Smallest local layer thickness as a share of t.", 0.5,
                                   lo=0.1, hi=1.0),
        "max_layer_factor": Number("Largest local layer thickness as a share of t (capped at "
                                   "0.8 × machine.nozzle_diameter).", 1.5,
                                   lo=1.0, hi=3.0),
        "interface_layers": Number("Solid parent layers under a child's base.", 3, lo=0,
                                   hi=50, integer=True),
        "interface_speed_factor": Number("Speed factor of a child's first layer.", 0.5,
                                         lo=0.05, hi=1.0),
        "interface_flow": Number("Extrusion multiplier of a child's first layer.", 1.1,
                                 lo=0.5, hi=2.0),
        "nozzle_temperature": Number("Hotend temperature, °C; at most "
                                     "machine.max_hotend_temp (a higher one is refused).",
                                     210.0, lo=0, hi=450),
        "bed_temperature": Number("Platform temperature, °C; at most machine.max_bed_temp "
                                  "(a higher one is refused).", 60.0, lo=0, hi=150),
        "fan_speed": Number("Part fan PWM while printing (0..255).", 255, lo=0, hi=255,
                            integer=True),
        "start_gcode": Text("G-code before the print. Its {placeholders}: a key of this "
                            "section (the scripts aside, e.g. {nozzle_temperature}), the "
                            "machine keys nozzle_diameter, filament_diameter, max_velocity, "
                            "max_accel, max_rotary_velocity, max_rotary_accel and "
                            "linearize_tolerance ({nozzle_diameter}), and {safe_z}: "
                            "safe_height above the empty platform at A = C = 0 (machine Z); "
                            "{{ and }} for literal braces.",
                            DEFAULT_START_GCODE, multiline=True),
        "end_gcode": Text("G-code after the print (and after a cancel), with the "
                          "placeholders of start_gcode; {safe_z} here is the safe machine "
                          "Z: no lower than the file's transitions lift.",
                          DEFAULT_END_GCODE, multiline=True),
    },
    "decompose": {
        "parts": Number("Coarse partition K; 0 chooses it automatically.", 0, lo=0, hi=64,
                        integer=True),
        "seed": Number("Seed of k-means and the plane search.", 0, lo=0, hi=2**31 - 1,
                       integer=True),
        "plane_offset_max": Number("Largest random plane offset per perturbation, mm.", 2.0,
                                   lo=0.0, hi=50.0),
        "plane_angle_max": Number("Largest random normal tilt per perturbation, degrees.",
                                  5.0, lo=0.0, hi=45.0),
        "area_growth_max": Number("Largest growth of the excluded cross-section (share).",
                                  0.15, lo=0.0, hi=10.0),
        "max_iterations": Number("Plane search iterations per boundary.", 2000, lo=1,
                                 hi=10**6, integer=True),
    },
    "serial": {
        "port": Text("Serial device, or sim:// for the built-in firmware emulator.", "sim://"),
        "baud": Number("Baud rate.", 115200, lo=1200, hi=4000000, integer=True),
        "flow_control": Text("window (buffer credit) or pingpong (one line in flight).",
                             "window", choices=("window", "pingpong")),
        "rx_buffer_bytes": Number("Firmware receive buffer the window may fill, bytes: "
                                  "Marlin's RX_BUFFER_SIZE less one (127 for its default of "
                                  "128), never more than the board has. A board built with a "
                                  "larger buffer lets hostd read the port less often while it "
                                  "streams.", 127, lo=16, hi=65536, integer=True),
        "partial_lines": Flag("Window mode: send the first part of the next line when the "
                              "credit is short of the whole line (fills the receive buffer "
                              "to the byte); false: whole lines only.", True),
        "read_hold": Number("Window mode, real ports, receive buffer of 120 bytes or more: "
                            "while oks come at the wire's pace, leave the port unread for "
                            "this share of the wire time still queued (at most 10 ms), so "
                            "one wake-up reads several; 0: read each at once.", 0.7,
                            lo=0.0, hi=0.9),
        "ok_timeout": Number("Seconds without an ok before nudging with M105.", 10.0,
                             lo=0.05, hi=3600),
        "starve_timeout": Number("Seconds without an ok while lines wait for credit before "
                                 "an M105 goes out past the window (a lost ok stalls the "
                                 "stream until its ok T:); 0: off.", 1.0, lo=0.0, hi=3600),
        "nudges": Number("M105 nudges after successive timeouts before the link is lost.", 1,
                         lo=1, hi=100, integer=True),
        "resend_limit": Number("Resends of one line before the job fails.", 10, lo=1,
                               hi=1000, integer=True),
        "history_size": Number("Sent lines kept for resends.", 1024, lo=16, hi=1_000_000,
                               integer=True),
        "reconnect_min": Number("First reconnect delay, s.", 0.5, lo=0.01, hi=600),
        "reconnect_max": Number("Largest reconnect delay, s.", 30.0, lo=0.01, hi=3600),
        "handshake_timeout": Number("Seconds to wait for the ok of M110 N0 before retrying.",
                                    2.0, lo=0.05, hi=60),
        "handshake_attempts": Number("M110 N0 attempts before connecting fails.", 5, lo=1,
                                     hi=100, integer=True),
        "max_queued": Number("Most job lines submitted ahead of their acknowledgements.", 64,
                             lo=1, hi=100000, integer=True),
    },
    "transition": {
        "position_tolerance": Number("Largest X/Y/Z mismatch after a rotate move, mm.", 0.05,
                                     lo=0.0, hi=10.0),
        "angle_tolerance": Number("Largest A/C mismatch after a rotate move, degrees.", 0.05,
                                  lo=0.0, hi=10.0),
        "temperature_tolerance": Number("Largest hotend drift before a rotate move, °C.", 5.0,
                                        lo=0.0, hi=100.0),
    },
    "pause": {
        "lift": Number("Lift along machine Z when a job pauses, after the retract (no "
                       "rotation; at most to machine.z_range's top), mm.", 10.0, lo=0.0,
                       hi=700.0),
        "lift_speed": Number("Speed of the Z moves hostd makes itself, mm/s: a pause's lift "
                             "and the way back down, and the climb to the safe Z and back "
                             "when a resume brings the head back (after a move by hand, or "
                             "for an interrupted job).", 10.0, lo=0.1, hi=500.0),
        "idle_timeout": Number("Seconds a job paused while the job database cannot be "
                               "written (a full disk) keeps its heaters on; then hostd turns "
                               "them off (the resume heats them again). 0: at once.", 300.0,
                               lo=0.0, hi=86400.0),
    },
    "daemon": {
        "socket": Text("Path of the JSON-RPC control socket.", "/run/hostd/hostd.sock",
                       path=True, max_bytes=UNIX_SOCKET_PATH_MAX),
        "state_dir": Text("Directory of the job database and the upload spool.",
                          "/var/lib/hostd", path=True),
        "max_upload_bytes": Number("Largest accepted upload, bytes.", 64 * 1024 * 1024,
                                   lo=1024, hi=2**34, integer=True),
        "log_level": Text("Logging level.", "info", choices=("debug", "info", "warning",
                                                               "error")),
        "next_job": Text("When the next queued job starts: after_clear holds the queue once "
                         "a job has left a part on the platform, until hostctl queue start; "
                         "at_once starts it right away (an empty platform each time).",
                         "after_clear", choices=("after_clear", "at_once")),
        "max_connections": Number(
            "Most control connections open at once. At the cap, the connection that has sent "
            "no request for longest is closed to make room; when every one has, a new one "
            "gets an error (-32009) and is closed (hostd_connections_refused_total).", 64,
            lo=1, hi=4096, integer=True),
        "idle_timeout": Number(
            "Seconds a control connection may go without a whole request while it has none "
            "in progress and no event subscription; then it is closed. The bytes of an "
            "unfinished request do not count (a client sending a byte at a time is dropped).",
            30.0, lo=1, hi=86400),
        "max_request_bytes": Number(
            "Largest request (one JSON-RPC line), bytes: a longer one gets an error (-32007) "
            "and its connection is closed. A file larger than about 3/4 of it (base64) goes "
            "in parts (job.upload), as hostctl sends any file over 192 KiB (a part of 256 "
            "KiB of base64 in its request).", 512 * 1024, lo=384 * 1024, hi=2**36,
            integer=True),
        "max_buffered_bytes": Number(
            "Bytes of unfinished and unanswered requests hostd holds across all control "
            "connections; when they would pass it, the connection holding the most is "
            "dropped. At least daemon.max_request_bytes.", 16 * 1024 * 1024,
            lo=384 * 1024, hi=2**38, integer=True),
    },
    "metrics": {
        "enabled": Flag("Serve Prometheus metrics.", True),
        "host": Text("Metrics listen address (loopback by default). The systemd unit lets "
                     "only localhost traffic through (IPAddressDeny=any, "
                     "IPAddressAllow=localhost): for a Prometheus on another host, add its "
                     "address in a drop-in (systemctl edit hostd.service: IPAddressAllow=ADDR).",
                     "127.0.0.1"),
        "port": Number("Metrics TCP port.", 9464, lo=1, hi=65535, integer=True),
        "max_connections": Number(
            "Most metrics connections open at once (a scrape takes one; one that sends no "
            "whole request within daemon.idle_timeout is closed); past it a new one gets "
            "503 and is closed.", 8, lo=1, hi=1024, integer=True),
    },
    "http": {
        "enabled": Flag("Serve the HTTP and WebSocket API (JSON-RPC at /websocket, uploads, "
                        "the slicers' OctoPrint and Moonraker upload endpoints, the web "
                        "page at /). Every request needs a key of http.api_key_file, but "
                        "GET /api/version.", False),
        "host": Text("HTTP listen address (loopback by default). Beyond loopback the unit "
                     "needs the clients' addresses allowed (IPAddressAllow= in a drop-in) "
                     "and a TLS reverse proxy should front it (README: Security).",
                     "127.0.0.1"),
        "port": Number("HTTP TCP port (Moonraker's).", 7125, lo=1, hi=65535, integer=True),
        "api_key_file": Text("File of the API keys, one a line (hostctl api-key new, list, "
                             "revoke); read again when it changes.", "/etc/hostd/api-keys",
                             path=True),
        "max_upload_mb": Number("Largest request body (an upload), MiB; a larger one gets "
                                "413. An upload is also held to daemon.max_upload_bytes.",
                                64, lo=1, hi=16384, integer=True),
    },
    "notify": {
        "command": Text(
            "Shell command run when a job completes, fails or pauses, with the job's JSON "
            "(as hostctl job --json shows it) on its standard input and HOSTD_JOB_ID, "
            "HOSTD_JOB_STATE, HOSTD_JOB_NAME in its environment; empty: none. It runs as "
            "hostd's user, under the unit's hardening (no network beyond loopback unless "
            "allowed); a failure is logged as a warning.", ""),
        "timeout": Number("Seconds notify.command may run before it is killed.", 30.0,
                          lo=1, hi=3600),
    },
    "sim": {
        "rx_buffer_bytes": Number("Emulated firmware receive buffer, bytes.", 127, lo=16,
                                  hi=65536, integer=True),
        "realtime": Flag("Run the emulated planner in real time (else as fast as possible).",
                         False),
        "time_scale": Number("Emulated seconds per real second when realtime.", 1.0,
                             lo=0.001, hi=1e6),
        "throttle": Flag("Limit the emulated wire to baud/10 bytes per second.", True),
        "bit_flip_prob": Number("Probability of a corrupted received line.", 0.0, lo=0,
                                hi=1),
        "lost_ok_prob": Number("Probability that an ok is never sent.", 0.0, lo=0, hi=1),
        "busy_prob": Number("Probability of a busy period after a command.", 0.0, lo=0,
                            hi=1),
        "busy_seconds": Number("Length of an injected busy period, emulated seconds.", 3.0,
                               lo=0, hi=3600),
        "advanced_ok": Flag("Answer ok N.. P.. B.. (Marlin ADVANCED_OK) instead of a bare ok.",
                            False),
        "queue_slots": Number("Emulated command queue (Marlin BUFSIZE).", 4, lo=1, hi=64,
                              integer=True),
        "planner_blocks": Number("Emulated planner blocks (BLOCK_BUFFER_SIZE).", 16, lo=1,
                                 hi=256, integer=True),
        "reset_at_line": Number("Reboot after executing this many lines; 0 = never.", 0, lo=0,
                                hi=2**31 - 1, integer=True),
        "silence_at_line": Number("Go silent after executing this many lines (for "
                                  "sim.silence_lines lines, which must then be above 0); "
                                  "0 = never.", 0,
                                  lo=0, hi=2**31 - 1, integer=True),
        "silence_lines": Number("Received lines swallowed without answer when silent.", 0,
                                lo=0, hi=2**31 - 1, integer=True),
        "lost_step_axis": Text("Rotary axis that loses steps.", "A", choices=("A", "C")),
        "lost_step_degrees": Number("Drift of the M114 position after the lost step, degrees.",
                                    0.0, lo=-360, hi=360),
        "lost_step_at_move": Number("Lose steps at this move changing the axis; 0 = never.", 0,
                                    lo=0, hi=2**31 - 1, integer=True),
        "seed": Number("Seed of the fault injection.", 0, lo=0, hi=2**31 - 1, integer=True),
    },
}
