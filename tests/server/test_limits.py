"""Safe by default on a shared network: deadlines for slow peers, connection
caps and --allow, the shared budget of unfinished messages, quiet logs.

Every test plays a healthy session beside the hostile connections and checks
that it got all of its results."""

from __future__ import annotations

import logging
import sqlite3
from pathlib import Path

import pytest
import trio
from ippc.server.app import open_services
from ippc.server.config import ServerConfig
from ippc.server.limits import (
    BufferBudget,
    ConnectionTable,
    Notices,
    default_max_connections,
    parse_networks,
)
from ippc.server.store import ResultStore

from .harness import (
    DECL,
    RawClient,
    noop_session,
    root_of,
    running_server,
    session_request,
    shared_registry,
)


def cfg(**kw) -> ServerConfig:
    kw.setdefault("rounds", 2)
    return ServerConfig(port=0, **kw)


def messages(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records]


async def connect_from(source: str, port: int) -> trio.SocketStream:
    """A connection to 127.0.0.1:`port` from the loopback address `source`."""
    sock = trio.socket.socket()
    await sock.bind((source, 0))
    await sock.connect(("127.0.0.1", port))
    return trio.SocketStream(sock)


async def closed_within(stream: trio.SocketStream, seconds: float) -> bool:
    """Whether the server closes `stream` within `seconds` (reading and
    dropping whatever it sends)."""
    with trio.move_on_after(seconds):
        try:
            while await stream.receive_some(65536):
                pass
        except (trio.BrokenResourceError, OSError):
            pass
        return True
    return False


# ---------------------------------------------------------------- deadlines


@pytest.mark.trio
async def test_a_silent_connection_is_closed_at_the_request_deadline(caplog) -> None:
    caplog.set_level(logging.INFO)
    async with running_server(cfg(request_timeout=0.5)) as (port, _):
        silent = await trio.open_tcp_stream("127.0.0.1", port)
        with trio.fail_after(20):
            result = await noop_session(port, client="healthy")
            assert await closed_within(silent, 5)
    assert len(result["rounds"]) == 2
    assert any("no session-request within 0.5 s" in m for m in messages(caplog))


@pytest.mark.trio
async def test_a_drip_is_cut_by_the_message_deadline_not_saved_by_the_idle_timeout(
    caplog,
) -> None:
    """One byte every 0.1 s would hold a slot forever under --idle-timeout
    alone (it restarts on every byte); the message deadline counts from the
    message's first byte."""
    caplog.set_level(logging.INFO)
    config = cfg(request_timeout=0, message_timeout=0.6, idle_timeout=5.0)
    async with running_server(config) as (port, _):
        c = await RawClient.connect(port)
        await c.send(session_request(client="drip"))
        assert root_of(await c.recv()) == "session-init"
        t0 = trio.current_time()
        with trio.fail_after(10):
            try:
                for b in DECL + b"<round-request/>":
                    await c.send(bytes([b]))
                    await trio.sleep(0.1)
            except (trio.BrokenResourceError, OSError):
                pass
            await c.expect_eof()
        assert trio.current_time() - t0 < 4.0
        result = await noop_session(port, client="healthy")
    assert len(result["rounds"]) == 2
    assert any(
        "client 'drip'" in m and "message deadline: unfinished 0.6 s after its first byte" in m
        for m in messages(caplog)
    )


@pytest.mark.trio
async def test_deadlines_off_leave_a_slow_message_alone() -> None:
    """0 turns the deadlines off: a message sent in pieces over 1 s is served."""
    async with running_server(cfg(request_timeout=0, message_timeout=0)) as (port, _):
        c = await RawClient.connect(port)
        req = session_request(client="slow")
        with trio.fail_after(10):
            for i in range(0, len(req), 40):
                await c.send(req[i : i + 40])
                await trio.sleep(0.25)
            assert root_of(await c.recv()) == "session-init"
        await c.close()


@pytest.mark.trio
async def test_deadlines_do_not_cut_a_client_that_thinks_between_messages() -> None:
    """A pause between whole messages is think time, not an unfinished message."""
    async with running_server(cfg(message_timeout=0.3, request_timeout=0.5)) as (port, _):
        with trio.fail_after(20):
            result = await noop_session(port, client="thinker", stall=0.4)
    assert len(result["rounds"]) == 2


