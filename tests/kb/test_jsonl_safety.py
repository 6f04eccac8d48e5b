"""What a hostile or broken client of the JSON-lines socket costs: itself
alone. Real sockets on 127.0.0.1; every wait bounded by trio.fail_after."""

from __future__ import annotations

import socket
import struct
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import pytest
import trio
from ippc.kb import KnowledgeBase
from ippc.kb.jsonl import MAX_DEPTH, Connection, JsonlServer, connect
from ippc.kb.service import register_kb

TIMEOUT = 20


@asynccontextmanager
async def running(server: JsonlServer, **limits: Any) -> AsyncIterator[int]:
    async with trio.open_nursery() as nursery:
        port = await nursery.start(server.serve, "127.0.0.1", 0)
        try:
            yield port
        finally:
            nursery.cancel_scope.cancel()


def big_server() -> JsonlServer:
    server = JsonlServer("test")

    def big(params: dict[str, Any], conn: Connection) -> Any:
        return "x" * int(params.get("n", 100_000))

    def echo(params: dict[str, Any], conn: Connection) -> Any:
        return params

    server.register("test.big", big)
    server.register("test.echo", echo)
    return server


def reset(sock: socket.socket) -> None:
    """Close with SO_LINGER 0: the peer gets a reset, not an end of stream."""
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    sock.close()


async def raw_connect(port: int) -> trio.SocketStream:
    return await trio.open_tcp_stream("127.0.0.1", port)


@pytest.mark.trio
async def test_a_client_that_resets_with_replies_unread_ends_only_itself() -> None:
    with trio.fail_after(TIMEOUT):
        async with running(big_server()) as port, connect(port) as good:
            assert await good.call("test.echo", {"a": 1}) == {"a": 1}
            for _ in range(5):
                stream = await raw_connect(port)
                # many big replies it never reads, then a reset
                await stream.send_all(
                    b"".join(
                        b'{"id": %d, "method": "test.big", "params": {"n": 200000}}\n' % i
                        for i in range(40)
                    )
                )
                await trio.sleep(0.05)
                reset(stream.socket._sock)  # type: ignore[attr-defined]
            await trio.sleep(0.2)
            # the server still serves, and the good client's session goes on
            assert await good.call("test.echo", {"b": 2}) == {"b": 2}
            async with connect(port) as later:
                assert await later.call("test.echo", {"c": 3}) == {"c": 3}


@pytest.mark.trio
async def test_a_subscriber_reset_with_events_unread(warehouse: KnowledgeBase) -> None:
    server = JsonlServer("kb")
    register_kb(server, warehouse)
    with trio.fail_after(TIMEOUT):
        async with running(server) as port, connect(port) as good:
            sub = await raw_connect(port)
            await sub.send_all(b'{"id": 1, "method": "kb.subscribe", "params": {}}\n')
            for i in range(200):
                where = "c2" if i % 2 else "c1"
                other = "c1" if i % 2 else "c2"
                await good.call(
                    "kb.apply",
                    {
                        "updates": [
                            {"op": "remove", "fluent": "robot-at", "args": [other]},
                            {"op": "add", "fluent": "robot-at", "args": [where]},
                        ]
                    },
                )
            reset(sub.socket._sock)  # type: ignore[attr-defined]
            for _ in range(20):  # events still posted to the reset subscriber
                await good.call(
                    "kb.apply", {"updates": [{"op": "set", "fluent": "battery", "value": 3}]}
                )
                await good.call(
                    "kb.apply", {"updates": [{"op": "set", "fluent": "battery", "value": 4}]}
                )
            await trio.sleep(0.1)
            assert await good.call("kb.get", {"fluent": "battery"}) == 4


@pytest.mark.trio
async def test_a_reset_while_reading_a_request() -> None:
    with trio.fail_after(TIMEOUT):
        async with running(big_server()) as port, connect(port) as good:
            for _ in range(5):
                stream = await raw_connect(port)
                await stream.send_all(b'{"id": 1, "method": "test.echo", "params": {"x": "')
                await trio.sleep(0.02)
                reset(stream.socket._sock)  # type: ignore[attr-defined]
            await trio.sleep(0.1)
            assert await good.call("test.echo", {}) == {}


