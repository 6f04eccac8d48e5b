"""`random` is rddlsim's RandomConcurrentPolicy: the Java generator bit for
bit, and the recorded Java sessions' choices byte for byte."""

from __future__ import annotations

import gzip
import json
import time
from pathlib import Path

import pytest
from ippc.client.session import model_from_task
from ippc.planners import Observation, PlannerError, RandomPlanner, SessionInfo
from ippc.planners.javarandom import RandomDataGenerator, Well19937c
from ippc.planners.rddlsim_random import STUCK_MESSAGE, RandomConcurrentPolicy, Stuck
from ippc.protocol import Actions, Fluent, SessionInit, Turn, decode, encode, parse_value
from ippc.rddl import load_pair
from ippc.rddl.simulator import Simulator
from ippc.rddl.wire import WireCodec, rddlsim_action_order, value_kind

from ..conftest import ippc_files

# Java sessions of rddl.competition.Client with rddl.policy.RandomConcurrentPolicy
POLICY_RECORDINGS = [
    "policy/java_skill_teaching_random_concurrent.jsonl.gz",  # 3 rounds, no constraints
    "policy/java_tamarisk_random_concurrent.jsonl.gz",  # 2 rounds
    "policy/java_manufacturer_random_concurrent.jsonl.gz",  # 2 rounds, action preconditions
    "transcripts/java_traffic_ctm_enum.jsonl",  # max-nondef-actions 2, constraints
    "transcripts/java_mars_rover_simerror.jsonl",  # real-valued actions
]


def _records(path: Path) -> tuple[dict[str, object], list[tuple[str, bytes]]]:
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt", encoding="utf-8") as fh:  # type: ignore[operator]
        lines = [json.loads(line) for line in fh]
    records = [(o["dir"], o["data"].encode("latin-1")) for o in lines[1:] if "data" in o]
    return lines[0]["meta"], records


def _strip(data: bytes) -> bytes:
    return data[:-1] if data.endswith(b"\0") else data


@pytest.mark.parametrize("name", POLICY_RECORDINGS)
def test_replays_the_java_clients_choices_byte_for_byte(recordings: Path, name: str) -> None:
    """Every actions message the Java client sent, from the states it was
    sent (the k-th turn answered by the k-th actions message: the recorder
    may log a turn before the answer to the previous one)."""
    meta, records = _records(recordings / "rddlsim" / name)
    client_args = meta["client_args"]
    assert isinstance(client_args, list) and meta["policy"] == "rddl.policy.RandomConcurrentPolicy"
    seed, instance = int(client_args[5]), str(client_args[6])
    sent = [_strip(d) for direction, d in records if direction == "c2s" and b"<actions" in d]
    policy = codec = None
    turns = 0
    for direction, data in records:
        if direction != "s2c":
            continue
        msg = decode(_strip(data))
        if isinstance(msg, SessionInit):
            model = model_from_task(msg.task, instance)
            sim = Simulator(model)
            codec = WireCodec(sim)
            policy = RandomConcurrentPolicy(sim, seed)
        elif isinstance(msg, Turn):
            assert policy is not None and codec is not None and msg.fluents is not None
            typed = [
                (
                    f.name,
                    f.args,
                    parse_value(str(f.value), value_kind(model, model.pvariables[f.name])),
                )
                for f in msg.fluents
            ]
            chosen = policy.choose(codec.state_from(typed))
            mine = encode(Actions(tuple(Fluent(n, a, v) for n, a, v in chosen)))
            assert mine == sent[turns], (name, turns + 1)
            turns += 1
    assert turns == len(sent) and turns >= 2


def test_well19937c_matches_java() -> None:
    # the first draws of seed 0 give the mars rover recording's first two moves:
    # the coin 0.743... takes yMove, then u = 0.5918... -> 10u - 5 (Java's u*5 + (1-u)*-5)
    rng = RandomDataGenerator(0)
    assert rng.next_uniform(0.0, 1.0) == 0.7432416673360078
    assert rng.next_uniform(-5.0, 5.0) == 0.9181647320338637
    # Java int semantics: the rejection step, powers of two, inclusive bounds
    gen = Well19937c(123456789012)
    draws = [gen.next_int(6) for _ in range(1000)]
    assert set(draws) == set(range(6))
    assert all(0 <= RandomDataGenerator(5).next_int(0, 5) <= 5 for _ in range(10))
    with pytest.raises(ValueError, match="must be below"):
        RandomDataGenerator(0).next_int(0, 0)  # Java throws NumberIsTooLargeException
    perm = RandomDataGenerator(3).permute(10)
    assert sorted(perm) == list(range(10)) and perm != list(range(10))
    assert RandomDataGenerator(3).permute(10) == perm
    assert RandomDataGenerator(3).permute(1) == [0]