# ------------------------------------------------- no record for non-sessions


@pytest.mark.trio
async def test_connections_without_a_session_request_leave_no_record(tmp_path: Path) -> None:
    config = cfg(request_timeout=0.5, db=tmp_path / "r.db", log_dir=tmp_path)
    registry = shared_registry()
    async with trio.open_nursery() as nursery:
        from functools import partial

        from ippc.server.app import serve

        port = await nursery.start(partial(serve, config, registry))
        with trio.fail_after(20):
            for _ in range(5):  # connect and go
                s = await trio.open_tcp_stream("127.0.0.1", port)
                await s.aclose()
            garbage = await RawClient.connect(port)
            await garbage.send(b"GET / HTTP/1.0\r\n\r\n\0")
            await garbage.expect_eof()
            silent = await trio.open_tcp_stream("127.0.0.1", port)
            assert await closed_within(silent, 5)
            result = await noop_session(port, client="healthy")
        nursery.cancel_scope.cancel()
    assert result["session_id"] == 8  # rddlsim numbers every connection
    log = next(tmp_path.glob("logs-*.log")).read_text()
    assert log.count("<client-info>") == 1
    with sqlite3.connect(tmp_path / "r.db") as db:
        rows = db.execute("SELECT client_name, status FROM sessions").fetchall()
    assert rows == [("healthy", "finished")]


# ---------------------------------------------------------- connection caps


@pytest.mark.trio
async def test_the_cap_refuses_at_once_and_keeps_the_sessions_in_progress(caplog) -> None:
    caplog.set_level(logging.INFO)
    async with running_server(cfg(max_connections=3, max_connections_per_address=3, rounds=1)) as (
        port,
        _,
    ):
        with trio.fail_after(20):
            held = [await RawClient.connect(port) for _ in range(2)]
            for i, c in enumerate(held):
                await c.send(session_request(client=f"held{i}"))
                assert root_of(await c.recv()) == "session-init"
            player = await RawClient.connect(port)
            await player.send(session_request(client="player"))
            assert root_of(await player.recv()) == "session-init"
            # the fourth and fifth are refused at once, before any deadline
            for _ in range(2):
                late = await trio.open_tcp_stream("127.0.0.1", port)
                assert await closed_within(late, 2)
            # the sessions in progress go on
            await held[0].close()
            await trio.sleep(0.2)  # the server sees it go
            result = await noop_session(port, client="after")
    assert len(result["rounds"]) == 1
    text = "\n".join(messages(caplog))
    assert "cap of 3 open connections" in text


@pytest.mark.trio
async def test_the_per_address_cap_leaves_room_for_other_addresses(caplog) -> None:
    caplog.set_level(logging.INFO)
    config = cfg(max_connections=10, max_connections_per_address=2, rounds=1)
    async with running_server(config) as (port, _):
        with trio.fail_after(20):
            hogs = [await connect_from("127.0.0.1", port) for _ in range(2)]
            third = await connect_from("127.0.0.1", port)
            assert await closed_within(third, 2)
            other = await connect_from("127.0.0.2", port)
            await other.send_all(session_request(client="other"))
            assert b"session-init" in await other.receive_some(65536)
            for s in [*hogs, other]:
                await s.aclose()
    assert any("cap of 2 per address" in m for m in messages(caplog))


@pytest.mark.trio
async def test_allow_accepts_only_the_listed_networks(caplog) -> None:
    caplog.set_level(logging.INFO)
    async with running_server(cfg(allow=("127.0.0.2/32",), rounds=1)) as (port, _):
        with trio.fail_after(20):
            refused = await connect_from("127.0.0.1", port)
            assert await closed_within(refused, 2)
            ok = await connect_from("127.0.0.2", port)
            await ok.send_all(session_request(client="allowed"))
            assert b"session-init" in await ok.receive_some(65536)
            await ok.aclose()
    assert any(
        "connection from 127.0.0.1 refused: address not in --allow" in m for m in messages(caplog)
    )


