"""The JSON-lines framework and the knowledge base's methods on it, over real
sockets on 127.0.0.1 (every wait bounded by trio.fail_after)."""

from __future__ import annotations

import json
import threading
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import pytest
import trio
from ippc.kb import KnowledgeBase
from ippc.kb.jsonl import MAX_LINE, Connection, JsonlServer, RequestError, connect
from ippc.kb.service import register_kb

TIMEOUT = 10


@asynccontextmanager
async def running(server: JsonlServer) -> AsyncIterator[int]:
    async with trio.open_nursery() as nursery:
        port = await nursery.start(server.serve, "127.0.0.1", 0)
        try:
            yield port
        finally:
            nursery.cancel_scope.cancel()


def framework_server() -> JsonlServer:
    server = JsonlServer("test")
    order: list[int] = []

    def echo(params: dict[str, Any], conn: Connection) -> Any:
        """return the params"""
        return params

    def record(params: dict[str, Any], conn: Connection) -> Any:
        order.append(params["n"])
        return list(order)

    async def slow(params: dict[str, Any], conn: Connection) -> Any:
        await trio.sleep(params.get("seconds", 0.2))
        return "slow done"

    def refuse(params: dict[str, Any], conn: Connection) -> Any:
        raise RequestError("not-today", "refused on purpose")

    def crash(params: dict[str, Any], conn: Connection) -> Any:
        raise ZeroDivisionError("a bug in a handler")

    def unjsonable(params: dict[str, Any], conn: Connection) -> Any:
        return {"set": {1, 2}}

    def notify(params: dict[str, Any], conn: Connection) -> Any:
        conn.send_event("test.note", {"text": params["text"]})
        return "sent"

    def from_thread(params: dict[str, Any], conn: Connection) -> Any:
        t = threading.Thread(target=lambda: conn.send_event("test.thread", {"ok": True}))
        t.start()
        t.join()
        return "posted"

    for fn in (echo, record, slow, refuse, crash, unjsonable, notify, from_thread):
        server.register(f"test.{fn.__name__}", fn)
    return server


@pytest.mark.trio
async def test_good_and_bad_lines_on_one_connection() -> None:
    with trio.fail_after(TIMEOUT):
        async with running(framework_server()) as port, connect(port) as client:
            assert await client.call("test.echo", {"a": [1, "x"]}) == {"a": [1, "x"]}
            await client.send_line(b"this is not json\n")
            await client.send_line(b"[1, 2]\n")
            await client.send_line(b'{"id": 5}\n')
            await client.send_line(b'{"id": 6, "method": "no.such"}\n')
            await client.send_line(b'{"id": 7, "method": "test.echo", "params": [1]}\n')
            await client.send_line(b'{"id": {"x": 1}, "method": "test.echo"}\n')
            await client.send_line(b"\n   \n")  # blank lines: nothing to answer
            replies = [await client.next_event() for _ in range(6)]
            assert [(r["id"], r["error"]["code"]) for r in replies] == [
                (None, "parse-error"),
                (None, "bad-request"),
                (5, "bad-request"),
                (6, "unknown-method"),
                (7, "bad-params"),
                (None, "bad-request"),
            ]
            assert "no method 'no.such'" in replies[3]["error"]["message"]
            # the connection is still good
            assert await client.call("test.echo", {}) == {}


@pytest.mark.trio
async def test_handler_errors_are_replies() -> None:
    with trio.fail_after(TIMEOUT):
        async with running(framework_server()) as port, connect(port) as client:
            for method, code, words in [
                ("test.refuse", "not-today", "refused on purpose"),
                ("test.crash", "internal-error", "ZeroDivisionError: a bug in a handler"),
                ("test.unjsonable", "internal-error", "not JSON"),
                ("test.record", "bad-params", "missing param 'n'"),
            ]:
                with pytest.raises(RequestError) as err:
                    await client.call(method, {})
                assert err.value.code == code and words in str(err.value)
            names = [m["method"] for m in await client.call("methods")]
            assert "test.echo" in names and "methods" in names


@pytest.mark.trio
async def test_plain_handlers_keep_order_and_slow_ones_do_not_block() -> None:
    with trio.fail_after(TIMEOUT):
        async with running(framework_server()) as port, connect(port) as client:
            results: dict[str, Any] = {}

            async def call(key: str, method: str, params: dict[str, Any]) -> None:
                results[key] = await client.call(method, params)

            async with trio.open_nursery() as nursery:
                nursery.start_soon(call, "slow", "test.slow", {"seconds": 1.0})
                await trio.sleep(0.05)
                for n in range(5):
                    nursery.start_soon(call, f"r{n}", "test.record", {"n": n})
                    await trio.sleep(0)
                with trio.fail_after(0.9):  # the five answer while the slow one sleeps
                    while len(results) < 5:
                        await trio.sleep(0.01)
            assert results["r4"] == [0, 1, 2, 3, 4]
            assert results["slow"] == "slow done"


@pytest.mark.trio
async def test_events_from_the_trio_thread_and_other_threads() -> None:
    with trio.fail_after(TIMEOUT):
        async with running(framework_server()) as port, connect(port) as client:
            assert await client.call("test.notify", {"text": "hi"}) == "sent"
            assert await client.next_event() == {"event": "test.note", "text": "hi"}
            assert await client.call("test.from_thread") == "posted"
            assert await client.next_event() == {"event": "test.thread", "ok": True}


@pytest.mark.trio
async def test_a_too_long_line_is_refused_and_skipped() -> None:
    with trio.fail_after(TIMEOUT):
        async with running(framework_server()) as port, connect(port) as client:
            await client.send_line(b'{"id": 1, "method": "test.echo", "params": {"x": "')
            await client.send_line(b"y" * (MAX_LINE + 10))
            await client.send_line(b'"}}\n')
            reply = await client.next_event()
            assert reply["error"]["code"] == "line-too-long"
            assert await client.call("test.echo", {"after": True}) == {"after": True}


