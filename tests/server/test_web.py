"""rddl-server's web view over real sockets: every page and event stream
during and after real sessions, a hostile client name escaped everywhere,
failed sessions with their reason, worker processes, many viewers."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from functools import partial
from typing import Any

import pytest
import trio
from ippc.server.app import serve
from ippc.server.config import ServerConfig
from ippc.server.registry import Registry
from ippc.server.web import ServerView, SessionBoard
from ippc.web import Feed, WebOptions, WebServer, serve_web
from lxml import etree

from ..conftest import REPO
from ..web.httpclient import events, fetch
from .harness import (
    NOOP,
    ROUND_REQUEST,
    RawClient,
    root_of,
    session_request,
    strip_frame,
)

HOSTILE = "<img src=x onerror=alert(1)>"
ESCAPED = "&lt;img src=x onerror=alert(1)&gt;"
INSTANCE = "print_jobs_inst_1"  # horizon 20
_registry: list[Registry] = []


def registry() -> Registry:
    """The bundled print_jobs instances, loaded once."""
    if not _registry:
        _registry.append(Registry.load(REPO / "domains" / "print_jobs"))
    return _registry[0]


@asynccontextmanager
async def web_server(
    config: ServerConfig, feed: Feed | None = None
) -> AsyncIterator[tuple[int, int, ServerView, WebServer]]:
    """rddl-server with its web view, as `rddl-server --web 0 --workers 1`
    runs them: one trio loop. Yields the server's port, the view's port,
    the view and its HTTP server."""
    board = SessionBoard()
    view = ServerView(board, feed)
    servers: list[WebServer] = []
    async with trio.open_nursery() as nursery:
        web_port = await nursery.start(
            partial(serve_web, view.routes, WebOptions(host="127.0.0.1"), servers=servers)
        )
        nursery.start_soon(view.run)
        port = await nursery.start(partial(serve, config, registry(), live=board))
        try:
            yield port, web_port, view, servers[0]
        finally:
            nursery.cancel_scope.cancel()


class Player:
    """A client that plays noop turns one at a time when told."""

    def __init__(self, client: RawClient, rounds: int):
        self.c = client
        self.turns = 0
        self.rounds_left = rounds

    @classmethod
    async def start(cls, port: int, name: str) -> Player:
        c = await RawClient.connect(port)
        await c.send(session_request(INSTANCE, name))
        init = etree.fromstring(strip_frame(await c.recv()))
        assert init.tag == "session-init"
        await c.send(ROUND_REQUEST)
        assert root_of(await c.recv()) == "round-init"
        assert root_of(await c.recv()) == "turn"
        return cls(c, int(init.findtext("num-rounds")))

    async def play(self, n: int) -> str:
        """`n` noop turns (or up to the end of the round); the last message's root."""
        root = "turn"
        for _ in range(n):
            await self.c.send(NOOP)
            root = root_of(await self.c.recv())
            if root != "turn":
                return root
            self.turns += 1
        return root

    async def finish(self) -> float:
        """Play the session to its end; its total reward."""
        while True:
            assert await self.play(1000) == "round-end"
            self.rounds_left -= 1
            if not self.rounds_left:
                end = await self.c.recv()
                assert root_of(end) == "session-end"
                return float(etree.fromstring(strip_frame(end)).findtext("total-reward"))
            await self.c.send(ROUND_REQUEST)
            assert root_of(await self.c.recv()) == "round-init"
            assert root_of(await self.c.recv()) == "turn"


def xml_name(name: str) -> str:
    return name.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def assert_escaped(body: bytes | str) -> None:
    text = body if isinstance(body, str) else body.decode("utf-8")
    assert HOSTILE not in text and "<img src=x" not in text, text[:2000]


async def wait_for(predicate: Any, timeout: float = 10.0) -> None:
    with trio.fail_after(timeout):
        while not predicate():
            await trio.sleep(0.02)


