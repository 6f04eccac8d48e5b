"""Our client against recorded rddlsim server behaviour.

A small trio server (tests/client/replay.py) replays the server side of the
recorded sessions in tests/data/rddlsim: after each recorded client
message it reads one message from our client (any content: our noop planner
answers differently from the recorded clients) and sends the next recorded
server bytes exactly, bare in no-header sessions. Our client must complete
the session with the recorded rewards, or stop with the ClientError the
situation calls for -- never hang.

Which scenarios, and why (the client only plays the client role, so a
recorded session is replayed only as far as our well-behaved client can
follow it):

* played to the end: every java_* session except the two below, the
  py_* sessions whose recorded client was legal or whose odd messages
  rddlsim answered like legal ones (py_sysadmin_legal_variants,
  py_sidewalk_enum, py_mars_rover_reals),
  the early round-ends (py_too_many_actions, py_constraint_violation_reals,
  py_state_fluent_as_action_true), the session time-out (py_session_timeout),
  no-header mode (py_prost_style_noheader, connection 0), monitor mode
  (py_execute_policy_no_monitor, with one training round as its client
  asked), connection 1 of py_disconnect_mid_round (connection 0 is a client
  that vanished), and py_resource_request with its resource-request
  exchanges cut out (our client never sends one, and a resource-notification
  where the client awaits a round-init is a protocol error).
* rddlsim closes the connection: the server's EOF is replayed where it was
  recorded, so the client sees the close at that point of the session.
  rddlsim closed because of the recorded client's bad message (unknown
  instance, malformed or wrong-rooted message, unknown action, bad value,
  a simulation error in java_mars_rover_simerror, individual-session mode);
  our client's message there is legal, so these replays show how the client
  handles a close at that point, not what rddlsim would answer to it.
* java_client_early_round_end_deadlock: replayed up to the early round-end.
  The Java client then waited for a session-end (deadlock) and the recording
  holds only resource-notifications sent after it was killed; our client
  must send the next round-request instead, after which the replay closes.
* py_input_language_pddl: rddlsim's session-init `null` (it answered a
  request for PDDL, which our client never makes) serves as garbage from a
  real rddlsim server.
* py_two_clients_global_read_lock, connection 1: rddlsim stalled (no
  session-init for 3 s while another client held its reader); with a short
  --timeout our client gives up with a ClientError.
* py_prost_style_noheader, connection 1: after a no-header session rddlsim
  sends bare XML to every later client; our client without no_header waits
  for a NUL that never comes and times out.
* not replayed: py_malformed_session_request and py_disconnect_mid_message
  (their subject is a bad client message; what is left is a plain close,
  covered above), py_disconnect_mid_round connection 0 (the client vanished).
"""

from __future__ import annotations

import re
from typing import Any

import pytest
import trio
from ippc.client.session import ClientConfig, ClientError, SessionResult, model_from_task
from ippc.planners.base import Observation, Planner, WireFluent
from ippc.protocol import SessionInit, Turn, decode

from ..server.harness import DECL, root_of
from .replay import Step, c2s_roots, expected, mean, messages, play, scenario_script

pytestmark = pytest.mark.trio

NOOP = DECL + b"<actions/>"


class Recorder(Planner):
    """Noop, remembering what it was shown."""

    name = "recorder"

    def __init__(self) -> None:
        super().__init__()
        self.observations: list[Observation] = []
        self.rounds_started: list[int] = []
        self.rounds_ended: list[float] = []
        self.total: float | None = None

    def start_round(self, round_num: int) -> None:
        self.rounds_started.append(round_num)

    def act(self, obs: Observation) -> list[WireFluent]:
        self.observations.append(obs)
        return []

    def end_round(self, reward: float) -> None:
        self.rounds_ended.append(reward)

    def end_session(self, total_reward: float) -> None:
        self.total = total_reward


# scenario -> (connection, client settings)
COMPLETE: dict[str, tuple[int | None, dict[str, Any]]] = {
    "java_sysadmin_mdp": (None, {}),
    "java_sysadmin_pomdp": (None, {}),
    "java_game_of_life": (None, {}),
    "java_elevators": (None, {}),
    "java_crossing_traffic": (None, {}),
    "java_sidewalk": (None, {}),
    "java_traffic_ctm_enum": (None, {}),
    "py_sysadmin_legal_variants": (0, {}),
    "py_sysadmin_pomdp": (0, {}),
    "py_mars_rover_reals": (0, {}),
    "py_sidewalk_enum": (0, {}),
    "py_slow_reply_no_timeout_hit": (0, {}),
    "py_prost_style_noheader": (0, {"no_header": True}),
    "py_disconnect_mid_round": (1, {}),
    "py_execute_policy_no_monitor": (0, {"rounds_training": 1}),
    "py_too_many_actions": (0, {}),
    "py_constraint_violation_reals": (0, {}),
    "py_state_fluent_as_action_true": (0, {}),
    "py_session_timeout": (0, {}),
}

