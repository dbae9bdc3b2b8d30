"""Malformed JSON-RPC, fuzzed with hypothesis, against a running hostd: it never fails."""

from __future__ import annotations

import asyncio
import json
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "daemon"))
from hostd_harness import DaemonProc

json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(), inner, max_size=4),
    max_leaves=10)
methods = st.sampled_from(["server.info", "job.get", "job.submit", "job.list", "job.pause",
                           "job.resume", "job.cancel", "job.delete", "printer.gcode",
                           "events.subscribe", "nope", ""]) | st.text(max_size=20)
requests = st.fixed_dictionaries(
    {"jsonrpc": st.sampled_from(["2.0", "1.0", 2]), "method": methods},
    optional={"id": json_values, "params": json_values})
messages = (requests.map(json.dumps) | json_values.map(json.dumps)
            | st.binary(max_size=200).map(lambda b: b.decode("latin-1"))
            | st.lists(requests, max_size=3).map(json.dumps))


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fuzz")
    d = DaemonProc(tmp)
    loop = asyncio.new_event_loop()
    loop.run_until_complete(d.start())
    yield d, loop
    loop.run_until_complete(d.stop())
    loop.close()


async def _exchange(path: Path, payload: str) -> None:
    async with asyncio.timeout(10):
        r, w = await asyncio.open_unix_connection(str(path))
        w.write(payload.replace("\n", " ").encode("utf-8", "surrogatepass") + b"\n")
        w.write(b'{"jsonrpc": "2.0", "id": "probe", "method": "server.info"}\n')
        await w.drain()
        while True:  # every reply is a JSON object/array line; the probe is answered
            line = await r.readline()
            assert line, "daemon closed the connection"
            msg = json.loads(line)
            if isinstance(msg, dict) and msg.get("id") == "probe":
                assert msg["result"]["name"] == "hostd"
                break
        w.close()


@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(messages)
def test_fuzzed_messages_never_break_the_daemon(daemon, payload):
    d, loop = daemon
    if "\r" in payload:
        payload = payload.replace("\r", " ")
    loop.run_until_complete(_exchange(d.socket, payload))
    assert d.proc.returncode is None


PARAMS = {  # every method's parameters (printer.estop left out: it halts the emulator)
    "server.info": [], "printer.status": [], "printer.gcode": ["script"],
    "job.submit": ["name", "data", "kind", "encoding"], "job.upload": ["data", "offset"],
    "job.list": ["states", "limit"], "job.get": ["id"], "job.pause": ["id", "wait"],
    "job.resume": ["id", "from"], "job.cancel": ["id", "wait"], "job.delete": ["id"],
    "events.subscribe": ["events"], "events.unsubscribe": [], "sim.log": ["since"],
    "queue.status": [], "queue.start": [], "queue.hold": [], "printer.firmware_restart": [],
}
TOKENS = ["a", "\ud800", "\udfff", "\x00", "\x07", ".gcode", ".stl", "é", "G1 X", "nan", "1e400",
          "\n", " ", "QUJD", "==", "G28", ";HOSTD_LAYER {", "gcode", "text", "layer"]
odd_text = st.lists(st.sampled_from(TOKENS), max_size=6).map("".join)  # lone surrogates too
odd_values = (st.integers(-(2**70), 2**70) | st.floats() | st.booleans() | st.none()
              | odd_text | odd_text | st.text(max_size=20)
              | st.lists(odd_text | st.integers(), max_size=3))
calls = st.sampled_from(sorted(PARAMS)).flatmap(lambda m: st.tuples(
    st.just(m), st.fixed_dictionaries({}, optional={p: odd_values for p in PARAMS[m]})))


async def _call(path: Path, method: str, params: dict) -> dict:
    async with asyncio.timeout(30):
        r, w = await asyncio.open_unix_connection(str(path))
        w.write(json.dumps({"jsonrpc": "2.0", "id": 1, "method": method, "params": params},
                           allow_nan=True).encode() + b"\n")
        await w.drain()
        reply = json.loads(await r.readline())
        w.close()
        return reply


@settings(max_examples=400, deadline=None, suppress_health_check=list(HealthCheck))
@given(calls)
def test_odd_params_get_a_clear_error_never_an_internal_one(daemon, call):
    """Well-formed calls with odd values (huge integers, lone surrogates, control
    characters, NaN, wrong types): an answer or an error naming the problem, never -32603."""
    d, loop = daemon
    method, params = call
    reply = loop.run_until_complete(_call(d.socket, method, params))
    assert reply.get("error", {}).get("code") != -32603, (method, params, reply)
    assert d.proc.returncode is None
