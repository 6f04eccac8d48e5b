"""Many clients at once: each finishes, each gets what it would alone."""

from __future__ import annotations

import pytest
from ippc.server.config import ServerConfig

from .harness import noop_session, noop_sessions_at_once, running_server

# many sessions at once: needs the machine to itself
pytestmark = [pytest.mark.trio, pytest.mark.alone]

CLIENTS = 200


async def test_200_concurrent_clients_get_their_results_alone() -> None:
    config = ServerConfig(port=0, rounds=2, seed=7)
    async with running_server(config) as (port, _):
        results = await noop_sessions_at_once(port, CLIENTS)
    assert len(results) == CLIENTS
    assert sorted(r["session_id"] for r in results) == list(range(1, CLIENTS + 1))
    assert all(len(r["rounds"]) == 2 for r in results)
    # Alone: session k of a server seeded s uses seed s + k - 1, so a fresh
    # server seeded 7 + k - 1 gives session k's run to its first session.
    for r in sorted(results, key=lambda r: r["session_id"])[:: CLIENTS // 8]:
        k = r["session_id"]
        async with running_server(ServerConfig(port=0, rounds=2, seed=7 + k - 1)) as (port, _):
            alone = await noop_session(port, client="alone")
        assert alone["session_id"] == 1
        assert alone["rounds"] == r["rounds"]
        assert alone["states"] == r["states"]