POMDP = {"java_sysadmin_pomdp", "py_sysadmin_pomdp"}
EARLY_END = {
    "py_too_many_actions",
    "py_constraint_violation_reals",
    "py_state_fluent_as_action_true",
}


def horizon_of(steps: list[Step], instance: str) -> int:
    init = decode(next(s.data for s in steps if s.kind == "s2c").rstrip(b"\0"))
    assert isinstance(init, SessionInit)
    model = model_from_task(init.task, instance)
    assert model.horizon is not None
    return model.horizon


def without_resource_requests(steps: list[Step]) -> list[Step]:
    """Cut out every client message that rddlsim answered with a
    resource-notification, and that answer (py_resource_request: two
    resource-requests and one malformed round-request)."""
    out: list[Step] = []
    i = 0
    while i < len(steps):
        if (
            steps[i].kind == "c2s"
            and i + 1 < len(steps)
            and steps[i + 1].kind == "s2c"
            and root_of(steps[i + 1].data) == "resource-notification"
        ):
            i += 2
            continue
        out.append(steps[i])
        i += 1
    return out


def check_complete(
    name: str,
    meta: dict[str, Any],
    steps: list[Step],
    result: SessionResult | ClientError,
    server: Any,
    planner: Recorder,
    cfg: dict[str, Any],
) -> None:
    assert isinstance(result, SessionResult), f"{name}: {result}"
    want = expected(steps)
    assert server.finished
    # our client sent one message per recorded client message, with the same roots
    assert [root_of(m) for m in server.received] == c2s_roots(steps)
    assert all(m == NOOP for m in server.received if root_of(m) == "actions")
    assert result.instance == meta["instance"]
    assert result.session_id == want.session_id
    got = [(r.round, r.reward, r.turns) for r in result.rounds]
    assert got == want.rounds
    assert want.total is not None
    assert result.total_reward == want.total
    training = [r.training for r in result.rounds]
    assert training == [True] * cfg.get("rounds_training", 0) + [False] * (
        len(got) - cfg.get("rounds_training", 0)
    )
    counted = [r.reward for r in result.rounds if not r.training]
    assert result.mean_round_reward == pytest.approx(mean(counted))
    assert result.total_reward == pytest.approx(sum(counted))
    # the planner saw every round and every turn the server sent
    assert planner.rounds_started == [r.round for r in result.rounds]
    assert planner.rounds_ended == [r.reward for r in result.rounds]
    assert planner.total == want.total
    # ... as the server sent it
    turns = [m for m in messages(steps) if isinstance(m, Turn)]
    assert len(planner.observations) == len(turns)
    for obs, turn in zip(planner.observations, turns, strict=True):
        assert obs.turn == turn.turn_num
        assert obs.immediate_reward == turn.immediate_reward
        assert obs.time_left == turn.time_left / 1000
        if turn.fluents is None:
            assert obs.fluents is None
        else:
            assert obs.fluents is not None
            assert set(obs.fluents) == {(f.name, tuple(f.args)) for f in turn.fluents}
    horizon = horizon_of(steps, meta["instance"])
    for r in result.rounds:
        assert (r.ended_early is None) == (r.turns >= horizon)
        assert r.seconds >= 0


@pytest.mark.parametrize("name", sorted(COMPLETE))
async def test_session_completes_with_the_recorded_rewards(name: str) -> None:
    conn, cfg = COMPLETE[name]
    meta, steps = scenario_script(name, conn)
    planner = Recorder()
    result, server = await play(
        steps, ClientConfig(instance=meta["instance"], timeout=5.0, **cfg), planner
    )
    check_complete(name, meta, steps, result, server, planner, cfg)
    assert isinstance(result, SessionResult)
    early = [r.round for r in result.rounds if r.ended_early]
    assert bool(early) == (name in EARLY_END or name == "py_session_timeout")
    obs = planner.observations
    if name in POMDP:
        # turn 1 of every round is <no-observed-fluents/>; no state for POMDPs
        firsts = [o for o in obs if o.turn == 1]
        assert firsts and all(o.fluents is None for o in firsts)
        assert all(o.fluents for o in obs if o.turn > 1)
        assert all(o.state is None for o in obs)
    else:
        assert all(o.fluents is not None and o.state is not None for o in obs)
    assert [o.immediate_reward for o in obs if o.turn == 1] == [0.0] * len(
        [o for o in obs if o.turn == 1]
    )


