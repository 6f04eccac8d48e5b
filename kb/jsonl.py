"""A JSON-lines request/reply protocol over TCP, on trio.

One JSON object per line, UTF-8, `\\n`-terminated, both ways:

* request: ``{"id": 7, "method": "kb.get", "params": {...}}`` (`params` may be
  left out; `id` is any JSON number or string the client chooses);
* reply: ``{"id": 7, "result": ...}`` or
  ``{"id": 7, "error": {"code": "bad-params", "message": "..."}}``;
* event (sent by the server when it chooses: a subscription, a dispatch to a
  remote action handler): ``{"event": "kb.changed", ...}``.

Theory of operation. The server owns no protocol logic of its own beyond
this framing: modules `register` methods on it (the knowledge base's
`kb.*`, the dispatcher's `sensing.*` and `handlers.*`). Each connection
has one task that reads lines and one that writes: everything sent to a
connection (replies and events, from any task or thread) goes through one
bounded queue, so lines never interleave, and a client that stops reading
is dropped once its queue is full instead of stalling the server.

Requests of one connection are handled in the order they arrive: a plain
function runs before the next line is read, so a controller's updates apply
in the order it sent them; a coroutine function runs in its own task, so a
slow one (waiting for a robot) does not hold up the rest, and its reply
comes when it is done.

Nothing a client sends or does ends the server: a reset, or a client gone
with replies unread, ends its own connection only. A line that is not
JSON, not an object, names no known method, has bad params, is too long, or
whose handler raises, gets an error reply (with the request's id when it
had one, else null) and the connection reads on. Error codes:
``parse-error``, ``bad-request``, ``unknown-method``, ``bad-params``,
``line-too-long``, ``too-deep`` (arrays and objects nested more than
`MAX_DEPTH`), ``internal-error``, or the `code` of the exception the
handler raised (`RequestError`, or any exception with a string `code`, such
as `KBError`'s).
"""

from __future__ import annotations

import inspect
import itertools
import json
import logging
import math
import re
import threading
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass
from typing import Any

import trio

from ..server.limits import AcceptPacer, BufferBudget, ConnectionTable, Notices, parse_networks
from ..server.listener import accept_connections

log = logging.getLogger(__name__)

DEFAULT_HOST = "127.0.0.1"
MAX_LINE = 1 << 20  # bytes; longer lines are refused (and skipped to their end)
MAX_DEPTH = 32  # arrays and objects in arrays and objects; deeper requests are refused
QUEUE_SIZE = 10_000  # events a `JsonlClient` keeps unread
# bytes of replies and events queued for one connection before it counts as
# not reading and is closed
MAX_QUEUED = 4 * 1024 * 1024
# a connection's requests wait (unread, in the kernel) while this many bytes
# of its replies are queued: a client that pipelines without reading slows
# down to its own pace instead of filling the server's memory
HIGH_WATER = 256 * 1024
MAX_RUNNING = 100  # coroutine requests of one connection under way at once


@dataclass(frozen=True)
class SocketLimits:
    """What a JSON-lines server allows its clients (safe by default; see
    docs/robot.md, "Exposing the knowledge base's socket").

    `max_connections` open at once (per address: `max_connections_per_address`,
    default the same), from the networks of `allow` only (CIDR; empty: any
    address), at most `accept_rate` new ones a second (0: no pacing);
    `max_buffered` bytes of queued replies and events and of unread input
    over all connections (the connection that would exceed it is closed);
    `max_queued` such bytes for one connection."""

    max_connections: int = 64
    max_connections_per_address: int | None = None
    allow: tuple[str, ...] = ()
    accept_rate: float = 50.0
    max_buffered: int = 32 * 1024 * 1024
    max_queued: int = MAX_QUEUED


Handler = Callable[[dict[str, Any], "Connection"], Any]


class RequestError(Exception):
    """Raised by a handler: the request gets an error reply with `code`."""

    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code = code


