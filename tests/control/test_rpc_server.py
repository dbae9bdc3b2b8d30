from __future__ import annotations

import asyncio
import json
import logging
import os
import stat

import pytest

from hostd.control.limits import Limits, LimitSettings
from hostd.control.rpc import Param, Registry, error_for
from hostd.control.server import ControlServer
from hostd.events import EventBus, EventError
from hostd.jobs.states import JobStateError
from hostd.jobs.store import JobNotFound


def make_registry() -> Registry:
    reg = Registry()

    async def echo(ctx, text: str, times: int) -> str:
        return text * times

    async def boom(ctx) -> None:
        raise RuntimeError("secret detail")

    async def missing(ctx) -> None:
        raise JobNotFound("no job 7")

    async def sub(ctx) -> str:
        ctx.subscribe(None)
        return "ok"

    reg.add("echo", echo, Param("text", "str"), Param("times", "int", required=False,
                                                      default=1))
    reg.add("boom", boom)
    reg.add("missing", missing)
    reg.add("sub", sub)
    return reg


def small_limits(**kw: object) -> Limits:
    return Limits(LimitSettings(**{"max_request_bytes": 4096, **kw}))  # type: ignore[arg-type]


async def call(reg: Registry, msg: object) -> dict:
    raw = await reg.dispatch(json.dumps(msg), None)
    return json.loads(raw) if raw else {}


@pytest.mark.asyncio
async def test_dispatch_results_and_standard_errors():
    reg = make_registry()
    async with asyncio.timeout(5):
        ok = await call(reg, {"jsonrpc": "2.0", "id": 1, "method": "echo",
                              "params": {"text": "ab", "times": 2}})
        assert ok == {"jsonrpc": "2.0", "id": 1, "result": "abab"}
        assert (await call(reg, {"jsonrpc": "2.0", "id": 2, "method": "echo",
                                 "params": ["x"]}))["result"] == "x"
        codes = {
            "nomethod": {"jsonrpc": "2.0", "id": 3, "method": "nope"},
            "badtype": {"jsonrpc": "2.0", "id": 4, "method": "echo", "params": {"text": 5}},
            "bool": {"jsonrpc": "2.0", "id": 4, "method": "echo",
                     "params": {"text": "a", "times": True}},
            "extra": {"jsonrpc": "2.0", "id": 5, "method": "echo",
                      "params": {"text": "a", "zzz": 1}},
            "missing": {"jsonrpc": "2.0", "id": 6, "method": "echo", "params": {}},
            "version": {"jsonrpc": "1.0", "id": 7, "method": "echo"},
            "internal": {"jsonrpc": "2.0", "id": 8, "method": "boom"},
            "app": {"jsonrpc": "2.0", "id": 9, "method": "missing"},
        }
        want = {"nomethod": -32601, "badtype": -32602, "bool": -32602, "extra": -32602,
                "missing": -32602, "version": -32600, "internal": -32603, "app": -32001}
        for key, msg in codes.items():
            assert (await call(reg, msg))["error"]["code"] == want[key], key
        internal = await call(reg, codes["internal"])
        assert "secret" not in internal["error"]["message"]
        assert (await reg.dispatch(b"{not json", None)) is not None
        assert json.loads(await reg.dispatch(b"{not json", None))["error"]["code"] == -32700
        assert json.loads(await reg.dispatch(b"[]", None))["error"]["code"] == -32600
        # notifications get no answer, even when they fail
        assert await reg.dispatch(json.dumps({"jsonrpc": "2.0", "method": "boom"}), None) is None
        batch = json.loads(await reg.dispatch(json.dumps([
            {"jsonrpc": "2.0", "id": 1, "method": "echo", "params": {"text": "a"}},
            {"jsonrpc": "2.0", "method": "echo", "params": {"text": "b"}},
            {"jsonrpc": "2.0", "id": 2, "method": "nope"}]), None))
        assert [m.get("result") for m in batch] == ["a", None] and len(batch) == 2


@pytest.mark.asyncio
async def test_a_failing_notification_is_logged_though_nobody_is_answered(
        caplog: pytest.LogCaptureFixture):
    reg = make_registry()
    async with asyncio.timeout(5):
        with caplog.at_level(logging.ERROR, logger="hostd.control.rpc"):
            assert await reg.dispatch(json.dumps({"jsonrpc": "2.0", "method": "boom"}),
                                      None) is None
    assert [str(r.exc_info[1]) for r in caplog.records if r.exc_info] == ["secret detail"]


