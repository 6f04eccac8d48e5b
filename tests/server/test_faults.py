"""Bad clients end their own sessions, with a log line; everyone else goes on."""

from __future__ import annotations

import logging

import pytest
import trio
from ippc.protocol import Actions
from ippc.server.config import ServerConfig
from ippc.server.environment import Episode, Outcome, SimulatedEpisode
from ippc.server.registry import Instance, Registry
from ippc.server.session import Services
from ippc.server.store import ResultStore

from .harness import (
    DECL,
    NOOP,
    ROUND_REQUEST,
    RawClient,
    noop_session,
    root_of,
    running_server,
    session_request,
    shared_registry,
)

pytestmark = pytest.mark.trio


def cfg(**kw) -> ServerConfig:
    kw.setdefault("rounds", 2)
    return ServerConfig(port=0, **kw)


async def _healthy_alongside(port: int, bad) -> dict:
    """Run `bad(port)` while a healthy noop session plays; return the
    healthy session's results."""
    result: dict = {}

    async def healthy() -> None:
        result.update(await noop_session(port, client="healthy", stall=0.01))

    with trio.fail_after(20):
        async with trio.open_nursery() as n:
            n.start_soon(healthy)
            await bad(port)
    assert len(result["rounds"]) == 2
    return result


async def test_disconnect_mid_message(caplog) -> None:
    caplog.set_level(logging.INFO)

    async def bad(port: int) -> None:
        c = await RawClient.connect(port)
        await c.send(session_request(client="bad"))
        assert root_of(await c.recv()) == "session-init"
        await c.send(DECL + b"<round-req")
        await c.close()

    async with running_server(cfg()) as (port, _):
        await _healthy_alongside(port, bad)
    assert any(
        "client 'bad'" in r.getMessage() and "closed" in r.getMessage() for r in caplog.records
    )


async def test_endless_message_is_cut_at_the_limit(caplog) -> None:
    caplog.set_level(logging.INFO)

    async def bad(port: int) -> None:
        c = await RawClient.connect(port)
        await c.send(session_request(client="flood"))
        assert root_of(await c.recv()) == "session-init"
        chunk = b"<round-request>" + b"x" * (1 << 20)
        sent = 0
        with pytest.raises((trio.BrokenResourceError, trio.ClosedResourceError, OSError)):
            while sent < 100 * (1 << 20):  # 100 MB without a terminator
                await c.send(chunk)
                sent += len(chunk)
            await c.expect_eof()  # not reached if the server reset us first
            raise trio.BrokenResourceError("server closed")
        assert sent < 100 * (1 << 20)

    async with running_server(cfg(max_message_size=1 << 20)) as (port, _):
        await _healthy_alongside(port, bad)
    assert any("client 'flood'" in r.getMessage() for r in caplog.records)


async def test_billion_laughs_is_refused(caplog) -> None:
    caplog.set_level(logging.INFO)
    lol = (
        b'<?xml version="1.0"?><!DOCTYPE lolz [<!ENTITY lol "lol">'
        + b"".join(
            b'<!ENTITY lol%d "%s">' % (i, (b"&lol%d;" % (i - 1) if i > 1 else b"&lol;") * 10)
            for i in range(1, 10)
        )
        + b"]><session-request><problem-name>&lol9;</problem-name><client-name>laughs</client-name></session-request>\0"
    )

    async def bad(port: int) -> None:
        c = await RawClient.connect(port)
        await c.send(lol)
        await c.expect_eof(timeout=5)
        await c.close()

    async with running_server(cfg()) as (port, _):
        await _healthy_alongside(port, bad)


async def test_silent_client_with_idle_timeout(caplog) -> None:
    caplog.set_level(logging.INFO)

    async def bad(port: int) -> None:
        c = await RawClient.connect(port)
        await c.send(session_request(client="silent"))
        assert root_of(await c.recv()) == "session-init"
        await c.send(ROUND_REQUEST)
        assert root_of(await c.recv()) == "round-init"
        assert root_of(await c.recv()) == "turn"
        await c.expect_eof(timeout=5)  # never answers; closed after --idle-timeout
        await c.close()

    async with running_server(cfg(idle_timeout=0.5)) as (port, _):
        await _healthy_alongside(port, bad)
    assert any("silent for 0.5 s" in r.getMessage() for r in caplog.records)


async def test_half_closed_client_ends_at_once() -> None:
    async def bad(port: int) -> None:
        c = await RawClient.connect(port)
        await c.send(session_request(client="half"))
        assert root_of(await c.recv()) == "session-init"
        await c.half_close()
        with trio.fail_after(2):
            await c.expect_eof()
        await c.close()

    async with running_server(cfg()) as (port, _):
        await _healthy_alongside(port, bad)


async def test_garbage_then_good_clients() -> None:
    garbage = [
        b"\0",
        b"hello\0",
        b"<session-request/>\0",
        b"\xff\xfe\0",
        b"<a><b></a>\0",
        DECL + b"<actions/>\0",
    ]
    async with running_server(cfg()) as (port, _):
        with trio.fail_after(20):
            for g in garbage:
                c = await RawClient.connect(port)
                await c.send(g)
                await c.expect_eof(timeout=5)
                await c.close()
            res = await noop_session(port)
    assert res["session_id"] == len(garbage) + 1


class _BrokenEpisode(SimulatedEpisode):
    """A simulated episode whose environment has a bug on the second turn."""

    turns = 0

    async def act(self, actions: Actions) -> Outcome:
        self.turns += 1
        if self.turns == 2:
            raise RuntimeError("the environment broke")
        return await super().act(actions)


class _BrokenFor:
    """A registry whose instance breaks for the client called 'broken'."""

    def __init__(self, registry: Registry) -> None:
        self.registry = registry
        self.next_client = ""

    def get(self, name: str) -> Instance:
        inst = self.registry.get(name)
        if self.next_client != "broken":
            return inst

        class Broken(Instance):
            async def open(self, seed: int) -> Episode:
                sim, codec = await inst.compiled()
                return _BrokenEpisode(inst, sim, codec, seed)

        return Broken(inst.name, inst.model, inst.task)


async def test_an_environment_that_raises_ends_its_session_only(tmp_path, caplog) -> None:
    caplog.set_level(logging.INFO)
    registry = _BrokenFor(shared_registry())
    config = cfg()
    store = ResultStore(tmp_path / "r.db")
    services = Services(config, registry, store=store)  # type: ignore[arg-type]
    try:
        async with running_server(config, registry, services) as (port, _):  # type: ignore[arg-type]
            with trio.fail_after(20):
                registry.next_client = "broken"
                c = await RawClient.connect(port)
                await c.send(session_request(client="broken"))
                assert root_of(await c.recv()) == "session-init"
                await c.send(ROUND_REQUEST)
                assert root_of(await c.recv()) == "round-init"
                for _ in range(2):
                    assert root_of(await c.recv()) == "turn"
                    await c.send(NOOP)
                await c.expect_eof()  # the server closes this session only
                await c.close()
                registry.next_client = ""
                healthy = await noop_session(port, client="healthy")
        assert len(healthy["rounds"]) == 2
        broken, good = store.sessions()
        assert broken["status"] == "dropped"
        assert broken["reason"] == "internal error: RuntimeError: the environment broke"
        assert good["status"] == "finished"
        (rnd,) = store.rounds(broken["id"])
        assert len(store.steps(rnd["id"])) == 1  # the turn before the bug is kept
    finally:
        store.close()
    assert any("internal error" in r.getMessage() and r.exc_info for r in caplog.records)
