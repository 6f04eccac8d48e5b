"""Test tools for the server: a server in the test's nursery, a raw client,
the recorded rddlsim scenarios, and a comparison of messages by form."""

from __future__ import annotations

import json
import re
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import trio
from ippc.protocol import MessageReader
from ippc.server.app import serve
from ippc.server.config import ServerConfig
from ippc.server.registry import Registry
from ippc.server.session import Services
from lxml import etree

from ..conftest import DATA

TRANSCRIPTS = DATA / "rddlsim" / "transcripts"
RDDL = DATA / "rddlsim" / "rddl"
DECL = b'<?xml version="1.0" encoding="UTF-8"?>\n'

_registry: Registry | None = None


def shared_registry() -> Registry:
    """The instances of the recorded sessions, loaded once per test run."""
    global _registry
    if _registry is None:
        _registry = Registry.load(RDDL)
    return _registry


def scenario(name: str) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    lines = [json.loads(x) for x in (TRANSCRIPTS / f"{name}.jsonl").read_text().splitlines()]
    return lines[0]["meta"], lines[1:]


def config_for(meta: dict[str, Any], **over: Any) -> ServerConfig:
    """rddlsim's positional server arguments as our config (port 0)."""
    args = meta["server_args"]
    kw: dict[str, Any] = {"port": 0}
    if len(args) > 2:
        kw["rounds"] = int(args[2])
    if len(args) > 3:
        kw["seed"] = int(args[3])
    if len(args) > 4:
        kw["individual_session"] = args[4] == "1"
    if len(args) > 5:
        kw["timeout"] = float(args[5])
    if len(args) > 7:
        kw["monitor_execution"] = args[7] == "1"
    kw.update(over)
    return ServerConfig(**kw)


@asynccontextmanager
async def running_server(
    config: ServerConfig, registry: Registry | None = None, services: Services | None = None
) -> AsyncIterator[tuple[int, Services]]:
    """A server on 127.0.0.1 for the body of the `async with`; yields its
    port and services, and stops it afterwards."""
    registry = registry or shared_registry()
    svc = services or Services(config, registry)
    async with trio.open_nursery() as nursery:
        port = await nursery.start(partial(serve, config, registry, services=svc))
        yield port, svc
        nursery.cancel_scope.cancel()


@dataclass
class RawClient:
    """Bytes out, messages in; remembers the raw inbound stream."""

    stream: trio.SocketStream
    reader: MessageReader
    raw: bytearray = field(default_factory=bytearray)

    @classmethod
    async def connect(cls, port: int, bare: bool = False) -> RawClient:
        stream = await trio.open_tcp_stream("127.0.0.1", port)
        return cls(stream, MessageReader("bare" if bare else "nul"))

    async def send(self, data: bytes) -> None:
        await self.stream.send_all(data)

    async def recv(self, timeout: float = 10.0) -> bytes | None:
        """One message (without terminator), or None at EOF."""
        with trio.fail_after(timeout):
            while True:
                msg = self.reader.next_message()
                if msg is not None:
                    return msg
                data = await self.stream.receive_some(65536)
                self.raw += data
                if not data:
                    self.reader.feed_eof()
                    msg = self.reader.next_message()
                    return msg
                self.reader.feed(data)

    async def expect_eof(self, timeout: float = 10.0) -> None:
        msg = await self.recv(timeout)
        assert msg is None, f"expected the server to close, got {msg[:120]!r}"

    async def half_close(self) -> None:
        await self.stream.send_eof()

    async def close(self) -> None:
        await self.stream.aclose()


# ------------------------------------------------------------ comparison

_DOUBLE = re.compile(r"^-?(\d+\.\d+(E-?\d+)?|NaN|Infinity)$")
_INT = re.compile(r"^-?\d+$")


def form(text: str | None) -> str:
    """The shape of a value: bool, int, double, enum, or text."""
    t = text or ""
    if t in ("true", "false"):
        return "bool"
    if _INT.match(t):
        return "int"
    if _DOUBLE.match(t):
        return "double"
    if t.startswith("@"):
        return "enum"
    return "text"


# Elements whose text depends on the clock or on random draws.
TIMING = {"time-left"}
SAMPLED = {"fluent-value", "immediate-reward", "round-reward", "total-reward"}