def test_connection_table_counts_and_refuses() -> None:
    t = ConnectionTable(3, 2, parse_networks(["10.0.0.0/8", "::1/128"]))
    assert t.refusal("192.168.1.1") is not None
    assert t.refusal("::ffff:10.1.2.3") is None  # IPv4-mapped
    assert t.refusal("::1") is None
    t.add(1, "10.0.0.1")
    t.add(2, "10.0.0.1")
    assert "per address" in t.refusal("10.0.0.1")[0]  # type: ignore[index]
    t.add(3, "10.0.0.2")
    assert "cap of 3 open" in t.refusal("10.0.0.3")[0]  # type: ignore[index]
    t.remove(1)
    t.remove(1)  # twice: no harm
    assert t.refusal("10.0.0.1") is None and t.open == 2
    with pytest.raises(ValueError, match="not a network"):
        parse_networks(["10.0.0.300/8"])


def test_the_default_cap_keeps_headroom_in_the_open_file_limit() -> None:
    assert default_max_connections(limit=256) == (256 - 64) // 2
    assert default_max_connections(transcripts=True, limit=256) == (256 - 64) // 3
    assert default_max_connections(limit=10) == 1
    total, per = ServerConfig().connection_caps()
    assert total == default_max_connections() and per == total // 2
    assert ServerConfig(max_connections=7).connection_caps() == (7, 3)


# -------------------------------------------------------- the buffer budget


@pytest.mark.trio
async def test_a_connection_past_the_shared_budget_is_closed_and_the_others_go_on(
    caplog,
) -> None:
    """Budget 256 KiB beyond 64 KiB per connection: two connections with
    200 KiB of unfinished message each need 272 KiB, so the second is
    closed; the first keeps its slot and the healthy session plays on."""
    caplog.set_level(logging.INFO)
    config = cfg(max_buffered=256 * 1024, message_timeout=0, request_timeout=0)
    async with running_server(config) as (port, svc):
        budget = svc.budget
        assert budget is not None
        with trio.fail_after(20):
            first = await RawClient.connect(port)
            await first.send(DECL + b"<session-request>" + b"x" * 200_000)
            while budget.used < 200_000 - 64 * 1024:
                await trio.sleep(0.01)
            second = await RawClient.connect(port)
            try:
                await second.send(DECL + b"<session-request>" + b"y" * 200_000)
            except (trio.BrokenResourceError, OSError):
                pass
            assert await closed_within(second.stream, 5)
            result = await noop_session(port, client="healthy")
            assert not await closed_within(first.stream, 0.2)  # still open
            await first.close()
            while budget.used:
                await trio.sleep(0.01)
    assert len(result["rounds"]) == 2
    assert any("buffer budget exhausted" in m for m in messages(caplog))


def test_budget_charges_only_beyond_the_allowance() -> None:
    b = BufferBudget(100, allowance=10)
    assert b.charge(0, 5) == 0 and b.used == 0
    held = b.charge(0, 60)
    assert held == 50 and b.used == 50
    assert b.charge(held, 120) is None and b.used == 50  # 110 > 100: refused
    held2 = b.charge(0, 60)
    assert held2 == 50 and b.used == 100
    assert b.charge(held, 8) == 0 and b.used == 50  # its message is done
    b.release(held2)
    assert b.used == 0


# ------------------------------------------------------------ quiet logs


def test_notices_log_a_cause_a_few_times_then_count_it(caplog) -> None:
    caplog.set_level(logging.INFO)
    now = [0.0]
    n = Notices(logging.getLogger("test.notices"), interval=10.0, burst=2, clock=lambda: now[0])
    for i in range(1234):
        n.note("connections refused: cap of 512 open connections reached", f"refused {i}")
    n.note("connections closed before a session-request", "closed 1")
    assert messages(caplog)[:2] == [
        "refused 0",
        "refused 1 (more of these are counted, one line per 10 s)",
    ]
    assert len(caplog.records) == 3
    now[0] = 10.5
    n.note("connections closed before a session-request", "closed 2")  # a new interval
    assert (
        "1,232 connections refused in the last 10 s: cap of 512 open connections reached"
        in messages(caplog)
    )
    assert messages(caplog)[-1] == "closed 2"
    assert n.totals["connections refused: cap of 512 open connections reached"] == 1234