def encode(obj: Any) -> bytes:
    """One protocol line: compact JSON (non-finite floats as strings
    "inf"/"-inf"/"nan", which plain JSON cannot carry), then a newline."""
    return (json.dumps(_finite(obj), separators=(",", ":"), allow_nan=False) + "\n").encode()


def _finite(obj: Any) -> Any:
    if isinstance(obj, float) and not math.isfinite(obj):
        return "nan" if obj != obj else ("inf" if obj > 0 else "-inf")
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


def _why(err: BaseException) -> str:
    """What a stream error says (trio's wrap the OSError under it)."""
    cause = err.__cause__ or err.__context__
    if isinstance(cause, OSError) and not str(err):
        return str(cause)
    return str(err) or type(err).__name__


def too_deep(line: bytes, limit: int) -> bool:
    """Whether the JSON text `line` nests arrays and objects deeper than
    `limit` (brackets inside strings do not count). Linear in the line: the
    parser recurses once per level, and Python's recursion limit is no
    bound to meet from a socket."""
    if line.count(b"[") + line.count(b"{") <= limit:
        return False
    depth = 0
    pos = 0
    while (m := _TOKEN.search(line, pos)) is not None:
        c = m.group()
        if c == b'"':
            end = _STRING_REST.match(line, m.end())
            if end is None:
                return False  # an unterminated string: not JSON, the parser says so
            pos = end.end()
            continue
        pos = m.end()
        if c in (b"[", b"{"):
            depth += 1
            if depth > limit:
                return True
        else:
            depth -= 1
    return False


_TOKEN = re.compile(rb'[\[\]{}"]')
_STRING_REST = re.compile(rb'[^"\\]*+(?:\\.[^"\\]*+)*+"', re.DOTALL)


def error_reply(rid: Any, code: str, message: str) -> dict[str, Any]:
    return {"id": rid, "error": {"code": code, "message": message}}


@dataclass
class Method:
    """A registered method: its handler and a one-line description."""

    name: str
    handler: Handler
    doc: str
    is_async: bool


