"""ippc.web's core over real sockets on 127.0.0.1: routes, limits, security
headers, the event stream and its bounded viewers, escaping, charts, options."""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import click
import pytest
import trio
from ippc.web import (
    SVG,
    EventStream,
    Feed,
    HTTPError,
    Markup,
    Request,
    Response,
    Routes,
    WebOptions,
    WebServer,
    esc,
    h,
    line_chart,
    live_table,
    page,
    row_event,
    rows_event,
    serve_web,
    sparkline,
)
from ippc.web.http import CSP

from .httpclient import HOST, events, fetch

HOSTILE = "<img src=x onerror=alert(1)>"
ESCAPED = "&lt;img src=x onerror=alert(1)&gt;"


def make_routes(feed: Feed) -> Routes:
    routes = Routes()

    @routes.route("/")
    def index(request: Request) -> Response:
        return Response(page(f"hello {HOSTILE}", h("p", HOSTILE), events="/events"))

    @routes.route("/item/{name}")
    def item(request: Request) -> Response:
        if request.params["name"] == "missing":
            raise HTTPError(404, "no such item")
        return Response(h("p", request.params["name"], request.query.get("q", "")))

    @routes.route("/chart.svg")
    def chart(request: Request) -> Response:
        return Response(line_chart({HOSTILE: [1.0, 2.0, 3.0]}, title=HOSTILE), content_type=SVG)

    routes.add(
        "/events",
        lambda r: EventStream(
            feed, ["a"], lambda: [rows_event([("t", 1, {"x": HOSTILE})], reset=True)]
        ),
    )
    return routes


@asynccontextmanager
async def running(
    feed: Feed | None = None, **opts: Any
) -> AsyncIterator[tuple[int, WebServer, Feed]]:
    feed = feed or Feed()
    servers: list[WebServer] = []
    async with trio.open_nursery() as nursery:
        port = await nursery.start(
            lambda task_status: serve_web(
                make_routes(feed),
                WebOptions(host=HOST, **opts),
                servers=servers,
                task_status=task_status,
            )
        )
        try:
            yield port, servers[0], feed
        finally:
            nursery.cancel_scope.cancel()


@pytest.mark.trio
async def test_page_headers_and_escaping() -> None:
    async with running() as (port, _, _):
        r = await fetch(port, "/")
        assert r.status == 200
        assert r.headers["content-type"] == "text/html; charset=utf-8"
        assert r.headers["content-security-policy"] == CSP
        assert "script-src 'self'" in CSP and "unsafe-inline" not in CSP
        assert r.headers["x-content-type-options"] == "nosniff"
        assert r.headers["cache-control"] == "no-store"
        assert HOSTILE not in r.text and r.text.count(ESCAPED) == 3  # title, h1, p
        assert "<script>" not in r.text  # no inline script: live.js comes from /static
        assert '<script src="/static/live.js" defer></script>' in r.text
        r = await fetch(port, "/item/%3Cb%3E?q=%3Ci%3E")
        assert r.status == 200 and r.text == "<p>&lt;b&gt;&lt;i&gt;</p>"
        r = await fetch(port, "/chart.svg")
        assert r.headers["content-type"] == SVG and HOSTILE not in r.text and ESCAPED in r.text
        head = await fetch(port, "/", method="HEAD")
        assert head.status == 200 and head.body == b""
        head = await fetch(port, "/events", method="HEAD")
        assert head.status == 200 and head.body == b""
        assert head.headers["content-type"].startswith("text/event-stream")


@pytest.mark.trio
async def test_static_files() -> None:
    async with running() as (port, _, _):
        js = await fetch(port, "/static/live.js")
        assert js.status == 200 and js.headers["content-type"].startswith("text/javascript")
        assert "textContent" in js.text and "innerHTML" not in js.text
        css = await fetch(port, "/static/style.css")
        assert css.status == 200 and css.headers["content-type"].startswith("text/css")
        for bad in (
            "/static/../__init__.py",
            "/static/%2e%2e%2f__init__.py",
            "/static/feed.py",
            "/static/nope.js",
        ):
            assert (await fetch(port, bad)).status == 404, bad


