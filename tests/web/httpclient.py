"""A small HTTP client for the web view's tests (h11 over trio, 127.0.0.1
only, every wait bounded): whole responses, and server-sent event streams."""

from __future__ import annotations

import json
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass
from typing import Any

import h11
import trio

HOST = "127.0.0.1"


@dataclass
class Reply:
    status: int
    headers: dict[str, str]
    body: bytes

    @property
    def text(self) -> str:
        return self.body.decode("utf-8")

    def json(self) -> Any:
        return json.loads(self.body)


async def fetch(
    port: int,
    path: str,
    *,
    method: str = "GET",
    headers: dict[str, str] | None = None,
    body: bytes = b"",
    timeout: float = 10.0,
) -> Reply:
    """One request on a new connection."""
    with trio.fail_after(timeout):
        stream = await trio.open_tcp_stream(HOST, port)
        async with stream:
            conn = h11.Connection(h11.CLIENT)
            hdrs = {"Host": f"{HOST}:{port}", **(headers or {})}
            if body:
                hdrs["Content-Length"] = str(len(body))
            data = conn.send(h11.Request(method=method, target=path, headers=list(hdrs.items())))
            if body:
                data += conn.send(h11.Data(data=body))
            data += conn.send(h11.EndOfMessage())
            await stream.send_all(data)
            return await _read_reply(conn, stream)


async def _read_reply(conn: h11.Connection, stream: trio.SocketStream) -> Reply:
    status = 0
    headers: dict[str, str] = {}
    chunks: list[bytes] = []
    while True:
        event = conn.next_event()
        if event is h11.NEED_DATA:
            conn.receive_data(await stream.receive_some(65536))
            continue
        if isinstance(event, h11.Response):
            status = event.status_code
            headers = {k.decode().lower(): v.decode() for k, v in event.headers}
        elif isinstance(event, h11.Data):
            chunks.append(bytes(event.data))
        elif isinstance(event, h11.EndOfMessage | h11.ConnectionClosed):
            return Reply(status, headers, b"".join(chunks))


class EventReader:
    """The events of one open event stream, decoded."""

    def __init__(self, conn: h11.Connection, stream: trio.SocketStream, reply: Reply):
        self.conn = conn
        self.stream = stream
        self.reply = reply
        self._buf = b""
        self.raw = bytearray()  # every byte of the stream's body so far

    async def next(self, timeout: float = 10.0) -> dict[str, Any]:
        """The next `data:` event (comments and `retry:` skipped)."""
        with trio.fail_after(timeout):
            while True:
                while b"\n\n" in self._buf:
                    block, self._buf = self._buf.split(b"\n\n", 1)
                    for line in block.split(b"\n"):
                        if line.startswith(b"data: "):
                            return json.loads(line[6:])  # type: ignore[no-any-return]
                event = self.conn.next_event()
                if event is h11.NEED_DATA:
                    self.conn.receive_data(await self.stream.receive_some(65536))
                elif isinstance(event, h11.Data):
                    self._buf += bytes(event.data)
                    self.raw += event.data
                elif isinstance(event, h11.EndOfMessage | h11.ConnectionClosed):
                    raise EOFError("the event stream ended")

    async def until(self, predicate: Any, timeout: float = 20.0) -> dict[str, Any]:
        """The first event for which `predicate(event)` holds."""
        with trio.fail_after(timeout):
            while True:
                event = await self.next(timeout)
                if predicate(event):
                    return event


@asynccontextmanager
async def events(port: int, path: str, timeout: float = 10.0) -> AsyncIterator[EventReader]:
    """An open event stream (its response head read)."""
    with trio.fail_after(timeout):
        stream = await trio.open_tcp_stream(HOST, port)
    async with stream:
        conn = h11.Connection(h11.CLIENT)
        await stream.send_all(
            conn.send(
                h11.Request(
                    method="GET",
                    target=path,
                    headers=[("Host", f"{HOST}:{port}"), ("Accept", "text/event-stream")],
                )
            )
            + conn.send(h11.EndOfMessage())
        )
        with trio.fail_after(timeout):
            while True:
                event = conn.next_event()
                if event is h11.NEED_DATA:
                    conn.receive_data(await stream.receive_some(65536))
                    continue
                assert isinstance(event, h11.Response), event
                reply = Reply(
                    event.status_code,
                    {k.decode().lower(): v.decode() for k, v in event.headers},
                    b"",
                )
                break
        yield EventReader(conn, stream, reply)