class Connection:
    """One client connection, as handlers see it.

    `send_event` queues an event from the trio thread; `post` queues any
    object from any thread (a knowledge-base subscriber called by a sensing
    thread). `state` is a dict where modules keep what they attach to a
    connection; `on_close` callbacks run once, when it ends, for whatever
    reason."""

    _ids = itertools.count(1)

    def __init__(
        self,
        peer: str,
        token: trio.lowlevel.TrioToken,
        budget: BufferBudget | None = None,
        max_queued: int = MAX_QUEUED,
        notices: Notices | None = None,
    ):
        self.id = next(self._ids)
        self.peer = peer
        self.state: dict[str, Any] = {}
        self.closed = False
        self._token = token
        self._thread = threading.get_ident()
        self._send, self._receive = trio.open_memory_channel[bytes](math.inf)
        self._close_callbacks: list[Callable[[Connection], None]] = []
        self._cancel = trio.CancelScope()
        self._budget = budget
        self._max_queued = max_queued
        self._notices = notices
        self.queued = 0  # bytes of replies and events not yet sent
        self.unread = 0  # bytes received that are not yet a whole request
        self._held = 0  # of them, drawn from the shared budget
        self._drained = trio.Event()  # set when `queued` falls below HIGH_WATER
        # the open connection holding the most of the budget (the server's)
        self._biggest: Callable[[], Connection | None] | None = None

    def __repr__(self) -> str:
        return f"Connection({self.id}, {self.peer})"

    def send_event(self, event: str, fields: dict[str, Any] | None = None) -> None:
        """Queue ``{"event": event, **fields}`` for this client."""
        self.post({"event": event, **(fields or {})})

    def post(self, obj: Any) -> None:
        """Queue one line for this client, from any thread; dropped once
        the connection is closed."""
        if self.closed:
            return
        data = encode(obj)
        if threading.get_ident() == self._thread:
            self._put(data)
        else:
            # Never wait for the trio thread: it may itself be waiting for
            # the thread that is posting (a lock, a join).
            try:
                self._token.run_sync_soon(self._put, data)
            except trio.RunFinishedError:
                pass

    def _put(self, data: bytes) -> None:
        if self.closed:
            return
        if self.queued + len(data) > self._max_queued:
            self._drop(
                "connections closed: not reading",
                f"{self}: not reading ({self.queued:,} bytes queued, at most "
                f"{self._max_queued:,}): closing it",
            )
            return
        self.queued += len(data)
        if not self._charge():
            return
        try:
            self._send.send_nowait(data)
        except (trio.BrokenResourceError, trio.ClosedResourceError):
            pass

    def _sent(self, n: int) -> None:
        self.queued -= n
        self._charge()
        if self.queued < HIGH_WATER:
            self._drained.set()

    def _charge(self) -> bool:
        """Draw this connection's buffered bytes from the shared budget.
        When the budget cannot give them, the connection that holds the
        most of it is closed (this one, or a bigger one, which makes room);
        False when it is this one."""
        if self._budget is None or self.closed:
            return not self.closed
        while True:
            held = self._budget.charge(self._held, self.queued + self.unread)
            if held is not None:
                self._held = held
                return True
            victim = self._biggest() if self._biggest is not None else self
            if victim is None or victim._held <= self.queued + self.unread - self._held:
                victim = self
            victim._drop(
                "connections closed: over the budget of queued replies and unread input",
                f"{victim}: closed: it holds {victim.queued + victim.unread:,} bytes of queued "
                f"replies and unread input, the most of the server's budget "
                f"({self._budget.used:,} of {self._budget.limit:,} bytes in use)",
            )
            if victim is self:
                return False

    async def wait_drained(self) -> None:
        """Until fewer than HIGH_WATER bytes of replies are queued."""
        while self.queued >= HIGH_WATER and not self.closed:
            self._drained = trio.Event()
            await self._drained.wait()

    def _drop(self, cause: str, detail: str) -> None:
        if self._notices is not None:
            self._notices.note(cause, detail)
        else:
            log.warning("%s", detail)
        self.close()

    def on_close(self, callback: Callable[[Connection], None]) -> None:
        """Call `callback(connection)` when the connection ends (at once if
        it already has)."""
        if self.closed:
            callback(self)
        else:
            self._close_callbacks.append(callback)

    def close(self) -> None:
        """End the connection (its tasks stop; callbacks run)."""
        self._cancel.cancel()
        self._finish()

    def _finish(self) -> None:
        if self.closed:
            return
        self.closed = True
        self._drained.set()
        if self._budget is not None:
            self._budget.release(self._held)
            self._held = 0
        for cb in self._close_callbacks:
            try:
                cb(self)
            except Exception:
                log.exception("%s: a close callback failed", self)
        self._close_callbacks.clear()