@pytest.mark.trio
async def test_errors_and_limits() -> None:
    async with running(header_timeout=0.5, max_request=2048) as (port, server, _):
        assert (await fetch(port, "/nowhere")).status == 404
        r = await fetch(port, "/item/missing")
        assert r.status == 404 and r.text == "no such item\n"
        r = await fetch(port, "/", method="POST", body=b"x=1")
        assert r.status == 405 and r.headers["allow"] == "GET, HEAD"
        assert (await fetch(port, "/", body=b"x" * 5000)).status == 413
        assert (await fetch(port, "/", headers={"X-Big": "y" * 4000})).status == 431
        # DNS rebinding: a page of another site under a name that resolves to 127.0.0.1
        assert (await fetch(port, "/", headers={"Host": "evil.example:80"})).status == 421
        assert (await fetch(port, "/", headers={"Host": f"localhost:{port}"})).status == 200
        # a request that never finishes its headers: 408 after header_timeout
        with trio.fail_after(5):
            stream = await trio.open_tcp_stream(HOST, port)
            async with stream:
                await stream.send_all(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")
                data = b""
                while chunk := await stream.receive_some(4096):
                    data += chunk
        assert data.startswith(b"HTTP/1.1 408 ")
        # garbage
        with trio.fail_after(5):
            stream = await trio.open_tcp_stream(HOST, port)
            async with stream:
                await stream.send_all(b"\x00\x01 nonsense\r\n\r\n")
                data = await stream.receive_some(4096)
        assert data.startswith(b"HTTP/1.1 400 ")
        with trio.fail_after(5):
            while server.connections:
                await trio.sleep(0.01)


@pytest.mark.trio
async def test_keep_alive_two_requests_one_connection() -> None:
    async with running() as (port, server, _):
        with trio.fail_after(5):
            stream = await trio.open_tcp_stream(HOST, port)
            async with stream:
                req = b"GET /item/a HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
                await stream.send_all(req + req.replace(b"/a", b"/b"))
                data = b""
                while data.count(b"</p>") < 2:
                    data += await stream.receive_some(4096)
                assert server.connections == 1
        assert b"<p>a</p>" in data and b"<p>b</p>" in data


@pytest.mark.trio
async def test_connection_cap() -> None:
    async with running(max_connections=2) as (port, server, _):
        with trio.fail_after(5):
            a = await trio.open_tcp_stream(HOST, port)
            b = await trio.open_tcp_stream(HOST, port)
            while server.connections < 2:
                await trio.sleep(0.01)
            c = await trio.open_tcp_stream(HOST, port)
            data = await c.receive_some(4096)
            assert data.startswith(b"HTTP/1.1 503 ")
            assert server.refused == 1
            for s in (a, b, c):
                await s.aclose()
            while server.connections:
                await trio.sleep(0.01)
        assert (await fetch(port, "/item/x")).status == 200


@pytest.mark.trio
async def test_event_stream_snapshot_then_events_of_its_topic() -> None:
    async with running() as (port, _, feed):
        async with events(port, "/events") as ev:
            assert ev.reply.status == 200
            assert ev.reply.headers["content-type"].startswith("text/event-stream")
            assert ev.reply.headers["cache-control"] == "no-store"
            first = await ev.next()
            assert first == {
                "type": "rows",
                "reset": True,
                "rows": [{"table": "t", "key": "1", "cells": {"x": HOSTILE}}],
            }
            with trio.fail_after(5):
                while not feed.watched("a"):
                    await trio.sleep(0.01)
            feed.publish(row_event("t", 2, {"x": "other topic"}), "b")
            feed.publish(row_event("t", 3, {"x": 1.5, "y": float("nan")}), "a")
            got = await ev.next()
            assert got["rows"] == [{"table": "t", "key": "3", "cells": {"x": "1.5", "y": "nan"}}]
        with trio.fail_after(5):
            while feed.watched("a"):
                await trio.sleep(0.01)


@pytest.mark.trio
async def test_a_viewer_that_does_not_read_is_dropped() -> None:
    feed = Feed(queue_size=8)
    async with running(feed) as (port, server, _):
        reader_events: list[dict[str, Any]] = []
        with trio.fail_after(20):
            idle = await trio.open_tcp_stream(HOST, port)  # never reads
            await idle.send_all(b"GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            async with events(port, "/events") as ev:
                await ev.next()  # the snapshot
                while feed.viewers < 2:
                    await trio.sleep(0.01)
                big = "z" * 20_000
                for k in range(200):
                    feed.publish(row_event("t", k, {"x": big}), "a")  # returns at once
                    if k % 4 == 3:
                        # the reader keeps up; the idle viewer's socket fills, then its queue
                        for _ in range(4):
                            reader_events.append(await ev.next())
                assert feed.dropped == 1
                while feed.viewers > 1 or server.connections > 1:
                    await trio.sleep(0.01)
            await idle.aclose()
        assert [e["rows"][0]["key"] for e in reader_events] == [str(k) for k in range(200)]


def test_publish_never_raises(caplog: pytest.LogCaptureFixture) -> None:
    async def main() -> None:
        feed = Feed()
        with feed.subscribe(["a"]) as sub:
            with caplog.at_level(logging.ERROR, logger="ippc.web.feed"):
                feed.publish({"bad": object()}, "a")  # not JSON
            feed.publish({"good": 1}, "a")
            assert await sub.next_batch() == [b'data: {"good":1}\n\n']
        feed.publish({"nobody": 1}, "a")  # no viewer: nothing happens

    trio.run(main)
    assert "not sent" in caplog.text


def test_html_escapes_everything() -> None:
    assert esc(HOSTILE) == ESCAPED
    assert esc('"') == "&quot;" and esc(None) == ""
    assert (
        h("td", HOSTILE, title=HOSTILE) == f'<td title="{ESCAPED.replace("=", "=")}">{ESCAPED}</td>'
    )
    assert h("p", Markup("<b>ok</b>")) == "<p><b>ok</b></p>"
    assert Markup("<b>") + HOSTILE == "<b>" + ESCAPED
    with pytest.raises(ValueError):
        h("p onclick=x")
    with pytest.raises(ValueError):
        h("p", **{"on click": "x"})
    table = live_table(
        "s",
        [("id", "session"), ("client", HOSTILE), ("chart", "chart")],
        [(HOSTILE, {"id": 1, "client": HOSTILE, "rounds": 2, "state": HOSTILE})],
        links={"id": "/session/{key}"},
        charts={"chart": ("/chart/{key}.svg", "rounds")},
    )
    assert HOSTILE not in table
    assert 'href="/session/%3Cimg%20src%3Dx%20onerror%3Dalert%281%29%3E"' in table
    for svg in (
        sparkline([1.0, float("nan"), 2.0], label=HOSTILE),
        line_chart({HOSTILE: [1.0]}, x_label=HOSTILE),
    ):
        assert svg.startswith("<svg") and HOSTILE not in svg and ESCAPED in svg


def test_web_options() -> None:
    assert WebOptions.from_cli(None, None) is None
    assert WebOptions.from_cli(8080, None) == WebOptions(port=8080, host="127.0.0.1")
    assert WebOptions.from_cli(0, "::1") == WebOptions(port=0, host="::1")
    for web, host in ((None, "127.0.0.1"), (70000, None), (80, "not an address")):
        with pytest.raises(click.BadParameter):
            WebOptions.from_cli(web, host)


def test_a_cell_with_its_own_state_and_link() -> None:
    from ippc.web import cell

    table = live_table(
        "grid",
        [("name", "name"), ("job", "job")],
        [("k", {"name": HOSTILE, "job": cell(HOSTILE, state="failed", href="/job/a%40b")})],
        state_field=None,
    )
    assert HOSTILE not in table and table.count(ESCAPED) == 2
    assert '<td data-field="job" data-state="failed"><a href="/job/a%40b">' in table
    assert cell(1.23456789, state="running") == {"text": "1.235", "state": "running"}
    for bad in ("//evil.example/x", "javascript:alert(1)", "http://x/"):
        with pytest.raises(ValueError):
            cell("x", href=bad)
    # the event carries the cell as it is (live.js sets its text, state and link)
    event = rows_event([("grid", "k", {"job": cell("done", state="finished", href="/j")})])
    assert event["rows"][0]["cells"]["job"] == {"text": "done", "state": "finished", "href": "/j"}


def test_a_page_names_its_layout_and_a_sparkline_its_scale() -> None:
    assert 'data-layout="abc"' in page("t", layout="abc", events="/events")
    assert "data-layout" not in page("t")
    svg = sparkline([3.0, -2.5, 7.25], label="rewards", x_start=4)
    # the highest and lowest value at the left, the first and last index below
    for label in (">7.25</text>", ">-2.5</text>", ">4</text>", ">6</text>"):
        assert label in svg, label
