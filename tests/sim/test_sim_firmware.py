"""The emulated board on its own: line checking, buffers, commands, heaters, faults."""

from __future__ import annotations

import pytest

from hostd.link.framing import encode, frame
from hostd.sim.firmware import Firmware
from hostd.sim.settings import SimSettings


def board(**kw: object) -> Firmware:
    fw = Firmware(SimSettings(**kw))  # type: ignore[arg-type]
    fw.take_output()
    send(fw, 0, "M110 N0")
    return fw


def send(fw: Firmware, n: int, cmd: str) -> list[str]:
    fw.receive(encode(frame(n, cmd)))
    fw.settle()
    return fw.take_output().decode().splitlines()


def test_boot_prints_the_start_banner() -> None:
    fw = Firmware(SimSettings())
    assert fw.take_output().decode().splitlines()[0] == "start"


def test_bad_checksum_and_wrong_number_are_rejected_like_marlin() -> None:
    fw = board()
    assert send(fw, 1, "G28") == ["ok"]
    fw.receive(b"N2 G1 X5*1\n")
    assert fw.take_output().decode().splitlines() == [
        "Error:checksum mismatch, Last Line: 1", "Resend: 2", "ok"]
    assert send(fw, 3, "G1 X5") == [
        "Error:Line Number is not Last Line Number+1, Last Line: 1", "Resend: 2", "ok"]
    fw.receive(b"N2 G1 X5\n")
    assert fw.take_output().decode().splitlines()[0].startswith("Error:No Checksum")
    assert [t for _, t in fw.log] == ["M110 N0", "G28"]


def test_overflowing_bytes_are_lost_when_the_planner_is_full() -> None:
    fw = board(rx_buffer_bytes=63)
    burst = b"".join(encode(frame(n, f"G1 X{n * 50} F300")) for n in range(1, 40))
    fw.receive(burst)
    assert fw.dropped_bytes > 0 and fw.rx_high_water <= 63


def test_m114_reports_xyzac_and_m105_temperatures() -> None:
    fw = board()
    send(fw, 1, "G1 X10 Y20 Z5 A30 C-90 E1 F3000")
    assert send(fw, 2, "M114")[0].startswith("X:10.00 Y:20.00 Z:5.00 A:30.00 C:-90.00 E:1.00")
    assert send(fw, 3, "M105")[0].startswith("ok T:22.00 /0.00 B:22.00 /0.00")


def test_relative_moves_and_g92() -> None:
    fw = board()
    send(fw, 1, "G91")
    send(fw, 2, "G1 X5 C10")
    send(fw, 3, "G1 X5 C10")
    send(fw, 4, "G92 X0")
    send(fw, 5, "G90")
    assert send(fw, 6, "M114")[0].startswith("X:0.00 Y:0.00 Z:0.00 A:0.00 C:20.00")


def test_m109_waits_with_busy_keepalive_until_the_heater_is_hot() -> None:
    fw = board()
    out = send(fw, 1, "M109 S200")
    assert out.count("echo:busy: processing") >= 2 and out[-1] == "ok"
    assert fw.machine.hotend.temperature(fw.now) == pytest.approx(200.0, abs=1.0)


def test_m109_without_busy_keepalive_prints_the_heaters_each_second() -> None:
    fw = board(busy_interval=0)
    out = send(fw, 1, "M109 S200")
    assert out[-1] == "ok" and not any("busy" in line for line in out)
    reports = [line for line in out[:-1] if line.strip().startswith("T:")]
    assert len(reports) >= 5 and all(line.endswith(" W:?") for line in reports)
    temps = [float(line.split()[0][2:]) for line in reports]
    assert temps == sorted(temps) and temps[-1] < 200.0  # heating, then the ok


def test_advanced_ok_reports_line_planner_and_queue() -> None:
    fw = board(advanced_ok=True)
    assert send(fw, 1, "G1 X1") == ["ok N1 P14 B3"]  # the G1 still holds its slot


def test_lost_step_on_a_drifts_after_the_given_move() -> None:
    fw = board(lost_step_axis="A", lost_step_degrees=-0.9, lost_step_at_move=2)
    send(fw, 1, "G1 A10")
    assert "A:10.00" in send(fw, 2, "M114")[0]
    send(fw, 3, "G1 A20")
    assert "A:19.10" in send(fw, 4, "M114")[0]


def test_emergency_parser_halts_even_with_a_full_buffer() -> None:
    fw = board(rx_buffer_bytes=32)
    send(fw, 1, "M109 S250")  # long wait, but settle() ran it; fill the queue
    fw.receive(b"".join(encode(frame(n, "G4 S100")) for n in range(2, 20)) + b"M112\n")
    assert fw.halted and fw.log[-1] == (None, "M112")
    assert "Error:Printer halted. kill() called!" in fw.take_output().decode()


def test_spontaneous_reset_prints_the_banner_again() -> None:
    fw = board(reset_at_line=2)
    send(fw, 1, "G28")
    out = send(fw, 2, "G1 X1")
    assert "start" in out and fw.boots == 2 and fw.last_n == 0


def test_bit_flips_are_seeded_and_never_split_lines() -> None:
    a, b = board(bit_flip_prob=0.5, seed=3), board(bit_flip_prob=0.5, seed=3)
    outs = [[send(fw, n, f"G1 X{n}") for n in range(1, 30)] for fw in (a, b)]
    assert outs[0] == outs[1]
    assert a.faults.flipped > 0


def test_a_line_arriving_in_parts_is_acted_on_only_when_whole() -> None:
    fw = board(rx_buffer_bytes=63, queue_slots=1)
    fw.receive(encode(frame(1, "G4 S100")))  # a dwell holds the only queue slot (no settle)
    line = encode(frame(2, "G1 X12.500 Y3.250 E0.0400"))
    for part in (line[:7], line[7:20], line[20:]):
        fw.receive(part)  # the bytes wait in the ring
    assert bytes(fw.rx) == line and fw.dropped_bytes == 0
    fw.settle()
    assert fw.log[-2:] == [(1, "G4 S100"), (2, "G1 X12.500 Y3.250 E0.0400")]
    assert [r for r in fw.take_output().decode().splitlines() if r.startswith("ok")] == [
        "ok", "ok"]


def test_parts_read_as_they_come_make_one_line() -> None:
    fw = board()
    line = encode(frame(1, "G1 X12.500 Y3.250 E0.0400"))
    fw.receive(line[:10])
    assert fw.log[-1] == (0, "M110 N0") and not fw.rx  # read into the line buffer
    fw.receive(line[10:])
    fw.settle()
    assert fw.log[-1] == (1, "G1 X12.500 Y3.250 E0.0400")


def test_m112_after_the_rest_of_a_line_in_parts_halts() -> None:
    fw = board(rx_buffer_bytes=32, queue_slots=1)
    fw.receive(encode(frame(1, "G4 S100")))
    line = encode(frame(2, "G1 X12.500 Y3.250 E0.0400"))
    fw.receive(line[:32])  # fills the ring to the byte
    fw.receive(line[32:] + b"M112\n")  # overflows the ring; the emergency parser sees it
    assert fw.halted and fw.log[-1] == (None, "M112")
