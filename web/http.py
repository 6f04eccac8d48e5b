"""A small read-only HTTP/1.1 server on trio (h11 does the protocol).

Theory of operation. `serve_web(routes, options)` listens (127.0.0.1 unless
told otherwise) and runs one task per connection in the caller's nursery,
so a page is served from the same process and event loop as the service it
shows, from its in-memory state. h11 parses the requests and frames the
responses; this module owns the socket, the deadlines and the bounds:

- GET and HEAD only (405 otherwise); a request line and headers of at most
  `max_request` bytes, complete within `header_timeout` seconds (408), a
  body of at most 1 KiB (413); at most `max_connections` open connections
  (a connection over the cap gets 503 and is closed at once); an idle
  keep-alive connection is closed after `header_timeout`.
- On a loopback address the Host header must name a loopback host
  (a page of another site that rebinds its DNS name to 127.0.0.1 cannot
  read the view).
- Every response carries a Content-Security-Policy that allows scripts,
  styles, images and event streams from this server only and no inline
  script, `X-Content-Type-Options: nosniff`, no framing, no referrer, and
  `Cache-Control: no-store` (static files: `no-cache`).
- A route's handler is a plain function of the `Request` that returns a
  `Response` or an `EventStream`; handlers read in-memory state and never
  wait. An `EventStream` subscribes to a `Feed`: the connection's task
  writes the viewer's events as they come (each write bounded by
  `write_timeout`), a comment every `heartbeat` seconds, and ends when the
  viewer falls behind (see `feed.py`).
"""

from __future__ import annotations

import ipaddress
import logging
import os
import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from http import HTTPStatus
from importlib import resources
from typing import Any
from urllib.parse import parse_qsl, unquote, urlsplit

import h11
import trio

from .feed import Feed
from .options import WebOptions

log = logging.getLogger(__name__)

CSP = (
    "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self';"
    " connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
)
SECURITY_HEADERS = (
    ("Content-Security-Policy", CSP),
    ("X-Content-Type-Options", "nosniff"),
    ("X-Frame-Options", "DENY"),
    ("Referrer-Policy", "no-referrer"),
    ("Cross-Origin-Resource-Policy", "same-origin"),
    ("Cross-Origin-Opener-Policy", "same-origin"),
)
HTML = "text/html; charset=utf-8"
SVG = "image/svg+xml"
JSON = "application/json"
TEXT = "text/plain; charset=utf-8"
_MAX_BODY = 1024
_LOOPBACK_NAMES = {"localhost", "localhost.", "127.0.0.1", "[::1]"}
_TYPES = {
    ".js": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".svg": "image/svg+xml",
}


@dataclass(frozen=True)
class Request:
    """A GET or HEAD request: the decoded path, its query, the headers (names
    lower case) and the route's `{name}` parts (`params`)."""

    method: str
    path: str
    query: Mapping[str, str] = field(default_factory=dict)
    headers: Mapping[str, str] = field(default_factory=dict)
    params: Mapping[str, str] = field(default_factory=dict)


@dataclass
class Response:
    """A whole response. `body` may be text (encoded as UTF-8)."""

    body: bytes | str = b""
    status: int = 200
    content_type: str = HTML
    headers: list[tuple[str, str]] = field(default_factory=list)
    cache: str = "no-store"


@dataclass
class EventStream:
    """A response that streams server-sent events: the events of `topics`
    published on `feed`, after `snapshot()` (called at connect time)."""

    feed: Feed
    topics: Iterable[str]
    snapshot: Callable[[], Iterable[Mapping[str, Any]]] = lambda: ()