@pytest.mark.trio
async def test_close_callbacks_run_when_the_client_goes() -> None:
    server = JsonlServer("test")
    closed = trio.Event()

    def hello(params: dict[str, Any], conn: Connection) -> Any:
        conn.on_close(lambda c: closed.set())
        return conn.peer.startswith("127.0.0.1:")

    server.register("hello", hello)
    with trio.fail_after(TIMEOUT):
        async with running(server) as port:
            async with connect(port) as client:
                assert await client.call("hello") is True
            await closed.wait()
            assert server.connections == set()


@pytest.mark.trio
async def test_registering_a_name_twice_is_an_error() -> None:
    server = JsonlServer()
    with pytest.raises(ValueError, match="'methods' is registered already"):
        server.register("methods", lambda p, c: None)


# ----------------------------------------------------------- kb methods


@pytest.mark.trio
async def test_kb_state_over_the_socket(warehouse: KnowledgeBase) -> None:
    server = JsonlServer("kb")
    register_kb(server, warehouse)
    with trio.fail_after(TIMEOUT):
        async with running(server) as port, connect(port) as client, connect(port) as watcher:
            assert await watcher.call("kb.subscribe", {"fluents": ["robot-at"]}) == {
                "subscribed": ["robot-at"]
            }
            assert await client.call("kb.get", {"fluent": "robot-at", "args": ["c1"]}) is True
            facts = await client.call("kb.facts", {"fluent": "status"})
            assert facts == [{"fluent": "status", "args": [], "value": "@busy"}]
            reply = await client.call(
                "kb.apply",
                {
                    "updates": [
                        {"op": "remove", "fluent": "robot-at", "args": ["c1"]},
                        {"op": "add", "fluent": "robot-at", "args": ["c2"]},
                        {"op": "set", "fluent": "battery", "value": 4},
                    ],
                    "source": "controller",
                },
            )
            assert reply["changes"][2] == {"fluent": "battery", "args": [], "old": 5, "new": 4}
            event = await watcher.next_event()
            assert event == {
                "event": "kb.changed",
                "source": "controller",
                "changes": [  # robot-at only: the watcher asked for nothing else
                    {"fluent": "robot-at", "args": ["c1"], "old": True, "new": False},
                    {"fluent": "robot-at", "args": ["c2"], "old": False, "new": True},
                ],
            }
            # a bad batch: an error, nothing applied, the server goes on
            with pytest.raises(RequestError) as err:
                await client.call(
                    "kb.apply",
                    {
                        "updates": [
                            {"op": "add", "fluent": "robot-at", "args": ["c3"]},
                            {"op": "set", "fluent": "battery", "value": "full"},
                        ]
                    },
                )
            assert err.value.code == "bad-value" and "update 2" in str(err.value)
            assert await client.call("kb.get", {"fluent": "robot-at", "args": ["c3"]}) is False
            assert await client.call("kb.get", {"fluent": "battery"}) == 4
            assert await watcher.call("kb.unsubscribe") == {"subscribed": True}


@pytest.mark.trio
async def test_kb_bad_requests(warehouse: KnowledgeBase) -> None:
    server = JsonlServer("kb")
    register_kb(server, warehouse)
    with trio.fail_after(TIMEOUT):
        async with running(server) as port, connect(port) as client:
            for method, params, code in [
                ("kb.get", {}, "bad-params"),
                ("kb.get", {"fluent": 3}, "bad-params"),
                ("kb.get", {"fluent": "robot-at", "args": "c1"}, "bad-params"),
                ("kb.get", {"fluent": "robot-at", "args": [1]}, "bad-params"),
                ("kb.get", {"fluent": "nothing"}, "unknown-fluent"),
                ("kb.apply", {"updates": [7]}, "bad-params"),
                ("kb.apply", {"updates": [{"op": "add"}]}, "bad-params"),
                ("kb.subscribe", {"fluents": ["nothing"]}, "unknown-fluent"),
                ("kb.set_parameters", {"horizon": 0}, "bad-value"),
                ("kb.set_parameters", {"discount": 0.5, "horizon": -1}, "bad-value"),
                ("kb.set_parameters", {"depth": 3}, "bad-params"),
                ("kb.immediate_reward", {"actions": [{"move": 1}]}, "bad-params"),
                ("kb.immediate_reward", {"actions": ["fly(c1)"]}, "unknown-action"),
            ]:
                with pytest.raises(RequestError) as err:
                    await client.call(method, params)
                assert err.value.code == code, (method, params, str(err.value))
            # the failed set_parameters changed nothing
            assert await client.call("kb.parameters") == {
                "horizon": 20,
                "discount": 1.0,
                "max_nondef_actions": 1,
            }
            assert await client.call("kb.set_parameters", {"horizon": 40}) == {
                "horizon": 40,
                "discount": 1.0,
                "max_nondef_actions": 1,
            }
            assert await client.call("kb.goal_holds") is False
            goal = await client.call("kb.goal")
            assert goal["facts"] == [{"fluent": "box-at", "args": ["b1", "c3"], "value": True}]
            assert await client.call("kb.immediate_reward", {"actions": ["move(c1, c2)"]}) == -1.0


def test_the_wire_is_compact_json_lines() -> None:
    from ippc.kb.jsonl import encode

    assert encode({"id": 1, "result": [True, None, 1.5]}) == b'{"id":1,"result":[true,null,1.5]}\n'
    assert json.loads(encode({"x": float("inf")})) == {"x": "inf"}
