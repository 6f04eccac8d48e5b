"""Our client against our server over loopback: whole sessions (2 rounds)
for every bundled instance and a sample of rddlrepository instances (MDP
and POMDP), with the noop and random planners, in both framings. The
client's results are checked against the server's result store, turn by
turn: the fluents the planner was shown are the state (or observation)
the server stored, and the actions it chose are the actions the server
received."""

from __future__ import annotations

from pathlib import Path

import pytest
import trio
from ippc.client.session import ClientConfig, ClientError, SessionResult, run_session
from ippc.planners import make_planner
from ippc.planners.base import Planner
from ippc.protocol import format_value
from ippc.server.store import ResultStore

from ..conftest import corpus_pairs, corpus_root
from .loopback import DOMAINS, Watch, our_server, settled

pytestmark = pytest.mark.trio

BUNDLED = [
    ("print_jobs", "instance1.rddl"),
    ("print_jobs", "instance2.rddl"),
    ("print_jobs", "instance3.rddl"),
    ("print_jobs_pomdp", "instance1.rddl"),
    ("corridor_enum", "instance1.rddl"),
]

# A sample of rddlrepository: bool/int/real/enum fluents, constraints,
# concurrency, and three POMDPs.
CORPUS_SAMPLE = [
    "archive/competitions/IPPC2011/SysAdmin/MDP/instance1.rddl",
    "archive/competitions/IPPC2011/Elevators/POMDP/instance1.rddl",
    "archive/competitions/IPPC2011/Navigation/POMDP/instance1.rddl",
    "archive/competitions/IPPC2011/Traffic/MDP/instance1.rddl",
    "archive/competitions/IPPC2014/AcademicAdvising/MDP/instance1.rddl",
    "archive/competitions/IPPC2014/TriangleTireworld/POMDP/instance1.rddl",
    "archive/competitions/IPPC2018/Manufacturer/instance1.rddl",
    "archive/competitions/IPPC2023/Reservoir/instance1.rddl",
    "archive/competitions/IPPC2023/MarsRover/instance1.rddl",
]

VARIANTS = [("noop", False), ("noop", True), ("random", False), ("random", True)]


def corpus_pair(rel: str) -> tuple[Path, Path]:
    root = corpus_root()
    inst = root / rel
    pair = (inst.parent / "domain.rddl", inst)
    assert pair in corpus_pairs(), rel
    return pair


async def check_against_store(
    result: SessionResult,
    watch: Watch,
    store: ResultStore,
    *,
    no_header: bool,
    horizon: int,
    pomdp: bool,
) -> None:
    """One session's client result, turn by turn, against the server's store."""
    assert [r.round for r in result.rounds] == [1, 2]
    assert not any(r.training for r in result.rounds)
    assert result.total_reward == result.rounds[0].reward + result.rounds[1].reward
    assert result.mean_round_reward == pytest.approx(result.total_reward / 2)
    row = await settled(store, result.session_id)
    assert row["status"] == "finished"
    assert row["client_name"] == result.client_name
    assert row["no_header"] is no_header
    assert row["total_reward"] == result.total_reward
    assert row["rounds_used"] == 2
    stored_rounds = store.rounds(row["id"])
    assert [
        (r["round_num"], r["reward"], r["turns_used"], r["counted"]) for r in stored_rounds
    ] == [(r.round, r.reward, r.turns, True) for r in result.rounds]
    turns = iter(watch.turns)
    for rnd, stored in zip(result.rounds, stored_rounds, strict=True):
        # every round runs to the horizon unless the instance reached a terminal state
        assert stored["status"] in ("finished", "terminal")
        assert (rnd.turns == horizon) == (stored["status"] == "finished")
        assert (rnd.ended_early is None) == (rnd.turns == horizon)
        steps = store.steps(stored["id"])
        assert [s["turn_num"] for s in steps] == list(range(1, rnd.turns + 1))
        for step in steps:
            obs, chosen = next(turns)
            assert obs.turn == step["turn_num"]
            assert obs.steps_left == horizon - obs.turn + 1
            shown = obs.fluents if obs.fluents is not None else {}
            assert shown == {(n, tuple(a)): v for n, a, v in step["state"]}
            if pomdp:
                assert obs.state is None
                assert (obs.fluents is None) == (obs.turn == 1)
            else:
                assert obs.state is not None and obs.fluents
            assert step["actions"] == [(n, tuple(a), format_value(v)) for n, a, v in chosen]
    assert next(turns, None) is None


