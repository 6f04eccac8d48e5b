"""Helpers for running our client against our server in one trio run."""

from __future__ import annotations

import re
import select
import signal
import subprocess
import sys
from collections.abc import AsyncIterator, Iterator
from contextlib import asynccontextmanager, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import trio
from ippc.planners.base import Observation, Planner, SessionInfo, WireFluent
from ippc.server.config import ServerConfig
from ippc.server.registry import Registry
from ippc.server.session import Services
from ippc.server.store import ResultStore

from ..server.harness import running_server

REPO = Path(__file__).resolve().parents[2]
DOMAINS = REPO / "domains"


class Watch(Planner):
    """Wraps a planner and remembers every observation and the actions it
    chose for it."""

    name = "watch"

    def __init__(self, inner: Planner) -> None:
        super().__init__()
        self.inner = inner
        self.turns: list[tuple[Observation, list[WireFluent]]] = []
        self.info: SessionInfo | None = None

    def start_session(self, session: SessionInfo) -> None:
        super().start_session(session)
        self.info = session
        self.inner.start_session(session)

    def start_round(self, round_num: int) -> None:
        self.inner.start_round(round_num)

    def act(self, obs: Observation) -> list[WireFluent]:
        chosen = self.inner.act(obs)
        self.turns.append((obs, list(chosen)))
        return chosen

    def end_round(self, reward: float) -> None:
        self.inner.end_round(reward)

    def end_session(self, total_reward: float) -> None:
        self.inner.end_session(total_reward)


@asynccontextmanager
async def our_server(
    *paths: Path, **config: Any
) -> AsyncIterator[tuple[int, Registry, ResultStore]]:
    """Our server on 127.0.0.1 (port 0) for the instances in `paths`, with
    an in-memory result store; yields (port, registry, store)."""
    registry = Registry.load(*paths)
    assert len(registry), f"nothing to serve in {paths}: {registry.broken}"
    cfg = ServerConfig(**{"port": 0, **config})
    store = ResultStore(":memory:")
    try:
        async with running_server(cfg, registry, Services(cfg, registry, store=store)) as (port, _):
            yield port, registry, store
    finally:
        store.close()


def stored_session(store: ResultStore, session_id: int) -> dict[str, Any]:
    """The store's row for the server's session-id."""
    rows = [s for s in store.sessions() if s["server_session_id"] == session_id]
    assert len(rows) == 1, rows
    return rows[0]


async def settled(
    store: ResultStore, session_id: int | None, timeout: float = 5.0
) -> dict[str, Any]:
    """The session's row once the server has closed it. The server writes
    the session's end (and a round's end) into the store just after it
    sends session-end (round-end), so a client in the same trio run can
    see the message before the row is updated."""
    assert session_id is not None
    with trio.fail_after(timeout):
        while (row := stored_session(store, session_id))["status"] == "open":
            await trio.sleep(0.005)
    return row


@dataclass
class Server:
    """`rddl-server` running in a subprocess: its port, its result database."""

    port: int
    db: Path
    proc: subprocess.Popen[str]


@contextmanager
def serve_domains(db: Path, *options: str, start_timeout: float = 30) -> Iterator[Server]:
    """`rddl-server domains/ --port 0 --rounds 2 --db DB -q OPTIONS` in a subprocess,
    stopped with SIGTERM (killed if it is not gone 10 s later) at the end."""
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "from ippc.server.cli import main; main()",
            str(DOMAINS),
            "--port",
            "0",
            "--rounds",
            "2",
            *options,
            "--db",
            str(db),
            "-q",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        assert proc.stdout is not None
        ready, _, _ = select.select([proc.stdout], [], [], start_timeout)
        line = proc.stdout.readline() if ready else ""
        m = re.match(r"listening on 127\.0\.0\.1:(\d+)$", line.strip())
        assert m, f"the server did not start: {line!r}"
        yield Server(int(m.group(1)), db, proc)
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)