async def test_resource_request_session_without_the_resource_exchanges() -> None:
    meta, steps = scenario_script("py_resource_request", 0)
    cut = without_resource_requests(steps)
    assert len(steps) - len(cut) == 6  # three requests, three notifications
    planner = Recorder()
    result, server = await play(cut, ClientConfig(instance=meta["instance"], timeout=5.0), planner)
    check_complete("py_resource_request", meta, cut, result, server, planner, {})


async def test_early_round_end_goes_on_to_the_next_round() -> None:
    """rddlsim ends a round at an illegal action (turns-used 1) and plays
    the next round normally: the client follows, marks the short round."""
    meta, steps = scenario_script("py_too_many_actions", 0)
    result, _ = await play(steps, ClientConfig(instance=meta["instance"], timeout=5.0))
    assert isinstance(result, SessionResult)
    assert [(r.round, r.turns) for r in result.rounds] == [(1, 1), (2, 5)]
    assert result.rounds[0].ended_early is not None and "early" in result.rounds[0].ended_early
    assert result.rounds[1].ended_early is None
    assert result.total_reward == 55.0 and result.mean_round_reward == 27.5


async def test_zero_turn_round() -> None:
    """A round-end right after the first turn's answer (turns-used 0)."""
    meta, steps = scenario_script("py_state_fluent_as_action_true", 0)
    planner = Recorder()
    result, _ = await play(steps, ClientConfig(instance=meta["instance"], timeout=5.0), planner)
    assert isinstance(result, SessionResult)
    assert [(r.round, r.reward, r.turns) for r in result.rounds] == [(1, 0.0, 0)]
    assert len(planner.observations) == 1


async def test_session_timeout_stops_cleanly() -> None:
    """py_session_timeout: 3 rounds offered, the budget (2 s) runs out in
    round 1: round-end, then session-end at once. The client has already
    sent its next round-request; it takes the session-end as the end."""
    meta, steps = scenario_script("py_session_timeout", 0)
    assert [root_of(s.data) for s in steps if s.kind == "s2c"][-2:] == ["round-end", "session-end"]
    assert steps[-1].kind == "close"
    # as recorded (rddlsim closes right after the session-end, so the
    # client's round-request meets a closed socket), and with the server
    # keeping the connection open to see what the client sends
    for script in (steps, steps[:-1]):
        result, server = await play(
            script, ClientConfig(instance=meta["instance"], timeout=5.0), linger=1.0
        )
        assert isinstance(result, SessionResult)
        assert [(r.round, r.reward, r.turns) for r in result.rounds] == [(1, 20.0, 2)]
        assert result.rounds[0].ended_early is not None
        assert result.total_reward == 20.0
    # the round-request for round 2 went out before the session-end was read
    assert [root_of(m) for m in server.received] == [
        "session-request",
        "round-request",
        "actions",
        "actions",
        "round-request",
    ]
    assert server.client_closed


async def test_monitor_mode_training_round() -> None:
    """py_execute_policy_no_monitor (rddlsim in monitor mode): the round
    asked with execute-policy no is numbered 0, not counted in the total."""
    meta, steps = scenario_script("py_execute_policy_no_monitor", 0)
    result, server = await play(
        steps, ClientConfig(instance=meta["instance"], timeout=5.0, rounds_training=1)
    )
    assert isinstance(result, SessionResult)
    assert [(r.round, r.reward, r.training) for r in result.rounds] == [
        (0, 47.0, True),
        (1, 44.0, False),
    ]
    assert result.total_reward == 44.0 and result.mean_round_reward == 44.0
    requests = [m for m in server.received if root_of(m) == "round-request"]
    policies = [re.search(rb"<execute-policy>(\w+)<", m) for m in requests]
    assert [p.group(1) if p else None for p in policies] == [b"no", b"yes"]