@pytest.mark.trio
async def test_deep_nesting_is_refused_with_a_clear_error() -> None:
    with trio.fail_after(TIMEOUT):
        async with running(big_server()) as port, connect(port) as client:
            await client.send_line(b"[" * 1100 + b"\n")
            reply = await client.next_event()
            assert reply["id"] is None
            assert reply["error"]["code"] == "too-deep"
            assert f"{MAX_DEPTH}" in reply["error"]["message"]
            deep = b'{"id": 4, "method": "test.echo", "params": {"a": ' + b"[" * 200
            deep += b"]" * 200 + b"}}\n"
            await client.send_line(deep)
            reply = await client.next_event()
            assert reply["id"] is None and reply["error"]["code"] == "too-deep"
            # brackets inside strings are text, not nesting
            text = "[" * 500
            assert await client.call("test.echo", {"t": text}) == {"t": text}
            ok: Any = 1
            for _ in range(MAX_DEPTH - 2):
                ok = [ok]
            assert await client.call("test.echo", {"ok": ok}) == {"ok": ok}
            await client.send_line(b'{"id": 9, "method": "test.echo", "params": {"s": "\\"[[["}}\n')
            assert (await client.next_event()) == {"id": 9, "result": {"s": '"[[['}}


def test_rddl_kb_survives_a_reset_and_deep_nesting() -> None:
    """The rddl-kb process itself, as an operator's tools would meet it."""
    import subprocess
    import sys

    from .conftest import WAREHOUSE

    proc = subprocess.Popen(
        [sys.executable, "-m", "ippc.kb.cli", str(WAREHOUSE), str(WAREHOUSE), "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stdout.readline() if proc.stdout is not None else ""
        assert line.startswith("listening on 127.0.0.1:"), line
        port = int(line.rsplit(":", 1)[1])

        def ask(sock: socket.socket, data: bytes) -> bytes:
            sock.sendall(data)
            got = b""
            while not got.endswith(b"\n"):
                chunk = sock.recv(65536)
                assert chunk, "closed"
                got += chunk
            return got

        good = socket.create_connection(("127.0.0.1", port), timeout=10)
        sub = socket.create_connection(("127.0.0.1", port), timeout=10)
        ask(sub, b'{"id": 1, "method": "kb.subscribe"}\n')
        for i in range(50):
            value = 3 + i % 2
            ask(
                good,
                b'{"id": 2, "method": "kb.apply", "params": {"updates": '
                b'[{"op": "set", "fluent": "battery", "value": %d}]}}\n' % value,
            )
        reset(sub)
        bad = socket.create_connection(("127.0.0.1", port), timeout=10)
        assert b'"too-deep"' in ask(bad, b"[" * 1100 + b"\n")
        reset(bad)
        reply = ask(good, b'{"id": 3, "method": "kb.get", "params": {"fluent": "battery"}}\n')
        assert reply == b'{"id":3,"result":4}\n'
        assert proc.poll() is None
        good.close()
    finally:
        proc.terminate()
        proc.wait(timeout=10)


# ------------------------------------------------ the listener's limits


async def closed_by_server(stream: trio.SocketStream) -> bool:
    """Whether the server closes `stream` (reads to its end, bounded)."""
    with trio.move_on_after(5):
        try:
            while await stream.receive_some(65536):
                pass
        except trio.BrokenResourceError:
            pass
        return True
    return False


@pytest.mark.trio
async def test_the_connection_cap_and_allow_come_from_the_listener() -> None:
    from ippc.kb.jsonl import SocketLimits

    with trio.fail_after(TIMEOUT):
        capped = big_server()
        capped.limits = SocketLimits(max_connections=2, accept_rate=0)
        async with running(capped) as port, connect(port) as one, connect(port) as two:
            assert await one.call("test.echo", {"n": 1}) == {"n": 1}
            third = await raw_connect(port)
            assert await closed_by_server(third)
            assert await two.call("test.echo", {"n": 2}) == {"n": 2}
            assert capped.notices.totals == {
                "connections refused: cap of 2 open connections reached": 1
            }
        elsewhere = big_server()
        elsewhere.limits = SocketLimits(allow=("10.0.0.0/8",))
        async with running(elsewhere) as port:
            stream = await raw_connect(port)
            assert await closed_by_server(stream)
            assert list(elsewhere.notices.totals) == ["connections refused: address not in --allow"]


@pytest.mark.trio
async def test_the_total_budget_closes_the_clients_that_do_not_read() -> None:
    from ippc.kb.jsonl import SocketLimits

    server = JsonlServer("test")
    limit = 4 << 20
    server.limits = SocketLimits(max_buffered=limit, max_queued=1 << 30, accept_rate=0)
    server.budget.limit = limit
    peak = [0]

    async def spam(params: dict[str, Any], conn: Connection) -> Any:
        chunk = "e" * 65536
        for _ in range(params["n"]):
            server.broadcast("test.spam", {"data": chunk})
            peak[0] = max(peak[0], server.budget.used)
            await trio.sleep(0.002)  # (a pace the good client, in this loop too, keeps up with)
        return len(server.connections)

    server.register("test.spam", spam)
    with trio.fail_after(TIMEOUT):
        async with running(server) as port, trio.open_nursery() as nursery:
            silent = [await raw_connect(port) for _ in range(3)]
            async with connect(port) as good:
                seen = [0]

                async def drain() -> None:
                    while True:
                        event = await good.next_event()
                        assert event["event"] == "test.spam"
                        seen[0] += 1

                nursery.start_soon(drain)
                left = await good.call("test.spam", {"n": 400})
                assert left == 1  # the good client alone
                assert peak[0] <= limit
                for stream in silent:
                    assert await closed_by_server(stream)
                assert await good.call("methods") is not None
                nursery.cancel_scope.cancel()
            counts = server.notices.totals
            assert counts == {
                "connections closed: over the budget of queued replies and unread input": 3
            }


@pytest.mark.trio
async def test_a_pipelining_client_does_not_stall_another() -> None:
    server = JsonlServer("test")
    handled: list[str] = []

    def count(params: dict[str, Any], conn: Connection) -> Any:
        handled.append(params["who"])
        return len(handled)

    server.register("test.count", count)
    with trio.fail_after(TIMEOUT):
        async with running(server) as port, connect(port) as good:
            assert await good.call("test.count", {"who": "good"}) == 1
            pipe = await raw_connect(port)
            lines = b"".join(
                b'{"id": %d, "method": "test.count", "params": {"who": "pipe"}}\n' % i
                for i in range(3000)
            )
            async with trio.open_nursery() as nursery:
                nursery.start_soon(pipe.send_all, lines)

                async def read_all() -> None:
                    got = b""
                    while got.count(b"\n") < 3000:
                        got += await pipe.receive_some(65536)

                nursery.start_soon(read_all)
                while "pipe" not in handled:
                    await trio.sleep(0)
                n = await good.call("test.count", {"who": "good"})
            # the good request took its turn among the pipelined ones
            assert handled.count("pipe") == 3000
            assert handled.index("good", 1) < 1 + 200, handled.index("good", 1)
            assert n == handled.index("good", 1) + 1


def test_a_generated_problem_is_made_again_only_after_a_change(
    warehouse: KnowledgeBase,
) -> None:
    """(A client pipelining thousands of kb.rddl_instance requests costs lookups.)"""
    from ippc.kb import Update

    first = warehouse.to_rddl_instance()
    assert warehouse.to_rddl_instance() is first
    warehouse.apply([Update.set("battery", (), 3)], "test")
    changed = warehouse.to_rddl_instance()
    assert changed is not first and changed != first
    warehouse.horizon = 7
    assert "horizon = 7" in warehouse.to_rddl_instance()