class JsonlServer:
    """Methods by name, served to any number of connections."""

    def __init__(self, name: str = "jsonl", limits: SocketLimits | None = None) -> None:
        self.name = name
        self.limits = limits or SocketLimits()
        self.methods: dict[str, Method] = {}
        self.connections: set[Connection] = set()
        # warnings about clients, once per cause, then counted
        self.notices = Notices(logging.getLogger(f"{__name__}.{name}"))
        self.budget = BufferBudget(self.limits.max_buffered, allowance=0)
        self.register(
            "methods", self._list_methods, "the methods this server offers, with a line each"
        )

    def register(self, name: str, handler: Handler, doc: str = "") -> None:
        """Offer `handler(params, connection)` as method `name`; a plain
        function or a coroutine function, whose return value (JSON-able) is
        the result. A second registration of one name is an error."""
        if name in self.methods:
            raise ValueError(f"method '{name}' is registered already")
        is_async = inspect.iscoroutinefunction(handler)
        if not doc:
            doc = (inspect.getdoc(handler) or "").split("\n")[0]
        self.methods[name] = Method(name, handler, doc, is_async)

    def _list_methods(self, params: dict[str, Any], conn: Connection) -> list[dict[str, str]]:
        return [
            {"method": m.name, "doc": m.doc}
            for m in sorted(self.methods.values(), key=lambda m: m.name)
        ]

    def _biggest(self) -> Connection | None:
        open_ = [c for c in self.connections if not c.closed]
        return max(open_, key=lambda c: c._held, default=None)

    def broadcast(self, event: str, fields: dict[str, Any] | None = None) -> None:
        """Send an event to every open connection."""
        for conn in list(self.connections):
            conn.send_event(event, fields)

    # -- serving -----------------------------------------------------

    async def serve(
        self,
        host: str = DEFAULT_HOST,
        port: int = 0,
        *,
        task_status: trio.TaskStatus[int] = trio.TASK_STATUS_IGNORED,
    ) -> None:
        """Listen on `host`:`port` (0: any free port, reported through
        `task_status`) and serve every connection until cancelled, under
        `self.limits` through the listener rddl-server's port uses
        (`ippc.server.listener`)."""
        limits = self.limits
        total = max(1, limits.max_connections)
        per = limits.max_connections_per_address or total
        table = ConnectionTable(total, min(per, total), parse_networks(limits.allow))
        listeners = await trio.open_tcp_listeners(port, host=host)
        bound = listeners[0].socket.getsockname()[1]
        log.info("%s: listening on %s:%d", self.name, host, bound)
        async with trio.open_nursery() as nursery:
            nursery.start_soon(self.notices.run)
            nursery.start_soon(self.budget.run)

            async def handle(stream: trio.SocketStream, key: int) -> None:
                try:
                    await self.handle_stream(stream)
                finally:
                    table.remove(key)

            def take(stream: trio.SocketStream, key: int) -> bool:
                nursery.start_soon(handle, stream, key)
                return False

            pacer = AcceptPacer(limits.accept_rate)
            keys = itertools.count(1)
            for listener in listeners:
                nursery.start_soon(
                    accept_connections, listener, self.notices, table, pacer, keys, take
                )
            task_status.started(bound)

    async def handle_stream(self, stream: trio.abc.Stream) -> None:
        """Serve one connection to its end; nothing it does ends more."""
        try:
            host, cport = stream.socket.getpeername()[:2]  # type: ignore[attr-defined]
            peer = f"{host}:{cport}"
        except (AttributeError, OSError):
            peer = "?"
        conn = Connection(
            peer,
            trio.lowlevel.current_trio_token(),
            budget=self.budget,
            max_queued=self.limits.max_queued,
            notices=self.notices,
        )
        conn._biggest = self._biggest
        self.connections.add(conn)
        log.debug("%s: %s connected", self.name, conn)
        try:
            with conn._cancel:
                async with stream, trio.open_nursery() as nursery:
                    nursery.start_soon(self._writer, conn, stream)
                    async with trio.open_nursery() as requests:
                        await self._reader(conn, stream, requests)
                        # The client has closed its side: requests still under
                        # way have nobody to wait for their replies.
                        requests.cancel_scope.cancel()
                    conn._send.close()  # the writer sends what is queued, then ends
        except* (trio.BrokenResourceError, trio.ClosedResourceError, OSError) as group:
            log.info("%s: %s: %s", self.name, conn, _why(group.exceptions[0]))
        except* Exception:  # a bug: this connection ends, the server goes on
            log.exception("%s: %s failed", self.name, conn)
        finally:
            self.connections.discard(conn)
            conn._finish()
            log.debug("%s: %s closed", self.name, conn)

    async def _writer(self, conn: Connection, stream: trio.abc.Stream) -> None:
        try:
            async with conn._receive:
                async for data in conn._receive:
                    await stream.send_all(data)
                    conn._sent(len(data))
        except (trio.BrokenResourceError, trio.ClosedResourceError, OSError) as err:
            # the client reset the connection (or closed it with replies
            # unread): this connection ends, nothing else does
            log.info("%s: %s: cannot send: %s", self.name, conn, _why(err))
            conn.close()

    async def _reader(
        self, conn: Connection, stream: trio.abc.Stream, nursery: trio.Nursery
    ) -> None:
        buf = bytearray()
        skipping = False  # inside a line that was too long
        running = trio.Semaphore(MAX_RUNNING)  # coroutine requests under way
        while True:
            try:
                data = await stream.receive_some(65536)
            except (trio.BrokenResourceError, trio.ClosedResourceError, OSError) as err:
                log.info("%s: %s: cannot receive: %s", self.name, conn, _why(err))
                conn.close()
                return
            if not data:
                if buf.strip() and not skipping:
                    await self._line(conn, bytes(buf), nursery, running)
                return
            buf += data
            while True:
                conn.unread = len(buf)
                if not conn._charge():
                    return
                nl = buf.find(b"\n")
                if nl < 0:
                    if len(buf) > MAX_LINE and not skipping:
                        conn.post(
                            error_reply(
                                None, "line-too-long", f"a line longer than {MAX_LINE} bytes"
                            )
                        )
                        skipping = True
                    if skipping:
                        buf.clear()
                        conn.unread = 0
                        conn._charge()
                    break
                line = bytes(buf[:nl])
                del buf[: nl + 1]
                if skipping:
                    skipping = False
                    continue
                if len(line) > MAX_LINE:
                    conn.post(
                        error_reply(None, "line-too-long", f"a line longer than {MAX_LINE} bytes")
                    )
                    continue
                if line.strip():
                    # a client that does not read its replies waits here
                    # (its requests stay in the kernel) instead of queueing more
                    await conn.wait_drained()
                    await self._line(conn, line, nursery, running)
                    # a fair turn: the other connections' requests (and the
                    # dispatcher) run between two of this one's
                    await trio.lowlevel.checkpoint()

    async def _line(
        self, conn: Connection, line: bytes, nursery: trio.Nursery, running: trio.Semaphore
    ) -> None:
        if too_deep(line, MAX_DEPTH):
            conn.post(
                error_reply(
                    None, "too-deep", f"a request nests arrays and objects deeper than {MAX_DEPTH}"
                )
            )
            return
        try:
            request = json.loads(line)
        except (UnicodeDecodeError, json.JSONDecodeError) as err:
            conn.post(error_reply(None, "parse-error", f"not JSON: {err}"))
            return
        except RecursionError:  # (too_deep should have told)
            conn.post(error_reply(None, "too-deep", "a request nests too deep"))
            return
        if not isinstance(request, dict):
            conn.post(error_reply(None, "bad-request", "a request is a JSON object"))
            return
        rid = request.get("id")
        if isinstance(rid, (dict, list)):
            conn.post(error_reply(None, "bad-request", "'id' must be a number, a string or null"))
            return
        name = request.get("method")
        if not isinstance(name, str):
            conn.post(error_reply(rid, "bad-request", "a request needs a 'method' (a string)"))
            return
        method = self.methods.get(name)
        if method is None:
            conn.post(
                error_reply(
                    rid, "unknown-method", f"no method '{name}' (call 'methods' for the list)"
                )
            )
            return
        params = request.get("params", {})
        if params is None:
            params = {}
        if not isinstance(params, dict):
            conn.post(error_reply(rid, "bad-params", f"'{name}': params must be a JSON object"))
            return
        if method.is_async:
            await running.acquire()  # at most MAX_RUNNING at once; the next waits
            nursery.start_soon(self._run_async, conn, method, rid, params, running)
        else:
            conn.post(self._outcome(rid, name, lambda: method.handler(params, conn)))

    async def _run_async(
        self,
        conn: Connection,
        method: Method,
        rid: Any,
        params: dict[str, Any],
        running: trio.Semaphore,
    ) -> None:
        try:
            result = await method.handler(params, conn)
        except Exception as err:
            conn.post(self._error(rid, method.name, err))
            return
        finally:
            running.release()
        conn.post(self._reply(rid, method.name, result))

    def _outcome(self, rid: Any, name: str, call: Callable[[], Any]) -> dict[str, Any]:
        try:
            result = call()
        except Exception as err:
            return self._error(rid, name, err)
        return self._reply(rid, name, result)

    def _reply(self, rid: Any, name: str, result: Any) -> dict[str, Any]:
        try:
            encode(result)
        except (TypeError, ValueError) as err:
            log.error("%s: '%s' returned a result JSON cannot carry: %s", self.name, name, err)
            return error_reply(rid, "internal-error", f"'{name}': the result is not JSON: {err}")
        return {"id": rid, "result": result}

    def _error(self, rid: Any, name: str, err: Exception) -> dict[str, Any]:
        code = getattr(err, "code", None)
        if isinstance(code, str):
            return error_reply(rid, code, f"{name}: {err}")
        if isinstance(err, (KeyError, TypeError, ValueError)):
            what = f"missing param {err}" if isinstance(err, KeyError) else str(err)
            return error_reply(rid, "bad-params", f"{name}: {what}")
        log.exception("%s: method '%s' failed", self.name, name)
        return error_reply(rid, "internal-error", f"{name}: {type(err).__name__}: {err}")


