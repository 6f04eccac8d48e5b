"""The client's clock: every turn the planner gets a deadline (a
time.monotonic() value). The client spreads what is left of the session's
budget evenly over the steps left in the session (PROST's uniform time
manager), by its own clock and the server's time-left, whichever says less.

So for a planner that uses all the time it is given, the deadlines stay in
the future, the time per turn shrinks slowly (by the overhead of each turn)
and the time offered over the whole session adds up to no more than the
session's time-allowed. A planner that answers at once leaves its time
unused; that time is offered again in later turns, so the last turn of its
session is offered about the whole budget.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import pytest
import trio
from ippc.client.session import ClientConfig, run_session
from ippc.planners.base import Observation, Planner, SessionInfo, WireFluent

from .loopback import DOMAINS, our_server, settled

# measures how a planner's time is spread over the steps: needs the machine to itself
pytestmark = [pytest.mark.trio, pytest.mark.alone]

ALLOWED = 1.0  # seconds: the server's --timeout, sent as time-allowed 1000.0
HORIZON = 15  # corridor_enum
ROUNDS = 2
# Between the client's reading of the clock and the planner's there is a
# little work (and whatever else the machine is doing): timing comparisons
# allow this much.
SLACK = 0.01


@dataclass
class Seen:
    turn: int
    now: float
    deadline: float
    time_left: float  # the server's, in seconds

    @property
    def offered(self) -> float:
        return self.deadline - self.now


class Clocked(Planner):
    """Noop that records its deadlines; `spend`: sleeps until each one."""

    name = "clocked"

    def __init__(self, spend: bool) -> None:
        super().__init__()
        self.spend = spend
        self.seen: list[Seen] = []
        self.time_allowed: float | None = None

    def start_session(self, session: SessionInfo) -> None:
        super().start_session(session)
        self.time_allowed = session.time_allowed

    def act(self, obs: Observation) -> list[WireFluent]:
        now = time.monotonic()
        self.seen.append(Seen(obs.turn, now, obs.deadline, obs.time_left))
        if self.spend:
            # blocks the trio thread (and our in-process server, which is
            # only waiting for this answer anyway)
            time.sleep(max(0.0, obs.deadline - time.monotonic()))
        return []


async def play(spend: bool) -> tuple[Clocked, float]:
    planner = Clocked(spend)
    async with our_server(DOMAINS / "corridor_enum", rounds=ROUNDS, timeout=ALLOWED) as (
        port,
        registry,
        store,
    ):
        t0 = time.monotonic()
        with trio.fail_after(ALLOWED + 10):
            result = await run_session(
                ClientConfig(port=port, instance=registry.names()[0], timeout=10), planner
            )
        elapsed = time.monotonic() - t0
        # a planner that uses all its time still leaves the session within budget
        row = await settled(store, result.session_id)
        assert row["status"] == "finished", row
    assert [(r.round, r.turns) for r in result.rounds] == [(1, HORIZON), (2, HORIZON)]
    assert planner.time_allowed == ALLOWED
    assert len(planner.seen) == ROUNDS * HORIZON
    return planner, elapsed


async def test_deadlines_of_a_planner_that_uses_its_time() -> None:
    planner, elapsed = await play(spend=True)
    seen = planner.seen
    offered = [s.offered for s in seen]
    # in the future, and never more than the server says is left
    for s in seen:
        assert 0 < s.offered <= s.time_left, s
    # the first turn gets about an even share of the session
    assert ALLOWED / (ROUNDS * HORIZON) * 0.5 < offered[0] <= ALLOWED / (ROUNDS * HORIZON)
    # shrinking: each turn's overhead comes out of the later turns
    for a, b in zip(seen, seen[1:], strict=False):
        assert b.offered <= a.offered + SLACK, (a, b)
    assert offered[-1] < offered[0]
    # the server's time-left goes down all the time
    for a, b in zip(seen, seen[1:], strict=False):
        assert b.time_left < a.time_left, (a, b)
    # the deadlines move forward in time and the offers add up to no more
    # than the session's budget
    for a, b in zip(seen, seen[1:], strict=False):
        assert b.deadline > a.deadline, (a, b)
    assert sum(offered) <= ALLOWED
    assert elapsed <= ALLOWED + 0.25


async def test_deadlines_of_a_planner_that_answers_at_once() -> None:
    planner, elapsed = await play(spend=False)
    seen = planner.seen
    total = ROUNDS * HORIZON
    assert elapsed < ALLOWED
    for i, s in enumerate(seen):
        assert 0 < s.offered <= s.time_left, s
        # an even share of what is left, over the steps left in the session
        # (the budget minus what the session has used so far)
        assert s.offered <= ALLOWED / (total - i) + 1e-6
        # (less the client's reserve for messages: max(0.1 s, 2% of the budget))
        reserve = max(0.1, 0.02 * ALLOWED)
        assert s.offered >= (ALLOWED - elapsed - reserve) / (total - i) - SLACK, s
    # unused time is offered again: the offers grow, the last turn gets
    # nearly the whole budget, and their sum exceeds the budget
    offered = [s.offered for s in seen]
    for a, b in zip(seen, seen[1:], strict=False):
        assert b.offered > a.offered - SLACK, (a, b)
    assert offered[-1] > 0.5 * ALLOWED
    assert sum(offered) > ALLOWED