@pytest.mark.trio
async def test_a_flood_of_empty_connections_is_logged_as_a_count(caplog) -> None:
    caplog.set_level(logging.INFO)
    async with running_server(cfg(rounds=1)) as (port, svc):
        with trio.fail_after(30):
            for _ in range(60):
                s = await trio.open_tcp_stream("127.0.0.1", port)
                await s.aclose()
            cause = (
                "connections closed before a session-request:"
                " the client closed the connection before its session-request"
            )
            while svc.notices.totals[cause] < 60:
                await trio.sleep(0.01)
            svc.notices.flush()
    lines = [m for m in messages(caplog) if m.startswith("session ")]
    assert len(lines) == svc.notices.burst
    assert any(
        m.startswith(
            f"{60 - svc.notices.burst} connections closed before a session-request in the last"
        )
        for m in messages(caplog)
    )


@pytest.mark.trio
async def test_services_of_a_server_share_one_budget(tmp_path: Path) -> None:
    config = cfg(max_buffered=1 << 20, db=tmp_path / "r.db")
    svc = open_services(config, shared_registry(), 0)
    try:
        assert svc.budget is not None and svc.budget.limit == 1 << 20
    finally:
        svc.store.close()
    ResultStore(tmp_path / "r.db").close()


def test_a_reader_that_failed_frees_its_bytes_at_once() -> None:
    """An unfinished message cut at the size limit is freed when the error
    is raised, not when the reader goes (its stored error's traceback can
    keep the reader, and its session, alive until a garbage collection)."""
    from ippc.protocol import MessageReader, RemoteProtocolError

    reader = MessageReader("nul", max_size=1000)
    reader.feed(b"x" * 5000)
    with pytest.raises(RemoteProtocolError, match="too long"):
        reader.next_message()
    assert reader.buffered == 0
    with pytest.raises(RemoteProtocolError, match="too long"):
        reader.next_message()  # and it keeps failing


# ------------------------------------------------------------ the command


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--allow", "10.0.0.300/8"], "not a network"),
        (["--request-timeout", "-1"], "must be 0 (off) or positive"),
        (["--message-timeout", "-2"], "must be 0 (off) or positive"),
        (["--max-connections", "0"], "must be at least 1"),
        (["--max-connections-per-address", "0"], "must be at least 1"),
        (["--max-buffered-mib", "0"], "must be positive"),
        (["--accept-rate", "-1"], "must be 0 (no limit) or positive"),
    ],
)
def test_option_errors(args: list[str], message: str) -> None:
    from click.testing import CliRunner
    from ippc.server.cli import main

    from .harness import RDDL

    r = CliRunner().invoke(main, [str(RDDL), *args])
    assert r.exit_code == 2 and message in r.output, r.output


def test_the_limits_line_says_what_the_server_allows() -> None:
    from ippc.server.cli import _limits_line

    line = _limits_line(
        ServerConfig(
            max_connections=100, allow=("10.0.0.0/8",), message_timeout=0, max_buffered=8 << 20
        )
    )
    assert line == (
        "limits: 100 connections (50 per address, only from 10.0.0.0/8);"
        " session-request 30 s, each message no limit; 8 MiB of unfinished messages"
    )


# ------------------------------------------------------------ worker processes


def _with_workers(config: ServerConfig, n: int, body, pools: list) -> None:
    from functools import partial

    from ippc.server.workers import serve_with_workers

    from .harness import RDDL

    async def main() -> None:
        async with trio.open_nursery() as nursery:
            port = await nursery.start(
                partial(serve_with_workers, config, [str(RDDL)], n, pools=pools)
            )
            await body(port, pools[0])
            nursery.cancel_scope.cancel()

    trio.run(main)


@pytest.mark.alone
def test_workers_the_listener_enforces_the_caps_and_allow(caplog) -> None:
    caplog.set_level(logging.INFO)
    config = ServerConfig(port=0, rounds=1, max_connections=10, max_connections_per_address=2)

    async def body(port: int, pool) -> None:
        with trio.fail_after(60):
            hogs = [await connect_from("127.0.0.1", port) for _ in range(2)]
            third = await connect_from("127.0.0.1", port)
            assert await closed_within(third, 5)
            result = await _session_from("127.0.0.2", port)
            assert result
            for s in hogs:
                await s.aclose()
            while pool.table.open:  # the workers report the ends
                await trio.sleep(0.02)
            assert pool.next_id == 3  # the refused one took no number

    pools: list = []
    _with_workers(config, 2, body, pools)
    assert any("cap of 2 per address" in m for m in messages(caplog))