@pytest.mark.trio
async def test_pages_and_streams_during_and_after_a_session() -> None:
    config = ServerConfig(port=0, rounds=2, host="127.0.0.1")
    async with web_server(config) as (port, web, view, _):
        # the page before any session, and the stream's snapshot
        r = await fetch(web, "/")
        assert r.status == 200 and "rddl-server: sessions" in r.text
        async with events(web, "/events") as overview:
            snap = await overview.next()
            assert snap == {"type": "rows", "reset": True, "rows": []}
            p = await Player.start(port, xml_name(HOSTILE))
            assert await p.play(5) == "turn"
            # the row appears live, with the name as text
            row = await overview.until(
                lambda e: (
                    e["type"] == "rows" and any(x["cells"].get("turn") == 5 for x in e["rows"])
                )
            )
            cells = row["rows"][0]["cells"]
            assert cells["client"] == HOSTILE  # (JSON: decoded it is the name, as text)
            assert cells["instance"] == INSTANCE and cells["state"] == "running"
            assert cells["round"] == "1 / 2" and cells["turns"] == 5
            assert "of 1080 s" in cells["time"]

            r = await fetch(web, "/")
            assert_escaped(r.body)
            assert ESCAPED in r.text and 'data-state="running"' in r.text
            r = await fetch(web, "/session/1")
            assert r.status == 200 and ESCAPED in r.text
            assert_escaped(r.body)
            assert r.text.count('data-key="1.') == 5  # the turns so far

            async with events(web, "/session/1/events") as detail:
                first = await detail.next()
                assert first["reset"] is True
                turns = [x["key"] for x in first["rows"] if x["table"] == "turns"]
                assert turns == [f"1.{k}" for k in range(1, 6)]
                assert await p.play(3) == "turn"
                got = await detail.until(
                    lambda e: e["type"] == "rows" and any(x["key"] == "1.8" for x in e["rows"])
                )
                assert {x["key"] for x in got["rows"]} >= {"1.6", "1.7", "1.8"}
                facts = await detail.until(
                    lambda e: e["type"] == "fields" and e["fields"]["turns"] == 8
                )
                assert facts["fields"]["client"] == HOSTILE
                total = await p.finish()
                done = await detail.until(
                    lambda e: e["type"] == "fields" and e["fields"]["state"] == "finished"
                )
                assert done["fields"]["total"] == f"{total:g}" or float(
                    done["fields"]["total"]
                ) == pytest.approx(total, rel=1e-3)
                rounds = await detail.until(
                    lambda e: e["type"] == "rows" and any(x["table"] == "rounds" for x in e["rows"])
                )
                assert rounds
                # the name went by in the stream's events, never as markup
                assert b"\\u003cimg src=x onerror=alert(1)\\u003e" in detail.raw
                assert_escaped(bytes(detail.raw))
            await overview.until(lambda e: e["type"] == "fields" and e["fields"]["finished"] == 1)
            assert b"\\u003cimg src=x" in overview.raw
            assert_escaped(bytes(overview.raw))

        # every response after the session: escaped, the whole picture
        for path in (
            "/",
            "/session/1",
            "/chart/session/1.svg",
            "/chart/session/1/rewards.svg",
            "/sessions.json",
        ):
            r = await fetch(web, path)
            assert r.status == 200, path
            assert_escaped(r.body)
            assert r.headers["x-content-type-options"] == "nosniff"
        data = (await fetch(web, "/sessions.json")).json()
        assert [s["client"] for s in data] == [HOSTILE]
        assert data[0]["status"] == "finished" and data[0]["rounds_total"] == 2
        assert data[0]["total_reward"] == pytest.approx(total)
        assert data[0]["turns_total"] == 40
        svg = (await fetch(web, "/chart/session/1/rewards.svg")).text
        assert svg.startswith("<svg") and "<polyline" in svg and ESCAPED in svg
        async with events(web, "/events") as again:
            snap = await again.next()
            assert snap["reset"] and snap["rows"][0]["cells"]["state"] == "finished"
            assert snap["rows"][0]["cells"]["client"] == HOSTILE
        for path in ("/session/2", "/session/x", "/session/2/events", "/chart/session/9.svg"):
            assert (await fetch(web, path)).status == 404, path
        await p.c.close()


@pytest.mark.trio
async def test_a_failed_session_shows_its_reason_as_text() -> None:
    config = ServerConfig(port=0, rounds=1, host="127.0.0.1")
    async with web_server(config) as (port, web, view, _):
        p = await Player.start(port, "badclient")
        await p.c.send(
            b'<?xml version="1.0" encoding="UTF-8"?>\n<actions><action><action-name>'
            + xml_name(HOSTILE).encode()
            + b"</action-name><action-arg>c1</action-arg><action-value>true</action-value>"
            b"</action></actions>\0"
        )
        await p.c.expect_eof()
        await wait_for(
            lambda: (
                view.board.sessions.get(1) is not None
                and view.board.sessions[1].status != "running"
            )
        )
        rec = view.board.sessions[1]
        assert rec.status == "dropped" and HOSTILE in (rec.reason or "")
        r = await fetch(web, "/")
        assert 'data-state="failed"' in r.text and "dropped: " in r.text
        assert_escaped(r.body)
        assert ESCAPED in r.text  # the reason names the action, as text
        r = await fetch(web, "/session/1")
        assert_escaped(r.body)
        assert "dropped" in r.text
        await p.c.close()


@pytest.mark.trio
async def test_a_server_stopped_marks_running_sessions_interrupted() -> None:
    board = SessionBoard()
    config = ServerConfig(port=0, rounds=1, host="127.0.0.1")
    async with trio.open_nursery() as nursery:
        port = await nursery.start(partial(serve, config, registry(), live=board))
        p = await Player.start(port, "c")
        await p.play(2)
        await wait_for(lambda: 1 in board.sessions and board.sessions[1].turns_total == 2)
        nursery.cancel_scope.cancel()
    rec = board.sessions[1]
    assert rec.status == "interrupted" and rec.reason == "server shut down"
    await p.c.close()


