"""When the connection cap (from the open-file limit) is reached by idle
connections, a new client gets its session at once: the oldest connection
that has had no session for a second is closed to make room (one process,
and worker processes; real sockets on 127.0.0.1)."""

from __future__ import annotations

import logging
from functools import partial

import pytest
import trio
from ippc.server.config import ServerConfig
from ippc.server.limits import ConnectionTable
from ippc.server.workers import serve_with_workers, supported

from .harness import RDDL, RawClient, noop_session, root_of, running_server, session_request
from .test_limits import closed_within, connect_from


def test_the_table_names_the_oldest_idle_connection() -> None:
    table = ConnectionTable(3, 3, min_idle_age=1.0)
    for key in (1, 2, 3):
        table.add(key, "127.0.0.2")
    assert table.full()
    assert table.oldest_idle(now=0.0) is None  # (all of them younger than a second)
    now = table._opened[3] + 2.0
    table.in_session(1)
    assert table.oldest_idle(now) == 2
    table.evicting(2)
    assert not table.full() and table.oldest_idle(now) == 3
    table.remove(2)
    assert table.open == 2 and not table.full()


async def _idle_then_good(port: int, caplog: pytest.LogCaptureFixture) -> None:
    with trio.fail_after(30):
        playing = await RawClient.connect(port)  # a session in progress: never closed
        await playing.send(session_request(client="playing"))
        assert root_of(await playing.recv()) == "session-init"
        idle = [await connect_from("127.0.0.2", port) for _ in range(2)]
        await trio.sleep(1.3)  # idle for over a second
        # the cap (3) is reached: the good client's connection makes room (with
        # workers, the next connection finds it: a client tries again)
        start = trio.current_time()
        result = None
        for _ in range(20):
            try:
                result = await noop_session(port, client="good")
                break
            except Exception:  # refused (closed at once): try again
                await trio.sleep(0.1)
        took = trio.current_time() - start
        assert result is not None
        assert len(result["rounds"]) == 1
        assert took < 10  # (not the 30 s request deadline of the idle ones)
        assert await closed_within(idle[0], 5)  # the oldest idle one was closed
        assert not await closed_within(idle[1], 0.2)
        await playing.send(b"")  # still there
    text = "\n".join(r.getMessage() for r in caplog.records)
    assert "closed to make room" in text


@pytest.mark.trio
async def test_one_process_closes_the_oldest_idle_connection_for_a_new_one(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO)
    config = ServerConfig(port=0, rounds=1, max_connections=3, max_connections_per_address=3)
    async with running_server(config) as (port, _):
        await _idle_then_good(port, caplog)


@pytest.mark.trio
@pytest.mark.alone
@pytest.mark.skipif(supported() is not None, reason=str(supported()))
async def test_workers_close_the_oldest_idle_connection_for_a_new_one(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO)
    config = ServerConfig(port=0, rounds=1, max_connections=3, max_connections_per_address=3)
    async with trio.open_nursery() as nursery:
        port = await nursery.start(partial(serve_with_workers, config, [str(RDDL)], 2))
        await _idle_then_good(port, caplog)
        nursery.cancel_scope.cancel()