def test_skill_teaching_first_action_frequencies() -> None:
    """SkillTeaching #1 (max-nondef-actions 1, no constraints): rddlsim's
    order is giveHint, askProb (Java HashMap order), so each giveHint(s) is
    taken with probability 3/8, each askProb(s) 3/32, noop 1/16. The
    declaration order (askProb first) would swap the two."""
    model = load_pair(*ippc_files("IPPC2014", "SkillTeaching"))
    sim = Simulator(model)
    assert [p.name for p in rddlsim_action_order(model)] == ["giveHint", "askProb"]
    assert [p.name for p in sim.action_fluents] == ["askProb", "giveHint"]
    state = sim.initial_state(1)
    counts: dict[str, int] = {}
    n = 4000
    policy = RandomConcurrentPolicy(sim, 1)  # (no constraints: every turn is the first)
    for _ in range(n):
        chosen = policy.choose(state)
        key = ",".join(f"{a}({x[0]})" for a, x, _ in chosen) or "noop"
        counts[key] = counts.get(key, 0) + 1
    want = {
        "giveHint(s0)": 3 / 8,
        "giveHint(s1)": 3 / 8,
        "askProb(s0)": 3 / 32,
        "askProb(s1)": 3 / 32,
        "noop": 1 / 16,
    }
    assert set(counts) == set(want)
    chi2 = sum((counts[k] - n * p) ** 2 / (n * p) for k, p in want.items())
    assert chi2 < 18.5, (chi2, counts)  # 4 degrees of freedom: p < 0.001


def _session(model_pair: tuple[Path, Path], seed: int | None = None) -> SessionInfo:
    model = load_pair(*model_pair)
    return SessionInfo(model.name, model, Simulator(model), rounds=1, time_allowed=60.0, seed=seed)


def _observe(codec: WireCodec, state: object, turn: int) -> Observation:
    return Observation(
        fluents={(n, a): v for n, a, v in codec.state(state)},  # type: ignore[arg-type]
        state=state,  # type: ignore[arg-type]
        turn=turn,
        steps_left=10,
        time_left=60.0,
        immediate_reward=0.0,
        deadline=time.monotonic() + 1.0,
    )


def test_stops_where_rddlsim_stops_and_can_go_on() -> None:
    """ChromaticDice #1 starts in phase roll1, where only all five rolls at
    once are legal: rddlsim's policy tries them one by one, none passes,
    and noop is illegal: it gives up. With when_stuck=legal the planner
    sends the five rolls instead."""
    info = _session(ippc_files("IPPC2018", "ChromaticDice"))
    sim = info.simulator
    codec = WireCodec(sim)
    state = sim.initial_state(1)
    with pytest.raises(Stuck, match=STUCK_MESSAGE):
        RandomConcurrentPolicy(sim, 0).choose(state)
    planner = RandomPlanner(seed="0")
    planner.start_session(info)
    with pytest.raises(PlannerError, match="turn 1: No actions satisfied state constraints"):
        planner.act(_observe(codec, state, 1))
    going = RandomPlanner(seed="0", when_stuck="legal")
    going.start_session(info)
    acts = going.act(_observe(codec, state, 1))
    assert sorted((n, a) for n, a, _ in acts) == [("roll", (f"d{i}",)) for i in range(1, 6)]
    decoded = codec.actions_from(acts)
    assert codec.check(state, decoded) is None
    with pytest.raises(PlannerError, match="when_stuck"):
        RandomPlanner(when_stuck="maybe")


def test_default_seed_is_the_java_clients() -> None:
    info = _session(ippc_files("IPPC2011", "SysAdmin"))
    codec = WireCodec(info.simulator)
    state = info.simulator.initial_state(1)
    a = RandomPlanner()
    a.start_session(info)
    java = RandomConcurrentPolicy(info.simulator, 0)
    assert [a.act(_observe(codec, state, t)) for t in range(1, 30)] == [
        java.choose(state) for _ in range(1, 30)
    ]