class HTTPError(Exception):
    """Raised by a handler: answer with this status and a short text."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status
        self.message = message


def not_found(what: str) -> HTTPError:
    return HTTPError(404, f"not found: {what}")


Handler = Callable[[Request], "Response | EventStream"]


class Routes:
    """Paths to handlers. A pattern is a path whose segments may be `{name}`
    (one segment, any text but '/'): `routes.add("/session/{id}", page)`.
    `/static/<file>` serves this package's static folder (live.js, the
    stylesheet)."""

    def __init__(self) -> None:
        self._routes: list[tuple[re.Pattern[str], Handler]] = []

    def add(self, pattern: str, handler: Handler) -> None:
        if not pattern.startswith("/"):
            raise ValueError(f"a route starts with '/': {pattern!r}")
        regex = "".join(
            f"(?P<{part[1:-1]}>[^/]+)"
            if part.startswith("{") and part.endswith("}")
            else re.escape(part)
            for part in re.split(r"(\{[a-z_]+\})", pattern)
        )
        self._routes.append((re.compile(f"^{regex}$"), handler))

    def route(self, pattern: str) -> Callable[[Handler], Handler]:
        """`add` as a decorator."""

        def register(handler: Handler) -> Handler:
            self.add(pattern, handler)
            return handler

        return register

    def resolve(self, request: Request) -> Response | EventStream:
        if request.path.startswith("/static/"):
            return static_file(request.path[len("/static/") :])
        if request.path == "/favicon.ico":
            return static_file("icon.svg")
        for regex, handler in self._routes:
            m = regex.match(request.path)
            if m:
                params = {k: unquote(v) for k, v in m.groupdict().items()}
                return handler(
                    Request(request.method, request.path, request.query, request.headers, params)
                )
        raise not_found(request.path)


_static_cache: dict[str, bytes] = {}


def static_file(name: str) -> Response:
    """A file of the package's static folder (no subfolders)."""
    suffix = name[name.rfind(".") :] if "." in name else ""
    if "/" in name or "\\" in name or name.startswith(".") or suffix not in _TYPES:
        raise not_found(name)
    data = _static_cache.get(name)
    if data is None:
        try:
            data = (resources.files("ippc.web") / "static" / name).read_bytes()
        except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
            raise not_found(name) from None
        _static_cache[name] = data
    return Response(data, content_type=_TYPES[suffix], cache="no-cache")