@pytest.mark.asyncio
async def test_a_lone_surrogate_in_a_string_param_is_invalid_params():
    """JSON's \\u escapes can carry a lone surrogate, which no file, database or port can
    store: the parameter is refused by name, before the handler runs."""
    reg = make_registry()
    raw = '{"jsonrpc": "2.0", "id": 1, "method": "echo", "params": {"text": "ab\\ud800"}}'
    reply = json.loads(await reg.dispatch(raw, None))
    assert reply["error"]["code"] == -32602
    assert reply["error"]["message"] == ("text: not Unicode text (a lone surrogate at "
                                         "character 2)")
    ok = ('{"jsonrpc": "2.0", "id": 2, "method": "echo", '
          '"params": {"text": "\\u00e9\\ud83d\\ude00"}}')  # a pair is fine
    assert json.loads(await reg.dispatch(ok, None))["result"] == "\u00e9\U0001F600"


@pytest.mark.asyncio
@pytest.mark.parametrize(("value", "ok"), [(2**63 - 1, True), (-(2**63), True),
                                           (2**63, False), (-(2**63) - 1, False),
                                           (10**30, False)])
async def test_integer_params_are_64_bit(value: int, ok: bool):
    """What the job database can store: a larger id is refused by name, not an overflow."""
    reg = Registry()

    async def same(ctx, n: int) -> int:
        return n

    reg.add("same", same, Param("n", "int"))
    reply = json.loads(await reg.dispatch(json.dumps(
        {"jsonrpc": "2.0", "id": 1, "method": "same", "params": {"n": value}}), None))
    if ok:
        assert reply["result"] == value
    else:
        assert reply["error"] == {"code": -32602, "message": f"n: {value} is out of range"}


@pytest.mark.asyncio
@pytest.mark.parametrize("depth", [2000, 200_000])
async def test_json_nested_too_deeply_is_a_parse_error(depth: int):
    """json's decoder recurses per level: a deep message raised RecursionError, which
    reached the journal as a traceback and left the client without an answer."""
    reg = make_registry()
    async with asyncio.timeout(5):
        for raw in ("[" * depth + "]" * depth, '{"a":' * depth + "1" + "}" * depth):
            reply = json.loads(await reg.dispatch(raw, None))
            assert reply["error"]["code"] == -32700
            assert "nested too deeply" in reply["error"]["message"]


@pytest.mark.asyncio
async def test_a_deep_but_parseable_batch_gets_answers():
    reg = make_registry()
    deep = [{"jsonrpc": "2.0", "id": 1, "method": "echo", "params": {"text": "a"}}]
    inner: list = []
    for _ in range(400):  # below json's limit: parsed, then refused as params
        inner = [inner]
    deep.append({"jsonrpc": "2.0", "id": 2, "method": "echo", "params": [inner]})
    async with asyncio.timeout(5):
        replies = json.loads(await reg.dispatch(json.dumps(deep), None))
    assert replies[0]["result"] == "a"
    assert replies[1]["error"]["code"] == -32602


def test_error_table_is_the_one_place():
    assert error_for(JobStateError("cannot"))["code"] == -32002
    assert error_for(EventError("x"))["code"] == -32602
    assert error_for(KeyError("k"))["code"] == -32603


def test_event_bus_isolates_a_failing_handler():
    bus = EventBus()
    seen = []

    def bad(name, data):
        raise ValueError("broken subscriber")

    bus.subscribe(bad)
    unsub = bus.subscribe(lambda n, d: seen.append((n, d["x"])), ["job.state"])
    bus.publish("job.state", {"x": 1})
    bus.publish("job.progress", {"x": 2})
    unsub()
    bus.publish("job.state", {"x": 3})
    assert seen == [("job.state", 1)]
    assert bus.status()["handler_errors"] == 3
    with pytest.raises(EventError):
        bus.subscribe(bad, ["no.such"])