# ------------------------------------------------------------------ client


class JsonlClient:
    """A client of a `JsonlServer`, for Python controllers and tests:
    `await call(method, params)` returns the result or raises
    `RequestError`; events are kept in order for `next_event`."""

    def __init__(self, stream: trio.SocketStream):
        self.stream = stream
        self._ids = itertools.count(1)
        self._waiting: dict[Any, trio.MemorySendChannel[dict[str, Any]]] = {}
        self._events_send, self._events = trio.open_memory_channel[dict[str, Any]](QUEUE_SIZE)
        self._lock = trio.Lock()

    async def call(self, method: str, params: dict[str, Any] | None = None) -> Any:
        """Send one request and wait for its reply."""
        rid = next(self._ids)
        send, receive = trio.open_memory_channel[dict[str, Any]](1)
        self._waiting[rid] = send
        request: dict[str, Any] = {"id": rid, "method": method}
        if params is not None:
            request["params"] = params
        async with self._lock:
            await self.stream.send_all(encode(request))
        reply = await receive.receive()
        if "error" in reply:
            raise RequestError(reply["error"]["code"], reply["error"]["message"])
        return reply.get("result")

    async def send_line(self, data: bytes) -> None:
        """Send raw bytes (a test's malformed line)."""
        async with self._lock:
            await self.stream.send_all(data)

    async def next_event(self) -> dict[str, Any]:
        """The next event (or reply no `call` waits for), in arrival order."""
        return await self._events.receive()

    async def _read(self) -> None:
        buf = bytearray()
        while True:
            data = await self.stream.receive_some(65536)
            if not data:
                await self._events_send.aclose()
                return
            buf += data
            while (nl := buf.find(b"\n")) >= 0:
                line = bytes(buf[:nl])
                del buf[: nl + 1]
                msg = json.loads(line)
                waiter = self._waiting.pop(msg.get("id"), None) if "event" not in msg else None
                if waiter is not None:
                    waiter.send_nowait(msg)
                else:
                    await self._events_send.send(msg)


@asynccontextmanager
async def connect(port: int, host: str = DEFAULT_HOST) -> AsyncIterator[JsonlClient]:
    """A connected `JsonlClient`, closed on exit."""
    stream = await trio.open_tcp_stream(host, port)
    client = JsonlClient(stream)
    async with stream, trio.open_nursery() as nursery:
        nursery.start_soon(client._read)
        try:
            yield client
        finally:
            nursery.cancel_scope.cancel()


__all__ = [
    "Connection",
    "DEFAULT_HOST",
    "JsonlClient",
    "JsonlServer",
    "Method",
    "RequestError",
    "connect",
    "encode",
]