def is_loopback(host: str) -> bool:
    """Whether `host` (an address or 'localhost') is this machine only."""
    if host in ("localhost", ""):
        return host == "localhost"
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class WebServer:
    """The HTTP side of one `serve_web` (its counters are for tests and
    pages: `connections` open, `refused` over the cap, `dropped` viewers
    that did not read)."""

    def __init__(self, routes: Routes, options: WebOptions):
        self.routes = routes
        self.options = options
        self.connections = 0
        self.refused = 0
        self.dropped = 0  # viewers dropped for not reading (queue full, or a write timed out)
        self.port: int | None = None
        self.check_host = is_loopback(options.host)

    async def serve(self, *, task_status: trio.TaskStatus[int] = trio.TASK_STATUS_IGNORED) -> None:
        opts = self.options
        listeners = await trio.open_tcp_listeners(opts.port or 0, host=opts.host)
        self.port = listeners[0].socket.getsockname()[1]
        if not is_loopback(opts.host):
            log.warning(
                "web view on %s:%d: reachable from other machines (--web-host); it shows client"
                " and instance names, has no login, and takes no input",
                opts.host,
                self.port,
            )
        else:
            log.debug("web view on http://%s:%d/", _url_host(opts.host), self.port)
        async with trio.open_nursery() as nursery:
            for listener in listeners:
                nursery.start_soon(self._accept, listener, nursery)
            task_status.started(self.port)

    async def _accept(self, listener: trio.SocketListener, nursery: trio.Nursery) -> None:
        async with listener:
            while True:
                try:
                    stream = await listener.accept()
                except OSError as err:  # e.g. out of file descriptors: wait, go on
                    log.warning("web view: accept failed: %s", err)
                    await trio.sleep(0.1)
                    continue
                if self.connections >= self.options.max_connections:
                    self.refused += 1
                    _refuse(stream)
                    continue
                self.connections += 1
                nursery.start_soon(self._connection, stream)

    async def _connection(self, stream: trio.SocketStream) -> None:
        try:
            await self._serve_connection(stream)
        except (trio.BrokenResourceError, trio.ClosedResourceError, trio.TooSlowError, OSError):
            pass  # the viewer went away, or did not read
        except Exception:  # a bug of a page: this connection only
            log.exception("web view: a request failed")
        finally:
            self.connections -= 1
            with trio.CancelScope(shield=True):
                with trio.move_on_after(1):
                    await stream.aclose()

    async def _serve_connection(self, stream: trio.SocketStream) -> None:
        opts = self.options
        conn = h11.Connection(h11.SERVER, max_incomplete_event_size=opts.max_request)
        while True:
            try:
                with trio.move_on_after(opts.header_timeout) as waited:
                    request = await _read_request(conn, stream, opts.max_request)
                if waited.cancelled_caught:
                    # (an idle keep-alive connection gets it too: browsers retry)
                    await self._send(conn, stream, "GET", _error(408, "request timeout"))
                    return
            except _TooLarge as err:
                await self._send(conn, stream, "GET", _error(err.status, err.message))
                return
            except h11.RemoteProtocolError as err:
                if conn.our_state in (h11.IDLE, h11.SEND_RESPONSE):
                    status = err.error_status_hint
                    await self._send(conn, stream, "GET", _error(status, "bad request"))
                return
            if request is None:
                return  # the viewer closed the connection
            response = self._respond(request)
            if isinstance(response, EventStream) and request.method == "HEAD":
                response = Response(b"", content_type="text/event-stream; charset=utf-8")
            if isinstance(response, EventStream):
                await self._stream_events(conn, stream, response)
                return
            await self._send(conn, stream, request.method, response)
            if conn.our_state is not h11.DONE or conn.their_state is not h11.DONE:
                return
            conn.start_next_cycle()

    def _respond(self, request: Request) -> Response | EventStream:
        if request.method not in ("GET", "HEAD"):
            r = _error(405, "method not allowed: this view only reads")
            r.headers.append(("Allow", "GET, HEAD"))
            return r
        if self.check_host and not _loopback_host(request.headers.get("host", "")):
            return _error(421, "this view answers only to localhost addresses")
        try:
            return self.routes.resolve(request)
        except HTTPError as err:
            return _error(err.status, err.message)

    async def _send(
        self, conn: h11.Connection, stream: trio.SocketStream, method: str, response: Response
    ) -> None:
        if conn.our_state not in (h11.IDLE, h11.SEND_RESPONSE):
            return
        body = response.body.encode("utf-8") if isinstance(response.body, str) else response.body
        headers = _headers(response.content_type, response.cache, response.headers)
        headers.append(("Content-Length", str(len(body))))
        try:
            data = conn.send(
                h11.Response(
                    status_code=response.status, headers=headers, reason=_reason(response.status)
                )
            )
        except h11.LocalProtocolError:
            return  # (h11 takes no response in this state: just close)
        if method != "HEAD" and body:
            data += conn.send(h11.Data(data=body))
        data += conn.send(h11.EndOfMessage())
        with trio.move_on_after(self.options.write_timeout):
            await stream.send_all(data)
            return
        conn.send_failed()

    async def _stream_events(
        self, conn: h11.Connection, stream: trio.SocketStream, events: EventStream
    ) -> None:
        opts = self.options
        headers = _headers("text/event-stream; charset=utf-8", "no-store", [])
        headers.append(("X-Accel-Buffering", "no"))
        head = conn.send(h11.Response(status_code=200, headers=headers, reason=b"OK"))
        with events.feed.subscribe(events.topics, events.snapshot()) as sub:
            async with trio.open_nursery() as nursery:
                sub.scope = nursery.cancel_scope  # the feed cancels it when the viewer falls behind
                nursery.start_soon(_watch_close, stream, nursery.cancel_scope)
                data = head + conn.send(h11.Data(data=b"retry: 2000\n\n"))
                while True:
                    try:
                        with trio.fail_after(opts.write_timeout):
                            await stream.send_all(data)
                    except trio.TooSlowError:
                        self.dropped += 1  # a viewer that does not read
                        nursery.cancel_scope.cancel()
                        break
                    except (trio.BrokenResourceError, trio.ClosedResourceError, OSError):
                        nursery.cancel_scope.cancel()  # the viewer is gone
                        break
                    data = b": ping\n\n"  # (a comment: keeps proxies and dead peers in check)
                    with trio.move_on_after(opts.heartbeat):
                        batch = await sub.next_batch()
                        if not batch:
                            nursery.cancel_scope.cancel()  # overflowed, or the feed closed
                            break
                        data = b"".join(batch)
                    data = conn.send(h11.Data(data=data))
            if sub.overflowed:
                self.dropped += 1
                log.info("web view: a viewer that fell behind was dropped")