@pytest.mark.asyncio
async def test_server_oversize_abrupt_disconnect_and_push(tmp_path):
    bus = EventBus()
    path = tmp_path / "s.sock"
    server = ControlServer(path, make_registry(), bus, limits=small_limits())
    async with asyncio.timeout(10):
        await server.start()
        assert stat.S_IMODE(os.stat(path).st_mode) == 0o660
        # abrupt disconnect in the middle of a line
        _, w = await asyncio.open_unix_connection(str(path))
        w.write(b'{"jsonrpc": "2.0", "id": 1, "meth')
        await w.drain()
        w.close()
        # oversized message: an error, then a clean close
        r, w = await asyncio.open_unix_connection(str(path))
        w.write(b"x" * 10000 + b"\n")
        await w.drain()
        reply = json.loads(await r.readline())
        assert reply["error"]["code"] == -32007
        assert await r.readline() == b""
        w.close()
        # a subscriber gets pushed events; others keep working
        r, w = await asyncio.open_unix_connection(str(path))
        w.write(b'{"jsonrpc": "2.0", "id": 1, "method": "sub"}\n')
        await w.drain()
        assert json.loads(await r.readline())["result"] == "ok"
        bus.publish("job.state", {"job_id": 1, "new": "printing"})
        note = json.loads(await r.readline())
        assert note["method"] == "notify_job_state" and note["params"]["new"] == "printing"
        w.write(b'{"jsonrpc": "2.0", "id": 2, "method": "echo", "params": {"text": "z"}}\n')
        await w.drain()
        assert json.loads(await r.readline())["result"] == "z"
        w.close()
        await server.close()
    assert not path.exists()


async def subscribed(path, names: list[str]) -> tuple[asyncio.StreamReader,
                                                     asyncio.StreamWriter]:
    r, w = await asyncio.open_unix_connection(str(path))
    w.write(json.dumps({"jsonrpc": "2.0", "id": 1, "method": "sub_to",
                        "params": {"names": names}}).encode() + b"\n")
    await w.drain()
    assert json.loads(await r.readline())["result"] == "ok"
    return r, w


@pytest.mark.asyncio
async def test_a_client_that_stops_reading_is_dropped_and_the_others_carry_on(
        tmp_path, caplog: pytest.LogCaptureFixture):
    """Events beyond what the socket and the subscriber's queue hold (bytes, here) drop the
    subscriber, with the reason logged and the events counted: nothing is buffered for it
    without bound. It got a prefix of the events, in order; the other subscriber all of its."""
    reg = make_registry()

    async def sub_to(ctx, names: list) -> str:
        ctx.subscribe(names)
        return "ok"

    reg.add("sub_to", sub_to, Param("names", "list"))
    bus = EventBus()
    path = tmp_path / "s.sock"
    limits = small_limits(queue_bytes=64 * 1024)
    server = ControlServer(path, reg, bus, limits=limits)
    pad = "x" * 10_000
    published = 300  # 3 MB: more than the socket's buffers and the queue together
    async with asyncio.timeout(20):
        await server.start()
        stuck_r, stuck_w = await subscribed(path, ["flood"])
        other_r, other_w = await subscribed(path, ["other"])
        with caplog.at_level(logging.WARNING, logger="hostd.control.limits"):
            for n in range(published):  # no turn of the loop: the client reads nothing
                bus.publish("flood", {"n": n, "pad": pad})
        bus.publish("other", {"n": -1})
        got = [json.loads(line)["params"]["n"] for line in (await stuck_r.read()).splitlines()
               if line.endswith(b"}")]  # the last line may be cut by the drop
        assert got == list(range(len(got))) and len(got) < published
        status = limits.status()
        assert status["dropped"]["slow_reader"] == 1
        assert 1 <= status["events_dropped"] <= published - len(got)
        assert any("not reading its events" in r.getMessage() for r in caplog.records)
        note = json.loads(await other_r.readline())
        assert note["method"] == "notify_other" and note["params"]["n"] == -1
        other_w.write(b'{"jsonrpc": "2.0", "id": 2, "method": "echo", "params": ["z"]}\n')
        await other_w.drain()
        assert json.loads(await other_r.readline())["result"] == "z"
        stuck_w.close()
        other_w.close()
        await server.close()


@pytest.mark.asyncio
async def test_close_hooks_run_when_a_connection_ends(tmp_path):
    """Each hook a handler registered runs once the client is gone, even after one fails."""
    reg = Registry()
    ran: list[int] = []
    done = asyncio.Event()

    async def hold(ctx) -> int:
        def fail() -> None:
            raise RuntimeError("hook failed")

        ctx.on_close["first"] = fail
        ctx.on_close["second"] = lambda: (ran.append(ctx.id), done.set())
        return ctx.id

    reg.add("hold", hold)
    server = ControlServer(tmp_path / "s.sock", reg, EventBus(), limits=small_limits())
    async with asyncio.timeout(10):
        await server.start()
        r, w = await asyncio.open_unix_connection(str(tmp_path / "s.sock"))
        w.write(b'{"jsonrpc": "2.0", "id": 1, "method": "hold"}\n')
        await w.drain()
        cid = json.loads(await r.readline())["result"]
        assert ran == []
        w.close()
        await done.wait()
        await server.close()
    assert ran == [cid]


