"""rddl-dispatch's IPPC listener has rddl-server's limits (server/limits.py):
`--allow`, the connection caps in total and per address (the connections
waiting for their turn count), the accept pacing, and the same options with
the same defaults. Real sockets on 127.0.0.1-127.0.0.3, loops bounded in
count and time."""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import pytest
import trio
from click.testing import CliRunner
from ippc.client.session import ClientConfig, run_session
from ippc.dispatch.actions import Dispatch, Status
from ippc.dispatch.cli import main
from ippc.dispatch.run import (
    LinkPolicy,
    ListenError,
    RunReport,
    build_robot,
    dispatch_session,
    server_config,
)
from ippc.kb import KnowledgeBase
from ippc.planners.base import make_planner
from ippc.protocol import SessionRequest, encode
from ippc.server.config import DEFAULT_ACCEPT_RATE, ServerConfig

from .conftest import DOMAIN, ONE


def courier() -> Any:
    robot, dispatcher = build_robot(
        KnowledgeBase.from_files(DOMAIN, ONE), None, action_timeout=5.0, settle_limit=0.0
    )

    @robot.handler("*")
    async def ok(d: Dispatch) -> Status:
        return Status.SUCCEEDED

    return dispatcher


async def connect_from(source: str, port: int) -> trio.SocketStream:
    sock = trio.socket.socket()
    await sock.bind((source, 0))
    await sock.connect(("127.0.0.1", port))
    return trio.SocketStream(sock)


async def closed_within(stream: trio.SocketStream, seconds: float) -> bool:
    """Whether the dispatcher closes `stream` (sending nothing) within `seconds`."""
    with trio.move_on_after(seconds):
        try:
            while await stream.receive_some(65536):
                pass
        except trio.BrokenResourceError:
            pass
        return True
    return False


async def start_session(stream: trio.SocketStream, client: str) -> bytes:
    await stream.send_all(encode(SessionRequest("courier_one", client)) + b"\0")
    return await stream.receive_some(65536)


async def serving(config: ServerConfig, body: Any, reconnect: bool = True) -> tuple[RunReport, Any]:
    """Run a dispatcher with `config` (waiting for a planner again after a
    dropped session, or with `reconnect` False ending the run), call
    `body(port)`, then stop it; its report and what `body` returned."""
    ports: list[int] = []
    stop = trio.Event()
    box: list[RunReport] = []
    with trio.fail_after(60):
        async with trio.open_nursery() as nursery:

            async def run() -> None:
                box.append(
                    await dispatch_session(
                        courier(),
                        None,
                        config,
                        on_listening=ports.append,
                        link=LinkPolicy(reconnect=reconnect),
                        stop=stop,
                    )
                )

            nursery.start_soon(run)
            while not ports:
                await trio.sleep(0.01)
            out = await body(ports[0])
            if not reconnect:  # the run ends by itself after its session
                with trio.move_on_after(10):
                    while not box:
                        await trio.sleep(0.01)
            if not box:
                stop.set()
    return box[0], out


def test_allow_and_the_caps_refuse_at_once_and_the_waiting_planner_is_served(caplog) -> None:
    caplog.set_level(logging.INFO)
    config = server_config(
        rounds=1, allow=("127.0.0.2/31",), max_connections=3, max_connections_per_address=2
    )

    async def body(port: int) -> dict[str, Any]:
        first = await connect_from("127.0.0.2", port)
        assert b"session-init" in await start_session(first, "first")
        waiting = await connect_from("127.0.0.2", port)  # the second from .2: waits its turn
        per_address = await connect_from("127.0.0.2", port)  # the third from .2
        other = await connect_from("127.0.0.3", port)  # waits too: 3 open in all
        total = await connect_from("127.0.0.3", port)  # the fourth in all
        outsider = await connect_from("127.0.0.1", port)  # not in --allow
        out = {
            "per_address": await closed_within(per_address, 5),
            "total": await closed_within(total, 5),
            "outsider": await closed_within(outsider, 5),
            "waiting": await closed_within(waiting, 0.3),
        }
        # the session in progress ends (its planner hangs up): the next one waiting is served
        await first.aclose()
        out["served"] = b"session-init" in await start_session(waiting, "second")
        for s in (waiting, other, per_address, total, outsider):
            await s.aclose()
        return out

    report, seen = trio.run(serving, config, body)
    assert seen == {
        "per_address": True,
        "total": True,
        "outsider": True,
        "waiting": False,
        "served": True,
    }
    assert report.sessions[0] == "dropped"
    text = "\n".join(r.getMessage() for r in caplog.records)
    assert "connection from 127.0.0.2 refused: cap of 2 per address reached" in text
    assert "connection from 127.0.0.3 refused: cap of 3 open connections reached" in text
    assert "connection from 127.0.0.1 refused: address not in --allow" in text