async def _watch_close(stream: trio.SocketStream, scope: trio.CancelScope) -> None:
    """End an event stream as soon as its viewer closes the connection (what
    it sends meanwhile is ignored; a stream has no more requests)."""
    try:
        while await stream.receive_some(4096):
            pass
    except (trio.BrokenResourceError, trio.ClosedResourceError, OSError):
        pass
    scope.cancel()


class _TooLarge(Exception):
    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status
        self.message = message


async def _read_request(
    conn: h11.Connection, stream: trio.SocketStream, max_request: int
) -> Request | None:
    """The next request, its body read and dropped; None if the peer closed.
    (h11 bounds what it buffers of an unfinished head; a head that came
    whole is measured here.)"""
    request: h11.Request | None = None
    body = 0
    while True:
        event = conn.next_event()
        if event is h11.NEED_DATA:
            data = await stream.receive_some(16384)
            conn.receive_data(data)
            continue
        if isinstance(event, h11.ConnectionClosed) or event is h11.PAUSED:
            return None
        if isinstance(event, h11.Request):
            request = event
            size = len(event.target) + sum(len(k) + len(v) + 4 for k, v in event.headers)
            if size > max_request:
                raise _TooLarge(431, "request header fields too large")
        elif isinstance(event, h11.Data):
            body += len(event.data)
            if body > _MAX_BODY:
                raise _TooLarge(413, "request body too large")
        elif isinstance(event, h11.EndOfMessage):
            assert request is not None
            return _request(request)


def _request(event: h11.Request) -> Request:
    target = event.target.decode("latin-1")
    parts = urlsplit(target)
    headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in event.headers}
    return Request(
        method=event.method.decode("ascii", "replace"),
        path=unquote(parts.path) or "/",
        query=dict(parse_qsl(parts.query)),
        headers=headers,
    )


def _headers(
    content_type: str, cache: str, extra: Iterable[tuple[str, str]]
) -> list[tuple[str, str]]:
    return [
        ("Content-Type", content_type),
        ("Cache-Control", cache),
        *SECURITY_HEADERS,
        *extra,
    ]


def _reason(status: int) -> bytes:
    try:
        return HTTPStatus(status).phrase.encode("ascii")
    except ValueError:
        return b""


def _error(status: int, message: str) -> Response:
    return Response(message + "\n", status=status, content_type=TEXT)


def _refuse(stream: trio.SocketStream) -> None:
    """Over the connection cap: a 503 if the socket takes it at once, then close."""
    sock = stream.socket
    try:  # (trio's sockets are non-blocking: this never waits)
        os.write(
            sock.fileno(),
            b"HTTP/1.1 503 Service Unavailable\r\nContent-Length: 0\r\nConnection: close\r\n"
            b"Retry-After: 5\r\n\r\n",
        )
    except OSError:
        pass
    sock.close()


def _loopback_host(host: str) -> bool:
    host = host.strip().lower()
    if host.startswith("["):
        name = host[: host.find("]") + 1]
    else:
        name = host.rsplit(":", 1)[0] if ":" in host else host
    return name in _LOOPBACK_NAMES or (name.startswith("127.") and is_loopback(name))


def _url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


async def serve_web(
    routes: Routes,
    options: WebOptions,
    *,
    task_status: trio.TaskStatus[int] = trio.TASK_STATUS_IGNORED,
    servers: list[WebServer] | None = None,
) -> None:
    """Serve `routes` until cancelled; reports the bound port through
    `task_status` (start it with `await nursery.start(serve_web, routes,
    options)`). The `WebServer` is appended to `servers` if given."""
    server = WebServer(routes, options)
    if servers is not None:
        servers.append(server)
    await server.serve(task_status=task_status)


__all__ = [
    "CSP",
    "EventStream",
    "HTML",
    "HTTPError",
    "JSON",
    "Request",
    "Response",
    "Routes",
    "SVG",
    "TEXT",
    "WebServer",
    "is_loopback",
    "not_found",
    "serve_web",
    "static_file",
]