@pytest.mark.asyncio
async def test_second_server_on_a_live_socket_is_refused(tmp_path):
    path = tmp_path / "s.sock"
    bus = EventBus()
    first = ControlServer(path, make_registry(), bus, small_limits())
    async with asyncio.timeout(5):
        await first.start()
        second = ControlServer(path, make_registry(), bus, small_limits())
        with pytest.raises(Exception, match="another daemon"):
            await second.start()
        await second.close()  # the refused daemon shuts down: the live socket stays
        r, w = await asyncio.open_unix_connection(str(path))
        w.write(b'{"jsonrpc": "2.0", "id": 1, "method": "echo", "params": ["up"]}\n')
        await w.drain()
        assert json.loads(await r.readline())["result"] == "up"
        w.close()
        await first.close()
    assert not path.exists()  # the first removes its own socket


@pytest.mark.asyncio
async def test_a_server_refused_by_an_ordinary_file_leaves_the_file(tmp_path):
    path = tmp_path / "s.sock"
    path.write_text("operator's notes\n")
    server = ControlServer(path, make_registry(), EventBus(), small_limits())
    async with asyncio.timeout(5):
        with pytest.raises(Exception, match="exists and is not a socket"):
            await server.start()
        await server.close()
    assert path.read_text() == "operator's notes\n"


@pytest.mark.asyncio
async def test_a_socket_replaced_after_start_is_not_removed_by_close(tmp_path):
    """The path now names another daemon's socket (ours was removed by hand and a second
    daemon started): stopping the first must not take the second's socket."""
    path = tmp_path / "s.sock"
    bus = EventBus()
    first = ControlServer(path, make_registry(), bus, small_limits())
    second = ControlServer(path, make_registry(), bus, small_limits())
    async with asyncio.timeout(5):
        await first.start()
        path.unlink()
        await second.start()
        await first.close()
        assert stat.S_ISSOCK(path.lstat().st_mode)
        await second.close()
    assert not path.exists()


@pytest.mark.asyncio
async def test_closing_with_clients_connected_leaves_nothing_for_the_loop_to_report(tmp_path):
    """A stop with clients still connected (``hostctl watch``, a dashboard) ends each
    connection's task: asyncio's stream callback on Python 3.11 reports a task that ended
    cancelled as an error ("Exception in callback ..."), which would reach the journal on
    every stop."""
    loop = asyncio.get_running_loop()
    contexts: list[dict] = []
    loop.set_exception_handler(lambda _loop, context: contexts.append(context))
    path = tmp_path / "s.sock"
    server = ControlServer(path, make_registry(), EventBus(), limits=small_limits())
    try:
        async with asyncio.timeout(10):
            await server.start()
            clients = [await asyncio.open_unix_connection(str(path)) for _ in range(3)]
            for r, w in clients:  # each connection served: its task is running
                w.write(b'{"jsonrpc": "2.0", "id": 1, "method": "echo", "params": ["z"]}\n')
                await w.drain()
                assert json.loads(await r.readline())["result"] == "z"
            await server.close()
            for r, _ in clients:
                assert await r.read() == b""  # closed by the server
            for _ in range(3):  # the tasks' done callbacks run
                await asyncio.sleep(0)
    finally:
        loop.set_exception_handler(None)
    assert contexts == []


@pytest.mark.asyncio
async def test_a_socket_path_too_long_to_bind_names_the_problem(tmp_path):
    """A path the config check did not see (built in code) fails with its reason, not
    ``None`` (an OSError without an errno)."""
    from hostd.control.server import ControlError

    path = tmp_path / ("d" * 60) / ("s" * 60 + ".sock")
    server = ControlServer(path, make_registry(), EventBus(), small_limits())
    async with asyncio.timeout(5):
        with pytest.raises(ControlError) as caught:
            await server.start()
    message = str(caught.value)
    assert message.startswith(f"{path}: cannot listen: ") and "None" not in message
    assert "too long" in message


@pytest.mark.parametrize("name", ["a\nWARNING fake.gcode", "tab\there.gcode", "esc\x1b[2J.gcode",
                                  "sep\u2028.gcode", "del\x7f.gcode"])
def test_a_job_name_with_a_control_character_is_invalid_params(name):
    from hostd.control.codes import INVALID_PARAMS, RpcError
    from hostd.control.rpc import Param

    param = Param("name", "str", line=True)
    with pytest.raises(RpcError) as caught:
        param.check(name)
    assert caught.value.code == INVALID_PARAMS
    assert caught.value.message.startswith("name: control character")
    assert param.check("pipé 3 (v2).gcode") == "pipé 3 (v2).gcode"