def test_a_connection_without_a_session_request_is_no_planner_lost(caplog) -> None:
    """Under --on-planner-loss exit, connections that never sent a
    session-request (one hung up after a byte, one sent something else) do
    not end the run: the planner that comes next plays its session."""
    caplog.set_level(logging.INFO)
    config = server_config(rounds=1)

    async def body(port: int) -> None:
        hung_up = await connect_from("127.0.0.2", port)
        await hung_up.send_all(b"<")
        await trio.sleep(0.2)  # accepted with its byte, then gone
        await hung_up.aclose()
        other = await connect_from("127.0.0.2", port)
        await other.send_all(b'<?xml version="1.0"?><round-request/>\0')
        assert await closed_within(other, 10)
        await run_session(
            ClientConfig(port=port, instance="courier_one", timeout=30.0),
            make_planner("exact", {}),  # type: ignore[arg-type]
            "exact",
        )

    report, _ = trio.run(serving, config, body, False)
    assert report.sessions == ["finished"] and report.turns > 0 and report.interrupted is None
    text = "\n".join(r.getMessage() for r in caplog.records)
    assert "expected <session-request> but received <round-request>" in text


def test_the_listener_paces_new_connections() -> None:
    """--accept-rate 4 (bursts of 2): six connections refused by the cap per
    address are closed one every quarter second, not all at once."""
    config = server_config(rounds=1, max_connections_per_address=1, accept_rate=4)

    async def body(port: int) -> float:
        first = await connect_from("127.0.0.2", port)  # takes a token and the address's slot
        assert b"session-init" in await start_session(first, "first")
        t0 = time.monotonic()
        for _ in range(6):
            extra = await connect_from("127.0.0.2", port)
            assert await closed_within(extra, 10)
            await extra.aclose()
        took = time.monotonic() - t0
        await first.aclose()
        return took

    _, took = trio.run(serving, config, body)
    # one token left of the burst, then 4 a second: 5 waits of 0.25 s (a floor, whatever the load)
    assert took >= 1.0


def test_the_options_reach_the_listener_with_rddl_servers_defaults(monkeypatch) -> None:
    seen: list[ServerConfig] = []

    async def fake_session(dispatcher: Any, spec: Any, config: ServerConfig, **kw: Any) -> Any:
        seen.append(config)
        raise ListenError("the planner's socket, --port", "here", OSError(98, "taken"))

    monkeypatch.setattr("ippc.dispatch.cli.dispatch_session", fake_session)
    runner = CliRunner()
    base = [str(DOMAIN), str(ONE), "--port", "0", "-q"]
    extra = [
        "--max-connections",
        "5",
        "--max-connections-per-address",
        "2",
        "--allow",
        "10.0.0.0/8",
        "--allow",
        "127.0.0.1",
        "--accept-rate",
        "7",
    ]
    for args in (base, base + extra):
        result = runner.invoke(main, args)
        assert result.exit_code != 0 and "cannot listen on here" in result.output
    default, given = seen
    plain = ServerConfig()
    assert (default.max_connections, default.max_connections_per_address) == (None, None)
    assert default.connection_caps() == plain.connection_caps()
    assert (default.allow, default.accept_rate) == ((), DEFAULT_ACCEPT_RATE)
    assert given.connection_caps() == (5, 2)
    assert given.allow == ("10.0.0.0/8", "127.0.0.1")
    assert given.accept_rate == 7


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--max-connections", "0"], "must be at least 1"),
        (["--max-connections-per-address", "-1"], "must be at least 1"),
        (["--allow", "10.0.0.300/8"], "not a network"),
        (["--accept-rate", "-1"], "must be 0 (no limit) or positive"),
    ],
)
def test_bad_limits_are_refused_before_anything_listens(
    args: list[str], message: str, tmp_path: Path
) -> None:
    result = CliRunner().invoke(main, [str(DOMAIN), str(ONE), *args])
    assert result.exit_code == 2 and message in result.output