async def _session_from(source: str, port: int) -> bool:
    s = await connect_from(source, port)
    await s.send_all(session_request(client="other"))
    data = await s.receive_some(65536)
    await s.aclose()
    return b"session-init" in data


@pytest.mark.alone
def test_workers_an_overloaded_worker_makes_the_listener_wait_not_drop(
    caplog, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With the only worker stopped, its queue of hand-overs fills; the
    listener then waits for room (new connections wait in the backlog)
    instead of closing them as 'no worker process'; past HANDOVER_WAIT the
    one it holds is closed as overload. Once the worker goes on, every
    queued connection is played."""
    import os
    import signal

    import ippc.server.workers as W

    monkeypatch.setattr(W, "HANDOVER_WAIT", 1.0)
    caplog.set_level(logging.INFO)
    config = ServerConfig(port=0, rounds=1)

    async def body(port: int, pool) -> None:
        (w,) = pool.workers
        pid = w.proc.pid
        os.kill(pid, signal.SIGSTOP)
        socks = []
        try:
            with trio.fail_after(60):
                while not any("overload" in m for m in messages(caplog)):
                    s = trio.socket.socket()
                    await s.connect(("127.0.0.1", port))
                    socks.append(s)
                    await trio.sleep(0.001)
        finally:
            os.kill(pid, signal.SIGCONT)
        for s in socks:
            s.close()
        with trio.fail_after(60):
            assert await _session_from("127.0.0.1", port)

    pools: list = []
    _with_workers(config, 1, body, pools)
    text = "\n".join(messages(caplog))
    assert "overload: no worker took the connection within 1 s" in text
    assert "no worker process is ready" not in text


@pytest.mark.alone
@pytest.mark.trio
async def test_a_session_in_progress_plays_on_through_a_connection_flood(caplog) -> None:
    """400 connections opened and closed back to back while a session
    plays: it gets all its turns, and the log has a few lines, not 400."""
    caplog.set_level(logging.INFO)
    async with running_server(cfg(rounds=3)) as (port, svc):
        quiet = await noop_session(port, client="quiet")
        flooded = 0

        async def flood() -> None:
            nonlocal flooded
            for _ in range(400):
                s = await trio.open_tcp_stream("127.0.0.1", port)
                await s.aclose()
                flooded += 1

        with trio.fail_after(60):
            async with trio.open_nursery() as n:
                n.start_soon(flood)
                result = await noop_session(port, client="healthy")
            cause = (
                "connections closed before a session-request:"
                " the client closed the connection before its session-request"
            )
            while svc.notices.totals[cause] < 400:
                await trio.sleep(0.01)
    assert len(result["rounds"]) == 3 and len(result["states"]) == len(quiet["states"])
    assert flooded == 400
    assert len(caplog.records) < 20


def test_the_accept_pacer_lets_a_burst_through_then_paces(monkeypatch) -> None:
    import ippc.server.limits as L

    now = [100.0]
    slept: list[float] = []

    async def fake_sleep(seconds: float) -> None:
        slept.append(seconds)
        now[0] += seconds

    monkeypatch.setattr(L.time, "monotonic", lambda: now[0])
    monkeypatch.setattr(trio, "sleep", fake_sleep)
    pacer = L.AcceptPacer(rate=10.0, burst=3.0)

    async def main() -> None:
        for _ in range(3):
            await pacer.pace()
        assert slept == []  # the burst
        for _ in range(4):
            await pacer.pace()
        assert slept == pytest.approx([0.1] * 4)  # then one per 1/rate
        now[0] += 10.0  # a quiet while refills the burst, no more
        slept.clear()
        for _ in range(3):
            await pacer.pace()
        assert slept == []
        await pacer.pace()
        assert slept == pytest.approx([0.1])
        unpaced = L.AcceptPacer(rate=0)
        for _ in range(100):
            await unpaced.pace()
        assert len(slept) == 1

    trio.run(main)