@pytest.mark.alone  # 100 connections and a session played against the clock of its viewers
@pytest.mark.trio
async def test_many_viewers_some_never_reading() -> None:
    """100 viewers, half of them never reading: the session plays to its end,
    every viewer that does not read is dropped (never waited for), and the
    ones that read see the session finished."""
    feed = Feed(queue_size=4)
    # (rounds enough that what the session's page sends fills an idle viewer's
    # socket buffers and then its queue: a turn's row is its true fluents and
    # changes, a few hundred bytes)
    config = ServerConfig(port=0, rounds=30, host="127.0.0.1")
    board = SessionBoard()
    view = ServerView(board, feed)
    servers: list[WebServer] = []
    async with trio.open_nursery() as nursery:
        web = await nursery.start(
            partial(
                serve_web,
                view.routes,
                WebOptions(host="127.0.0.1", write_timeout=2.0),
                servers=servers,
            )
        )
        nursery.start_soon(view.run)
        port = await nursery.start(partial(serve, config, registry(), live=board))
        p = await Player.start(port, "watched")
        await p.play(3)
        await wait_for(lambda: 1 in board.sessions)

        idle = []
        for _ in range(50):  # connect, ask, never read
            sock = trio.socket.socket()
            sock.setsockopt(trio.socket.SOL_SOCKET, trio.socket.SO_RCVBUF, 2048)
            await sock.connect(("127.0.0.1", web))
            await sock.send(b"GET /session/1/events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            idle.append(sock)
        finished: list[int] = []

        async def reader(k: int) -> None:
            path = "/events" if k % 2 else "/session/1/events"
            async with events(web, path) as ev:
                await ev.until(
                    lambda e: (
                        e["type"] == "fields" and e["fields"].get("finished") == 1
                        if path == "/events"
                        else e["type"] == "fields" and e["fields"].get("state") == "finished"
                    ),
                    timeout=120,
                )
                finished.append(k)

        with trio.fail_after(120):
            async with trio.open_nursery() as viewers:
                for k in range(50):
                    viewers.start_soon(reader, k)
                await wait_for(lambda: feed.viewers == 100, 30)
                while True:  # the session, a turn every 10 ms
                    root = await p.play(1)
                    if root == "round-end":
                        p.rounds_left -= 1
                        if not p.rounds_left:
                            assert root_of(await p.c.recv()) == "session-end"
                            break
                        await p.c.send(ROUND_REQUEST)
                        assert root_of(await p.c.recv()) == "round-init"
                        assert root_of(await p.c.recv()) == "turn"
                    await trio.sleep(0.01)
        assert sorted(finished) == list(range(50))
        assert board.sessions[1].status == "finished" and board.sessions[1].turns_total == 600
        # every viewer that never read was dropped by the server
        await wait_for(lambda: servers[0].connections == 0, 30)
        assert servers[0].dropped == 50 and feed.viewers == 0
        with trio.fail_after(30):
            for sock in idle:  # each sees the end of its stream once it reads
                while await sock.recv(65536):
                    pass
                sock.close()
        await p.c.close()
        nursery.cancel_scope.cancel()


@pytest.mark.alone  # worker processes
@pytest.mark.trio
async def test_worker_processes_send_their_sessions_to_the_view() -> None:
    """`rddl-server --workers 2 --web 0`: sessions played in the workers show
    in the main process's view, live and when finished."""
    from .test_web_browser import start_server

    proc, port, web = start_server("--workers", "2", "--rounds", "2")
    try:
        with trio.fail_after(60):
            async with events(web, "/events") as overview:
                await overview.next()  # the snapshot
                p = await Player.start(port, xml_name(HOSTILE))
                await p.play(4)
                live = await overview.until(
                    lambda e: (
                        e["type"] == "rows" and any(x["cells"].get("turns") == 4 for x in e["rows"])
                    )
                )
                assert live["rows"][0]["cells"]["client"] == HOSTILE
                total = await p.finish()
                await p.c.close()
                await overview.until(
                    lambda e: e["type"] == "fields" and e["fields"]["finished"] == 1
                )
                other = await Player.start(port, "second")
                await other.finish()
                await other.c.close()
                await overview.until(
                    lambda e: e["type"] == "fields" and e["fields"]["finished"] == 2
                )
        data = (await fetch(web, "/sessions.json")).json()
        assert [(s["id"], s["client"], s["status"]) for s in data] == [
            (1, HOSTILE, "finished"),
            (2, "second", "finished"),
        ]
        assert data[0]["total_reward"] == pytest.approx(total)
        assert data[0]["turns_total"] == 40 and data[0]["rounds_total"] == 2
        page = await fetch(web, "/session/2")
        assert page.status == 200 and page.text.count('data-key="2.') == 20
        assert_escaped((await fetch(web, "/")).body)
    finally:
        proc.terminate()
        proc.wait(20)