async def play_variants(
    port: int, name: str, horizon: int, pomdp: bool, store: ResultStore
) -> list[SessionResult]:
    results = []
    for planner_name, no_header in VARIANTS:
        options = {"seed": "7"} if planner_name == "random" else {}
        inner = make_planner(planner_name, options)
        assert isinstance(inner, Planner)
        watch = Watch(inner)
        config = ClientConfig(
            port=port,
            instance=name,
            client_name=f"{planner_name}-{int(no_header)}",
            no_header=no_header,
            timeout=30.0,
        )
        with trio.fail_after(60):
            result = await run_session(config, watch, planner_name)
        assert result.instance == name and result.planner == planner_name
        assert result.client_name == config.client_name
        assert watch.info is not None and watch.info.rounds == 2 and watch.info.model.name == name
        await check_against_store(
            result, watch, store, no_header=no_header, horizon=horizon, pomdp=pomdp
        )
        results.append(result)
    # every session is a new server session
    ids = [r.session_id for r in results]
    assert ids == sorted(set(ids)) and len(ids) == len(VARIANTS)
    return results


async def run_pair(domain: Path, instance: Path) -> list[SessionResult]:
    async with our_server(domain, instance, rounds=2) as (port, registry, store):
        assert len(registry) == 1
        inst = registry.instances[registry.names()[0]]
        assert inst.horizon is not None
        _, codec = inst.compiled_now()
        return await play_variants(port, inst.name, inst.horizon, codec.pomdp, store)


@pytest.mark.parametrize("folder,instance", BUNDLED, ids=[f"{d}/{i}" for d, i in BUNDLED])
async def test_bundled_instance_sessions(folder: str, instance: str) -> None:
    results = await run_pair(DOMAINS / folder / "domain.rddl", DOMAINS / folder / instance)
    # noop is deterministic where the domain is: the two framings agree
    if folder.startswith("print_jobs"):
        assert results[0].total_reward == results[1].total_reward


@pytest.mark.parametrize("rel", CORPUS_SAMPLE)
async def test_corpus_instance_sessions(rel: str) -> None:
    await run_pair(*corpus_pair(rel))


async def test_bundled_pomdp_is_a_pomdp() -> None:
    """The POMDP variants above really play POMDPs (turn 1 without fluents)."""
    async with our_server(DOMAINS / "print_jobs_pomdp", rounds=1) as (port, registry, _):
        watch = Watch(make_planner("noop", {}))  # type: ignore[arg-type]
        with trio.fail_after(30):
            await run_session(
                ClientConfig(port=port, instance=registry.names()[0], timeout=10), watch
            )
    assert watch.turns[0][0].fluents is None and watch.turns[0][0].state is None
    assert watch.turns[1][0].fluents


async def test_local_rddl_instead_of_the_task() -> None:
    """`rddl`: the model comes from local files (as rddlsim's Java client
    does); the session is the same."""
    folder = DOMAINS / "corridor_enum"
    async with our_server(folder, rounds=2) as (port, registry, store):
        name = registry.names()[0]
        base = ClientConfig(port=port, instance=name, timeout=10)
        with trio.fail_after(30):
            from_task = await run_session(base, make_planner("noop", {}))  # type: ignore[arg-type]
            watch = Watch(make_planner("noop", {}))  # type: ignore[arg-type]
            local = await run_session(
                ClientConfig(
                    port=port,
                    instance=name,
                    timeout=10,
                    rddl=(folder / "domain.rddl", folder / "instance1.rddl"),
                ),
                watch,
            )
            assert watch.info is not None and watch.info.model.domain_file == str(
                folder / "domain.rddl"
            )
            assert [(r.reward, r.turns) for r in local.rounds] == [
                (r.reward, r.turns) for r in from_task.rounds
            ]
            # files that do not hold the instance: a clear error, not a crash
            with pytest.raises(ClientError, match=r"^--rddl: .*no instance 'corridor_enum_inst_1'"):
                await run_session(
                    ClientConfig(
                        port=port, instance=name, timeout=10, rddl=(DOMAINS / "print_jobs",)
                    ),
                    make_planner("noop", {}),  # type: ignore[arg-type]
                )
        for session in (from_task, local):
            assert (await settled(store, session.session_id))["status"] == "finished"


async def test_unknown_instance_on_our_server() -> None:
    async with our_server(DOMAINS / "corridor_enum", rounds=1) as (port, _, _):
        with (
            trio.fail_after(10),
            pytest.raises(
                ClientError, match="closed the connection while we waited for session-init"
            ),
        ):
            await run_session(
                ClientConfig(port=port, instance="no_such_instance", timeout=5),
                make_planner("noop", {}),
            )  # type: ignore[arg-type]


async def test_closed_port() -> None:
    with trio.socket.socket() as s:
        await s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # bound, not listening
        with (
            trio.fail_after(10),
            pytest.raises(ClientError, match=rf"^cannot connect to 127\.0\.0\.1:{port}: "),
        ):
            await run_session(
                ClientConfig(port=port, instance="x", timeout=5), make_planner("noop", {})
            )  # type: ignore[arg-type]
