"""Training rounds (`rounds_training`): round-requests with execute-policy
no before the evaluated rounds.

In monitor-execution mode (rddlsim's 8th argument, our
`monitor_execution`) such a round is practice: round-init round-num 0,
not counted in the total. Without monitor mode, rddlsim and our server
ignore execute-policy and count the round like any other: the "training"
round is then the first evaluated round, the session ends after
`num_rounds` rounds in all (one evaluated round fewer than asked for),
and the third round-request is answered with session-end.

The wire side (execute-policy no, then yes) is checked against rddlsim's
recorded monitor-mode session in test_replay.py.
"""

from __future__ import annotations

import pytest
import trio
from ippc.client.session import ClientConfig, SessionResult, run_session
from ippc.planners import make_planner
from ippc.planners.base import Planner

from .loopback import DOMAINS, our_server, settled

pytestmark = pytest.mark.trio

FOLDER = DOMAINS / "print_jobs"
INSTANCE = "print_jobs_inst_1"


async def play(port: int, training: int) -> SessionResult:
    planner = make_planner("random", {"seed": "3"})
    assert isinstance(planner, Planner)
    with trio.fail_after(30):
        return await run_session(
            ClientConfig(port=port, instance=INSTANCE, rounds_training=training, timeout=10),
            planner,
            "random",
        )


async def test_monitor_mode_training_round_is_marked_and_not_counted() -> None:
    async with our_server(FOLDER, rounds=2, monitor_execution=True) as (port, _, store):
        result = await play(port, 1)
        row = await settled(store, result.session_id)
        stored = store.rounds(row["id"])
    assert [(r.round, r.training, r.turns) for r in result.rounds] == [
        (0, True, 20),
        (1, False, 20),
        (2, False, 20),
    ]
    counted = [r.reward for r in result.rounds[1:]]
    assert result.total_reward == counted[0] + counted[1]
    assert result.mean_round_reward == pytest.approx((counted[0] + counted[1]) / 2)
    # the server agrees: the practice round is stored, not counted
    assert [(r["round_num"], r["counted"], r["reward"]) for r in stored] == [
        (r.round, not r.training, r.reward) for r in result.rounds
    ]
    assert row["total_reward"] == result.total_reward and row["rounds_used"] == 2
    assert row["status"] == "finished"


async def test_two_training_rounds_in_monitor_mode() -> None:
    async with our_server(FOLDER, rounds=1, monitor_execution=True) as (port, _, store):
        result = await play(port, 2)
        row = await settled(store, result.session_id)
    assert [(r.round, r.training) for r in result.rounds] == [(0, True), (0, True), (1, False)]
    assert result.total_reward == result.rounds[2].reward == row["total_reward"]


async def test_without_monitor_mode_the_training_round_is_counted() -> None:
    """The server counts the round asked with execute-policy no (as rddlsim
    does without monitor mode): it is round 1 of the session, its reward is
    in the total, and the session is over after 2 rounds; the client's
    third round-request is answered with session-end."""
    async with our_server(FOLDER, rounds=2) as (port, _, store):
        result = await play(port, 1)
        row = await settled(store, result.session_id)
        stored = store.rounds(row["id"])
    assert [r.round for r in result.rounds] == [1, 2]  # round-init numbers: both counted
    assert [(r["round_num"], r["counted"]) for r in stored] == [(1, True), (2, True)]
    assert row["rounds_used"] == 2 and row["status"] == "finished"
    both = result.rounds[0].reward + result.rounds[1].reward
    assert result.total_reward == both == row["total_reward"]
    # The client sees from round-init's round-num that the server counted the
    # round (a practice round repeats the last counted number) and says so.
    assert result.rounds[0].training is False
    assert result.mean_round_reward == pytest.approx(both / 2)