# scenario -> (connection, what the client waited for when rddlsim closed)
CLOSED: dict[str, tuple[int | None, str]] = {
    "py_unknown_instance": (0, "session-init"),
    "py_wrong_root_round_request": (0, "round-init"),
    "py_malformed_action": (0, "a turn or round-end"),
    "py_wrong_root_action": (0, "a turn or round-end"),
    "py_unknown_action_name": (0, "a turn or round-end"),
    "py_bad_real_value": (0, "a turn or round-end"),
    "py_state_fluent_as_action_default": (0, "a turn or round-end"),
    "py_individual_session_exit": (0, "a turn or round-end"),
    "py_wrong_arg_count_and_unknown_object": (0, "a turn or round-end"),
    "java_mars_rover_simerror": (None, "a turn or round-end"),
}


@pytest.mark.parametrize("name", sorted(CLOSED))
async def test_server_closes_the_connection(name: str) -> None:
    conn, waiting = CLOSED[name]
    meta, steps = scenario_script(name, conn)
    assert steps[-1].kind == "close"
    with trio.fail_after(10):
        result, server = await play(steps, ClientConfig(instance=meta["instance"], timeout=5.0))
    assert isinstance(result, ClientError)
    assert str(result) == f"the server closed the connection while we waited for {waiting}"
    assert server.finished
    assert len(server.received) == len(c2s_roots(steps))


async def test_java_client_deadlock_scenario_our_client_asks_for_the_next_round() -> None:
    """rddlsim ended round 1 early (an illegal second action); the Java
    client then waited for a session-end while rddlsim waited for a
    round-request. Ours sends the round-request; the replay has nothing
    recorded to answer it with, so it closes."""
    meta, steps = scenario_script("java_client_early_round_end_deadlock")
    cut = [
        s
        for s in steps[: next(i for i, s in enumerate(steps) if root_of(s.data) == "round-end") + 1]
    ]
    script = [*cut, Step("c2s", DECL + b"<round-request/>\0"), Step("close")]
    result, server = await play(script, ClientConfig(instance=meta["instance"], timeout=5.0))
    assert isinstance(result, ClientError)
    assert str(result) == "the server closed the connection while we waited for round-init"
    assert [root_of(m) for m in server.received] == [
        "session-request",
        "round-request",
        "actions",
        "actions",
        "round-request",
    ]


async def test_null_session_init_is_a_bad_message() -> None:
    meta, steps = scenario_script("py_input_language_pddl", 0)
    assert steps[1] == Step("s2c", b"null\0")
    result, _ = await play(steps[:2], ClientConfig(instance=meta["instance"], timeout=5.0))
    assert isinstance(result, ClientError)
    assert str(result).startswith("bad message from the server while waiting for session-init: ")
    assert "null" in str(result)


async def test_stalled_rddlsim_times_out() -> None:
    """rddlsim held back client B's session-init for 3 s (one global
    reader); with timeout 0.5 s the client stops with a ClientError."""
    meta, records = scenario_script("py_two_clients_global_read_lock", 1)
    assert [s.kind for s in records] == ["c2s", "s2c"]
    script = [records[0], Step("stall")]
    t0 = trio.current_time()
    result, _ = await play(script, ClientConfig(instance=meta["instance"], timeout=0.5), linger=0.5)
    assert isinstance(result, ClientError)
    assert str(result) == "no answer from the server for 0.5 s while waiting for session-init"
    assert trio.current_time() - t0 < 3


async def test_bare_xml_to_a_client_without_no_header_times_out() -> None:
    """After a no-header session rddlsim writes bare XML (no NUL) to every
    later client. A client that did not ask for no-header reads up to a NUL
    that never comes: it must not hang."""
    meta, steps = scenario_script("py_prost_style_noheader", 1)
    assert not steps[1].data.endswith(b"\0")
    result, _ = await play(
        steps[:2] + [Step("stall")],
        ClientConfig(instance=meta["instance"], timeout=0.5),
        linger=0.5,
    )
    assert isinstance(result, ClientError)
    assert "0.5 s" in str(result) and "session-init" in str(result)


# ------------------------------------------------------------ synthetic faults


def _java_sysadmin() -> tuple[dict[str, Any], list[Step]]:
    return scenario_script("java_sysadmin_mdp")