def strip_frame(msg: bytes) -> bytes:
    return msg[len(DECL) :] if msg.startswith(DECL) else msg


def compare(recorded: bytes, ours: bytes, *, exact_values: bool) -> list[str]:
    """Differences between two messages: element names and order exactly,
    counters and names exactly, clock values by form, sampled values
    exactly when `exact_values` else by form."""
    a = etree.fromstring(strip_frame(recorded))
    b = etree.fromstring(strip_frame(ours))
    out: list[str] = []

    def walk(x: Any, y: Any, path: str) -> None:
        if x.tag != y.tag:
            out.append(f"{path}: <{x.tag}> vs <{y.tag}>")
            return
        p = f"{path}/{x.tag}"
        xs, ys = list(x), list(y)
        if [c.tag for c in xs] != [c.tag for c in ys]:
            out.append(f"{p}: children {[c.tag for c in xs][:12]} vs {[c.tag for c in ys][:12]}")
            return
        if not xs:
            tx, ty = x.text or "", y.text or ""
            if x.tag in TIMING or (x.tag in SAMPLED and not exact_values):
                if form(tx) != form(ty):
                    out.append(f"{p}: {tx!r} vs {ty!r} (form {form(tx)} vs {form(ty)})")
            elif tx != ty:
                out.append(f"{p}: {tx!r} vs {ty!r}")
        for c1, c2 in zip(xs, ys, strict=True):
            walk(c1, c2, p)

    walk(a, b, "")
    return out


def root_of(msg: bytes) -> str:
    m = re.search(rb"<([a-zA-Z-]+)", strip_frame(msg))
    return m.group(1).decode() if m else "?"


def session_request(
    instance: str = "sysadmin_inst_mdp__1", client: str = "raw", no_header: bool = False
) -> bytes:
    nh = b"<no-header/>" if no_header else b""
    return (
        DECL
        + b"<session-request><problem-name>"
        + instance.encode()
        + b"</problem-name><client-name>"
        + client.encode()
        + b"</client-name>"
        + nh
        + b"</session-request>\0"
    )


ROUND_REQUEST = DECL + b"<round-request/>\0"
NOOP = DECL + b"<actions/>\0"


async def noop_session(
    port: int, instance: str = "sysadmin_inst_mdp__1", client: str = "raw", *, stall: float = 0.0
) -> dict[str, Any]:
    """A whole session of noops with raw bytes: session id, the round
    rewards, the turns' states and the total."""
    c = await RawClient.connect(port)
    out: dict[str, Any] = {"rounds": [], "states": []}
    try:
        await c.send(session_request(instance, client))
        init = etree.fromstring(strip_frame(await c.recv()))
        assert init.tag == "session-init", init.tag
        out["session_id"] = int(init.findtext("session-id"))
        for _ in range(int(init.findtext("num-rounds"))):
            await c.send(ROUND_REQUEST)
            assert root_of(await c.recv()) == "round-init"
            while True:
                msg = etree.fromstring(strip_frame(await c.recv()))
                if msg.tag == "round-end":
                    out["rounds"].append(float(msg.findtext("round-reward")))
                    break
                assert msg.tag == "turn", msg.tag
                out["states"].append(
                    [x.findtext("fluent-value") for x in msg.findall("observed-fluent")]
                )
                if stall:
                    await trio.sleep(stall)
                await c.send(NOOP)
        end = etree.fromstring(strip_frame(await c.recv()))
        assert end.tag == "session-end"
        out["total"] = float(end.findtext("total-reward"))
        await c.expect_eof()
    finally:
        await c.close()
    return out


async def noop_sessions_at_once(port: int, n: int, timeout: float = 120.0) -> list[dict[str, Any]]:
    """`n` whole noop sessions (`noop_session`, clients c0, c1, ...) played
    at once; their results in the order they ended."""
    results: list[dict[str, Any]] = []

    async def one(i: int) -> None:
        results.append(await noop_session(port, client=f"c{i}"))

    with trio.fail_after(timeout):
        async with trio.open_nursery() as nursery:
            for i in range(n):
                nursery.start_soon(one, i)
    return results
