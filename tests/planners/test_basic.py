"""NoopPlanner and RandomPlanner on bundled and recorded models: random
actions are legal (as the server checks them), vary, and are reproducible."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import pytest
from ippc.planners import (
    NoopPlanner,
    Observation,
    PlannerError,
    RandomPlanner,
    SessionInfo,
    WireFluent,
)
from ippc.rddl import Model, load
from ippc.rddl.simulator import Simulator, State
from ippc.rddl.wire import WireCodec

REPO = Path(__file__).resolve().parents[2]

# (model, whether stepping the simulator with random actions works: the
# mars rover's random negative moves give a negative Normal variance, and
# sidewalk's state-action constraints are really state invariants that its
# own random walks break, after which not even noop is legal)
MDPS = [
    ("print_jobs_inst_1", True),
    ("print_jobs_inst_2", True),
    ("print_jobs_inst_3", True),  # no max-nondef-actions, preconditions only
    ("corridor_enum_inst_1", True),  # enum-valued actions
    ("sysadmin_inst_mdp__1", True),  # max-nondef-actions = 1, no preconditions
    ("elevators_inst_mdp__1", True),  # state-action constraints
    ("game_of_life_inst_mdp__1", True),
    ("crossing_traffic_inst_mdp__1", True),
    ("inst_traffic_binary_ctm", True),  # max-nondef-actions = 2 and constraints
    ("is4", False),  # sidewalk: enum actions, max-nondef-actions = 4
    ("inst_simple_mars_rover", False),  # real-valued actions
]
POMDPS = ["sysadmin_inst_pomdp__1", "print_jobs_pomdp_inst_1"]


@pytest.fixture(scope="module")
def models(rddlsim_rddl: Path) -> dict[str, Model]:
    return {**load(rddlsim_rddl), **load(REPO / "domains")}


def session(model: Model, seed: int | None = None) -> SessionInfo:
    return SessionInfo(model.name, model, Simulator(model), rounds=1, time_allowed=60.0, seed=seed)


def observe(codec: WireCodec, state: State | None, turn: int, horizon: int = 40) -> Observation:
    fluents = None if state is None else {(n, a): v for n, a, v in codec.state(state)}
    return Observation(
        fluents=fluents,
        state=state,
        turn=turn,
        steps_left=horizon - turn + 1,
        time_left=60.0,
        immediate_reward=0.0,
        deadline=time.monotonic() + 1.0,
    )


def play(
    planner: RandomPlanner, info: SessionInfo, steps: int, step_sim: bool = True
) -> list[list[WireFluent]]:
    """Run the planner for `steps` turns; every answer must be legal where
    it is played (as the server checks it: WireCodec.actions_from + check)."""
    sim = info.simulator
    codec = WireCodec(sim)
    planner.start_session(info)
    planner.start_round(1)
    rng = np.random.default_rng(123)
    state = sim.initial_state(1)
    played = []
    for turn in range(1, steps + 1):
        acts = planner.act(observe(codec, state, turn))
        decoded = codec.actions_from(acts)
        assert decoded.ignored == () and decoded.illegal == ()
        assert codec.check(state, decoded) is None, (info.instance, turn, acts)
        played.append(acts)
        if step_sim:
            state = sim.step(state, decoded.arrays, rng).next_state
    planner.end_round(0.0)
    planner.end_session(0.0)
    return played


def test_noop(models: dict[str, Model]) -> None:
    info = session(models["print_jobs_inst_1"])
    planner = NoopPlanner()
    planner.start_session(info)
    assert planner.session is info
    assert planner.act(observe(WireCodec(info.simulator), info.simulator.initial_state(1), 1)) == []
    assert planner.act(observe(WireCodec(info.simulator), None, 1)) == []
    with pytest.raises(
        PlannerError, match=r"planner 'noop' has no option 'seed' \(valid options: none\)"
    ):
        NoopPlanner(seed="1")


@pytest.mark.parametrize("name,step_sim", MDPS)
def test_random_is_legal_and_varies(models: dict[str, Model], name: str, step_sim: bool) -> None:
    model = models[name]
    played = play(RandomPlanner(seed="5"), session(model), 25, step_sim)
    distinct = {tuple(sorted(map(repr, a))) for a in played}
    assert len(distinct) >= 3, distinct
    if model.max_nondef_actions is not None:
        assert max(len(a) for a in played) <= model.max_nondef_actions
    assert any(a for a in played)  # not just noop
    # typed wire values, as the protocol writes them
    for acts in played:
        for fname, args, value in acts:
            p = model.pvariables[fname]
            assert isinstance(args, tuple) and all(isinstance(x, str) for x in args)
            if p.range == "bool":
                assert value is True  # only non-defaults are sent; defaults are false
            elif p.range == "real":
                assert type(value) is float
            elif p.range == "int":
                assert type(value) is int
            else:
                assert isinstance(value, str) and value.startswith("@")


def test_random_is_reproducible(models: dict[str, Model]) -> None:
    model = models["game_of_life_inst_mdp__1"]  # 9 cells: many choices
    a = play(RandomPlanner(seed="7"), session(model), 20)
    b = play(RandomPlanner(seed="7"), session(model), 20)
    c = play(RandomPlanner(seed="8"), session(model), 20)
    assert a == b
    assert a != c
    # without the option, the session's seed is used; the option wins over it
    assert play(RandomPlanner(), session(model, seed=7), 20) == a
    assert play(RandomPlanner(seed="7"), session(model, seed=8), 20) == a
    # one generator per session: a new session starts the sequence again
    planner = RandomPlanner(seed="7")
    assert play(planner, session(model), 20) == a
    assert play(planner, session(model), 20) == a


@pytest.mark.parametrize("name", POMDPS)
def test_random_pomdp_uses_the_initial_state(models: dict[str, Model], name: str) -> None:
    """No state in POMDP observations: the actions are chosen legal for the
    instance's initial state (the Java client's state never leaves it); in
    these domains the constraints do not depend on the state, so they are
    legal in the real state too. A turn without observations (the first)
    gets no actions, as from the Java client."""
    model = models[name]
    info = session(model, seed=3)
    sim, codec = info.simulator, WireCodec(info.simulator)
    planner = RandomPlanner()
    planner.start_session(info)
    initial = sim.initial_state(1)
    state = sim.initial_state(1)
    rng = np.random.default_rng(0)
    played = []
    assert planner.act(observe(codec, None, 1)) == []
    for turn in range(2, 22):
        obs = dataclasses.replace(observe(codec, None, turn), fluents={})
        acts = planner.act(obs)
        decoded = codec.actions_from(acts)
        assert codec.check(initial, decoded) is None
        state = sim.step(state, decoded.arrays, rng).next_state  # check=True: raises if illegal
        played.append(acts)
    assert len({tuple(map(repr, a)) for a in played}) >= 3


def test_random_options_and_misuse(models: dict[str, Model]) -> None:
    with pytest.raises(
        PlannerError, match="planner 'random': option 'seed' must be an integer, got 'x1'"
    ):
        RandomPlanner(seed="x1")
    with pytest.raises(
        PlannerError,
        match=r"planner 'random' has no option 'sed' \(valid options: seed, when_stuck\)",
    ):
        RandomPlanner(sed="1")
    assert RandomPlanner(seed=" 42 ").seed == 42
    with pytest.raises(PlannerError, match="before start_session"):
        RandomPlanner().act(observe(WireCodec(Simulator(models["sysadmin_inst_mdp__1"])), None, 1))