async def test_stall_mid_round_times_out() -> None:
    meta, steps = _java_sysadmin()
    # session-init, round-init, turn 1 answered, then silence
    upto = [i for i, s in enumerate(steps) if s.kind == "c2s"][2]  # the first actions
    script = [*steps[: upto + 1], Step("stall")]
    assert [root_of(s.data) for s in script if s.kind == "s2c"] == [
        "session-init",
        "round-init",
        "turn",
    ]
    t0 = trio.current_time()
    result, _ = await play(script, ClientConfig(instance=meta["instance"], timeout=0.3), linger=0.5)
    assert isinstance(result, ClientError)
    assert (
        str(result) == "no answer from the server for 0.3 s while waiting for a turn or round-end"
    )
    assert trio.current_time() - t0 < 3


GARBAGE: dict[str, bytes] = {
    "binary": b"\xff\xfe garbage \x01\x02\0",
    "empty frame": b"\0",
    "not xml": b"hello, this is not XML\0",
    "unknown root": DECL + b"<hello/>\0",
    "doctype": DECL
    + b'<!DOCTYPE x [<!ENTITY e SYSTEM "file:///etc/passwd">]><session-init>&e;</session-init>\0',
    "bad number": DECL + b"<session-init><task>eA==</task><session-id>one</session-id>"
    b"<num-rounds>1</num-rounds><time-allowed>1000.0</time-allowed></session-init>\0",
    "truncated then close": DECL + b"<session-init><task>",
}


@pytest.mark.parametrize("kind", sorted(GARBAGE))
async def test_garbage_instead_of_session_init(kind: str) -> None:
    meta, steps = _java_sysadmin()
    script = [steps[0], Step("s2c", GARBAGE[kind])]
    if kind == "truncated then close":
        script.append(Step("close"))
    else:
        script.append(Step("stall"))
    result, _ = await play(script, ClientConfig(instance=meta["instance"], timeout=3.0), linger=0.5)
    assert isinstance(result, ClientError)
    text = str(result)
    assert text.startswith("bad message from the server while waiting for session-init: "), text
    if kind == "truncated then close":
        assert "closed" in text


async def test_garbage_mid_round() -> None:
    """A turn whose turn-num is not a number, then a message that is not
    legal here (session-end inside a round)."""
    meta, steps = _java_sysadmin()
    upto = [i for i, s in enumerate(steps) if s.kind == "c2s"][2]  # after the first actions
    bad_turn = (
        DECL + b"<turn><turn-num>two</turn-num><time-left>1.0</time-left>"
        b"<immediate-reward>0.0</immediate-reward><no-observed-fluents/></turn>\0"
    )
    result, _ = await play(
        [*steps[: upto + 1], Step("s2c", bad_turn), Step("stall")],
        ClientConfig(instance=meta["instance"], timeout=3.0),
        linger=0.5,
    )
    assert isinstance(result, ClientError)
    assert "while waiting for a turn or round-end" in str(result) and "turn-num" in str(result)
    session_end = next(s for s in steps if root_of(s.data) == "session-end")
    result, _ = await play(
        [*steps[: upto + 1], session_end, Step("stall")],
        ClientConfig(instance=meta["instance"], timeout=3.0),
        linger=0.5,
    )
    assert isinstance(result, ClientError)
    assert str(result).startswith(
        "bad message from the server while waiting for a turn or round-end"
    )
    assert "session-end" in str(result)


async def test_endless_message_is_refused() -> None:
    """More than the 10 MB message limit without a terminator: refused,
    not buffered forever."""
    meta, steps = _java_sysadmin()
    blob = b"<session-init><task>" + b"A" * (11 * 1024 * 1024)
    result, _ = await play(
        [steps[0], Step("s2c", blob), Step("stall")],
        ClientConfig(instance=meta["instance"], timeout=5.0),
        linger=0.5,
    )
    assert isinstance(result, ClientError)
    assert str(result).startswith("bad message from the server while waiting for session-init")


async def test_task_that_does_not_load() -> None:
    """A session-init whose task is not RDDL for the instance asked."""
    meta, steps = _java_sysadmin()
    init = (
        DECL + b"<session-init><task>bm90IHJkZGw=</task><session-id>1</session-id>"  # "not rddl"
        b"<num-rounds>1</num-rounds><time-allowed>1000.0</time-allowed></session-init>\0"
    )
    result, _ = await play(
        [steps[0], Step("s2c", init), Step("stall")],
        ClientConfig(instance=meta["instance"], timeout=3.0),
        linger=0.5,
    )
    assert isinstance(result, ClientError)
    assert str(result).startswith(f"the server's task for '{meta['instance']}' does not load: ")
