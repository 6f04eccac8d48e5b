"""A one-connection test server that replays the server side of a recorded
rddlsim session (tests/data/rddlsim) to our client.

The script is the recorded s2c bytes in order: after each recorded c2s
message, the server waits for one message from the client (any content:
our planner's actions differ from the recorded ones) and then sends the next
recorded s2c messages, byte for byte (bare, as recorded, in no-header
sessions). A recorded server EOF closes the connection; a `stall` step
keeps it open and silent. Bounded in time; 127.0.0.1 only.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import trio
from ippc.client.session import ClientConfig, ClientError, SessionResult, run_session
from ippc.planners.base import Planner
from ippc.planners.basic import NoopPlanner
from ippc.protocol import MessageReader, RoundEnd, RoundInit, SessionEnd, SessionInit, decode

from ..server.harness import TRANSCRIPTS, root_of

StepKind = Literal["c2s", "s2c", "close", "stall"]


@dataclass(frozen=True)
class Step:
    """One step of the server's script."""

    kind: StepKind
    data: bytes = b""  # s2c: the exact bytes to send; c2s: the recorded message (for its root)


def load(name: str) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The meta line and the records of a scenario."""
    lines = [json.loads(x) for x in (TRANSCRIPTS / f"{name}.jsonl").read_text().splitlines()]
    return lines[0]["meta"], lines[1:]


def server_script(records: list[dict[str, Any]], conn: int | None = None) -> list[Step]:
    """The steps of one recorded connection as the server played it. The
    Java-client recordings have one connection and no `conn` key."""
    steps: list[Step] = []
    for rec in records:
        if rec.get("conn") != conn:
            continue  # another connection (notes have no conn and no data)
        if "data" in rec:
            kind: StepKind = "c2s" if rec["dir"] == "c2s" else "s2c"
            steps.append(Step(kind, rec["data"].encode("ascii")))
        elif rec.get("event") == "eof" and rec["dir"] == "s2c":
            steps.append(Step("close"))
    return steps


def scenario_script(name: str, conn: int | None = None) -> tuple[dict[str, Any], list[Step]]:
    meta, records = load(name)
    return meta, server_script(records, conn)


def messages(steps: list[Step]) -> list[Any]:
    """The decoded s2c messages of a script (bare or framed, as recorded)."""
    out = []
    for s in steps:
        if s.kind == "s2c":
            out.append(decode(s.data.rstrip(b"\0")))
    return out


def c2s_roots(steps: list[Step]) -> list[str]:
    return [root_of(s.data) for s in steps if s.kind == "c2s"]


@dataclass
class Expected:
    """What the recorded server said about the session."""

    session_id: int
    num_rounds: int
    rounds: list[tuple[int, float, int]]  # (round-init round-num, round-reward, turns-used)
    total: float | None
    rounds_used: int | None


def expected(steps: list[Step]) -> Expected:
    msgs = messages(steps)
    init = next(m for m in msgs if isinstance(m, SessionInit))
    rounds: list[tuple[int, float, int]] = []
    current: int | None = None
    total = used = None
    for m in msgs:
        if isinstance(m, RoundInit):
            current = m.round_num
        elif isinstance(m, RoundEnd):
            assert current is not None
            rounds.append((current, m.round_reward, m.turns_used))
        elif isinstance(m, SessionEnd):
            total, used = m.total_reward, m.rounds_used
    return Expected(init.session_id, init.num_rounds, rounds, total, used)


@dataclass
class ReplayServer:
    """Serve `script` to one client connection."""

    script: list[Step]
    linger: float = 5.0  # how long to wait for the client once the script is done
    stall: float = 30.0  # upper bound of a `stall` step (the test cancels it sooner)
    received: list[bytes] = field(default_factory=list)  # the client's messages, in order
    finished: bool = False  # every step was played
    client_closed: bool = False  # the client closed its side
    done: trio.Event = field(default_factory=trio.Event)

    async def serve(self, task_status: trio.TaskStatus[int] = trio.TASK_STATUS_IGNORED) -> None:
        try:
            listeners = await trio.open_tcp_listeners(0, host="127.0.0.1")
            listener = listeners[0]
            async with listener:
                task_status.started(listener.socket.getsockname()[1])
                stream = await listener.accept()
            async with stream:
                await self._play(stream, MessageReader("nul"))
        finally:
            self.done.set()

    async def _recv(self, stream: trio.SocketStream, reader: MessageReader) -> bytes | None:
        """One client message (our client always ends its messages with a NUL)."""
        while True:
            msg = reader.next_message()
            if msg is not None:
                return msg
            if reader.at_eof:
                return None
            try:
                data = await stream.receive_some(65536)
            except (trio.BrokenResourceError, trio.ClosedResourceError):
                data = b""
            if data:
                reader.feed(data)
            else:
                reader.feed_eof()
                self.client_closed = True

    async def _play(self, stream: trio.SocketStream, reader: MessageReader) -> None:
        for step in self.script:
            if step.kind == "s2c":
                try:
                    await stream.send_all(step.data)
                except (trio.BrokenResourceError, trio.ClosedResourceError):
                    return
            elif step.kind == "c2s":
                msg = await self._recv(stream, reader)
                if msg is None:
                    return
                self.received.append(msg)
            elif step.kind == "stall":
                # silent until the client gives up (closes) or `stall` passes
                await self._drain(stream, reader, self.stall)
                return
            else:  # close
                self.finished = True
                return
        self.finished = True
        # As rddlsim: keep the connection until the client closes it (bounded);
        # whatever the client sends now is recorded too.
        await self._drain(stream, reader, self.linger)

    async def _drain(
        self, stream: trio.SocketStream, reader: MessageReader, seconds: float
    ) -> None:
        with trio.move_on_after(seconds):
            while (msg := await self._recv(stream, reader)) is not None:
                self.received.append(msg)


async def play(
    script: list[Step],
    config: ClientConfig,
    planner: Planner | None = None,
    *,
    limit: float = 20.0,
    linger: float = 5.0,
) -> tuple[SessionResult | ClientError, ReplayServer]:
    """Run our client against a replay of `script`; the client's result or
    its ClientError, and the server (what it received)."""
    server = ReplayServer(script, linger=linger)
    outcome: SessionResult | ClientError
    with trio.fail_after(limit):
        async with trio.open_nursery() as nursery:
            port = await nursery.start(server.serve)
            try:
                outcome = await run_session(
                    replace(config, host="127.0.0.1", port=port), planner or NoopPlanner(), "noop"
                )
            except ClientError as err:
                outcome = err
            # the server notices the client's close (or gives up lingering)
            with trio.move_on_after(min(linger, 5.0) + 1.0):
                await server.done.wait()
            nursery.cancel_scope.cancel()
    return outcome, server


def mean(values: list[float]) -> float:
    return math.fsum(values) / len(values) if values else 0.0


def rddl_dir() -> Path:
    return TRANSCRIPTS.parent / "rddl"
