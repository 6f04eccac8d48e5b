"""The determinise-and-replan planner (`replan`) on tiny hand-written
domains (tests/planners/replan_domains/) where the best plan is known:
the determinisation, a deterministic chain followed without replanning, a
slippery chain that forces replans, legal actions under max-nondef-actions
and preconditions, goals (termination), deadlines, options, and whole
sessions through our client and server."""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
import trio
from ippc.client.session import ClientConfig, SessionResult, run_session
from ippc.planners import (
    Observation,
    Planner,
    PlannerError,
    SessionInfo,
    WireFluent,
    make_planner,
)
from ippc.planners.determinise import determinise, model_has_draws
from ippc.planners.replan import (
    ReplanPlanner,
    SearchProblem,
    joint_actions,
    same_state,
    search,
)
from ippc.rddl import Model, load
from ippc.rddl.simulator import SimulationError, Simulator, State
from ippc.rddl.wire import WireCodec

from ..client.loopback import DOMAINS, Watch, our_server, settled

HERE = Path(__file__).resolve().parent
TINY = HERE / "replan_domains"


@pytest.fixture(scope="module")
def models() -> dict[str, Model]:
    return load(TINY)


@dataclass
class Played:
    """One round played locally against the real simulator."""

    actions: list[list[WireFluent]] = field(default_factory=list)
    states: list[State] = field(default_factory=list)  # before each turn, then the last
    rewards: list[float] = field(default_factory=list)
    done: bool = False

    @property
    def total(self) -> float:
        return sum(self.rewards)


def start(planner: ReplanPlanner, model: Model, seed: int | None = 0) -> Simulator:
    sim = Simulator(model)
    planner.start_session(SessionInfo(model.name, model, sim, 1, 600.0, seed))
    return sim


def play(planner: ReplanPlanner, sim: Simulator, world_seed: int, seconds: float = 5.0) -> Played:
    """A round: the planner's actions, checked as the server checks them,
    stepped in the real (random) simulator."""
    codec = WireCodec(sim)
    rng = np.random.default_rng(world_seed)
    horizon = sim.model.horizon
    assert horizon is not None
    planner.start_round(1)
    state = sim.initial_state(1)
    out = Played(states=[state])
    for turn in range(1, horizon + 1):
        fluents = {(n, a): v for n, a, v in codec.state(state)}
        obs = Observation(
            fluents, state, turn, horizon - turn + 1, 600.0, 0.0, time.monotonic() + seconds
        )
        chosen = planner.act(obs)
        decoded = codec.actions_from(chosen)
        assert codec.check(state, decoded) is None, (turn, chosen)
        step = sim.step(state, decoded.arrays, rng)
        out.actions.append(chosen)
        out.rewards.append(float(step.reward[0]))
        state = step.next_state
        out.states.append(state)
        if bool(step.done[0]):
            out.done = True
            break
    planner.end_round(out.total)
    return out


def at(sim: Simulator, state: State) -> str:
    """Where the robot of the chain domains is."""
    cells = sim.model.objects("cell")
    (where,) = np.nonzero(state.values["at"][0])[0]
    return cells[int(where)]


FORWARD: list[WireFluent] = [("forward", (), True)]


# ------------------------------------------------------------ determinisation


def test_most_likely_determinisation(models: dict[str, Model]) -> None:
    model = models["draws_inst"]
    assert model_has_draws(model)
    det = determinise(model)
    assert not model_has_draws(det)
    assert det.cpfs.keys() == model.cpfs.keys()
    assert det.pvariables == model.pvariables and det.init_state == model.init_state
    sim = Simulator(det)
    state = sim.initial_state(2)
    first = sim.step(state, None, None)  # type: ignore[arg-type]  # no draw is left: no rng needed
    values = {k: v[0].item() for k, v in first.next_state.values.items()}
    levels = model.objects("level")
    slots = model.objects("slot")
    assert values["rare"] is False  # Bernoulli(1 - 0.6)
    assert values["even"] is True  # Bernoulli(0.5): a tie counts as true
    assert levels[values["lvl"]] == "@mid"  # 0.2 / 0.5 / 0.3
    assert levels[values["other"]] == "@high"  # 0.1 / 0.3 / otherwise (0.6)
    assert values["gauss"] == 5.0  # Normal(3 + count, 4) with count = 2: the mean
    assert values["flat"] == 2.5  # Uniform(1, 4): the mean
    assert values["count"] == 2  # Poisson(2.7): the mode
    assert values["trials"] == 3  # Binomial(10, 0.3): the mode
    assert slots[values["picked"]] == "s2"  # Discrete_ over WEIGHT: the heaviest
    assert first.reward.tolist() == [0.0, 0.0]  # reward = gauss (still 0.0 in the state)
    second = sim.step(first.next_state, None, None)  # type: ignore[arg-type]
    assert second.reward.tolist() == [5.0, 5.0]
    # the real model still draws: it cannot step without a generator
    real = Simulator(model)
    with pytest.raises(SimulationError, match="needs a numpy Generator"):
        real.step(real.initial_state(1), None, None)  # type: ignore[arg-type]


def test_terminate_when_becomes_a_termination(models: dict[str, Model]) -> None:
    import dataclasses

    from ippc.rddl import ast as A

    model = models["chain_inst"]
    goal = A.PVar("at", (A.ObjectLit("c1"),))
    inst = dataclasses.replace(model.instance, horizon=goal)
    det = determinise(dataclasses.replace(model, instance=inst, horizon=None))
    assert det.domain.termination[-1] == goal
    sim = Simulator(det)
    step = sim.step(sim.initial_state(1), {"forward": np.array([True])}, None)  # type: ignore[arg-type]
    assert step.done.tolist() == [True]


def test_joint_actions_respect_max_nondef(models: dict[str, Model]) -> None:
    one, truncated = joint_actions(Simulator(models["gate_one"]), 1000)
    assert not truncated
    # noop, then each of the 4 groundings (3 pulls, unlock) alone
    assert one["pull"].shape == (5, 3) and one["unlock"].shape == (5,)
    assert (one["pull"].sum(axis=1) + one["unlock"]).tolist() == [0, 1, 1, 1, 1]
    two, truncated = joint_actions(Simulator(models["gate_two"]), 1000)
    assert not truncated and two["unlock"].shape == (1 + 4 + 6,)
    assert max(two["pull"].sum(axis=1) + two["unlock"]) == 2
    cut, truncated = joint_actions(Simulator(models["gate_two"]), 5)
    assert truncated and cut["unlock"].shape == (5,)  # pairs left out as a whole


# ------------------------------------------------------------ planning


def test_deterministic_chain_followed_without_replanning(models: dict[str, Model]) -> None:
    planner = ReplanPlanner()
    sim = start(planner, models["chain_inst"])
    played = play(planner, sim, world_seed=0)
    # forward four times to the goal, then wait there (a move costs 1)
    assert played.actions == [FORWARD] * 4 + [[]] * 4
    assert played.total == -4 + 4 * 10
    assert [at(sim, s) for s in played.states] == ["c0", "c1", "c2", "c3"] + ["c4"] * 5
    assert planner.searches == 1 and planner.replans == 0 and planner.refinements == 0
    result = planner.last_search
    assert result is not None and result.complete and result.depth == 8
    assert result.value == pytest.approx(36.0)
    # a second round plans again from the start, still without surprises
    again = play(planner, sim, world_seed=1)
    assert again.actions == played.actions
    assert planner.searches == 2 and planner.replans == 0


def test_slips_force_replans_and_the_goal_is_still_reached(models: dict[str, Model]) -> None:
    planner = ReplanPlanner()
    sim = start(planner, models["slip_inst"])
    played = play(planner, sim, world_seed=3)  # a world where it slips at least twice
    cells = [at(sim, s) for s in played.states]
    # a slip: the planner moved forward and stayed where it was
    slips = [
        t
        for t, chosen in enumerate(played.actions)
        if chosen == FORWARD and cells[t + 1] == cells[t]
    ]
    assert len(slips) >= 2, "the seed no longer makes the robot slip: pick another"
    # each slip is a surprise the planner notices: one replan each, and a
    # search each time (the first search is the round's start)
    assert planner.replans == len(slips)
    assert planner.searches == 1 + len(slips)
    # it keeps going forward until it is there, then stays at the goal
    goal_turn = cells.index("c4")
    assert all(chosen == FORWARD for chosen in played.actions[:goal_turn])
    assert all(chosen == [] for chosen in played.actions[goal_turn:])
    assert cells[-1] == "c4" and goal_turn == 4 + len(slips)
    assert played.total == 10 * (len(cells) - 1 - goal_turn) - goal_turn


def test_all_outcomes_reaches_the_goal_too(models: dict[str, Model]) -> None:
    planner = ReplanPlanner(determinisation="all-outcomes", outcomes="3", seed="5")
    assert planner.outcomes == 3
    sim = start(planner, models["slip_inst"])
    played = play(planner, sim, world_seed=3)
    cells = [at(sim, s) for s in played.states]
    assert cells[-1] == "c4"
    slips = sum(
        1 for t, a in enumerate(played.actions) if a == FORWARD and cells[t + 1] == cells[t]
    )
    # it expects the lucky outcome (the move works), so a slip surprises it as well
    assert planner.replans == slips >= 1


def test_goal_domain_ends_at_the_goal(models: dict[str, Model]) -> None:
    planner = ReplanPlanner()
    sim = start(planner, models["goal_inst"])
    played = play(planner, sim, world_seed=3)
    cells = [at(sim, s) for s in played.states]
    assert played.done and cells[-1] == "c4"  # the episode ended at the goal
    assert all(chosen == FORWARD for chosen in played.actions)  # never waits, never back
    assert played.total == -len(played.actions)
    assert planner.replans >= 1 and planner.searches == 1 + planner.replans


@pytest.mark.parametrize(
    "instance,plan,total",
    [
        # one action per step: unlock (worth nothing) first, then the locked lever
        ("gate_one", [[("unlock", (), True)]] + [[("pull", ("c",), True)]] * 4, 400.0),
        # two per step: the second best lever beside each
        (
            "gate_two",
            [[("pull", ("b",), True), ("unlock", (), True)]]
            + [[("pull", ("b",), True), ("pull", ("c",), True)]] * 4,
            5.0 + 4 * 105.0,
        ),
    ],
)
def test_max_nondef_actions_and_preconditions(
    models: dict[str, Model], instance: str, plan: list[list[WireFluent]], total: float
) -> None:
    planner = ReplanPlanner()
    sim = start(planner, models[instance])
    played = play(planner, sim, world_seed=0)  # play() checks every action as the server does
    assert played.actions == plan
    assert played.total == total
    assert planner.replans == 0
    # without the precondition the planner would have pulled c at once: it
    # is illegal while locked, and the simulator says so
    locked = sim.initial_state(1)
    pull_c = WireCodec(sim).actions_from([("pull", ("c",), True)])
    assert not sim.check_actions(locked, pull_c.arrays)[0]


@pytest.mark.parametrize("depth", [1, 4, 8])
def test_complete_search_is_optimal_on_game_of_life(rddlsim_rddl: Path, depth: int) -> None:
    """A search that runs out of nodes has found the best plan: its value
    equals value iteration over all 512 states of the determinised 3x3
    Game of Life (one cell set per step)."""
    model = load(rddlsim_rddl)["game_of_life_inst_mdp__1"]
    world = Simulator(model)
    det = Simulator(determinise(model))
    candidates, truncated = joint_actions(world, 1000)
    k = candidates["set"].shape[0]
    assert not truncated and k == 10  # noop and the 9 cells
    grids = np.array(list(itertools.product([False, True], repeat=9)))
    n = len(grids)
    out = det.step(
        State({"alive": np.repeat(grids, k, axis=0).reshape(-1, 3, 3)}),
        {"set": np.tile(candidates["set"], (n, 1, 1))},
        None,  # type: ignore[arg-type]
        check=False,
    )
    code = 1 << np.arange(8, -1, -1)
    successor = out.next_state.values["alive"].reshape(n, k, 9).astype(np.int64) @ code
    reward = out.reward.reshape(n, k)
    value = np.zeros(n)
    for _ in range(depth):
        value = (reward + value[successor]).max(axis=1)
    problem = SearchProblem(det, world, candidates, truncated, 1.0, np.random.default_rng(0))
    for grid in (grids[0b010100001], grids[0b101110000], world.initial_state(1).values["alive"]):
        root = State({"alive": np.asarray(grid, dtype=bool).reshape(1, 3, 3)})
        result = search(problem, root, depth, time.monotonic() + 30.0)
        assert result.complete
        assert result.value == value[int(np.asarray(grid).reshape(-1).astype(np.int64) @ code)]
        # the plan's own predicted rewards add up to its value
        assert len(result.steps) == depth
        assert sum(step.reward for step in result.steps) == result.value


def test_deadline_is_respected_and_the_best_plan_so_far_returned(
    models: dict[str, Model],
) -> None:
    planner = ReplanPlanner()
    sim = start(planner, models["gate_long"])  # 60 steps, up to 3 actions each: a huge tree
    codec = WireCodec(sim)
    state = sim.initial_state(1)
    t0 = time.monotonic()
    obs = Observation(None, state, 1, 60, 600.0, 0.0, t0 + 0.2)
    chosen = planner.act(obs)
    took = time.monotonic() - t0
    assert took < 2.0, took  # deadline 0.2 s; room for a busy machine
    result = planner.last_search
    assert result is not None and not result.complete and result.expansions > 0
    assert codec.check(state, codec.actions_from(chosen)) is None
    # the best plan found so far already beats pulling b and a every step
    assert result.value > 60 * 6.0
    assert ("unlock", (), True) in chosen
    # refining: the plan holds, the last search was cut short: search again
    state = sim.step(state, codec.actions_from(chosen).arrays, np.random.default_rng(0)).next_state
    obs = Observation(None, state, 2, 59, 600.0, 0.0, time.monotonic() + 0.1)
    planner.act(obs)
    assert planner.refinements == 1 and planner.replans == 0 and planner.searches == 2
    assert planner.planning_seconds < 3.0
    # time_per_step caps the search below the turn's deadline
    capped = ReplanPlanner(time_per_step="0.05")
    start(capped, models["gate_long"])
    t0 = time.monotonic()
    capped.act(Observation(None, sim.initial_state(1), 1, 60, 600.0, 0.0, t0 + 30.0))
    assert time.monotonic() - t0 < 2.0  # not the 30 s deadline


def test_same_state_compares_reals_loosely() -> None:
    a = State({"x": np.array([[1.0, 2.0]]), "b": np.array([[True]])})
    b = State({"x": np.array([[1.0, 2.0 + 1e-9]]), "b": np.array([[True]])})
    c = State({"x": np.array([[1.0, 2.1]]), "b": np.array([[True]])})
    d = State({"x": np.array([[1.0, 2.0]]), "b": np.array([[False]])})
    assert same_state(a, b) and not same_state(a, c) and not same_state(a, d)


def test_options() -> None:
    planner = make_planner("replan", {"max-depth": "3", "time_per_step": "0.5", "seed": "4"})
    assert isinstance(planner, ReplanPlanner)
    assert (planner.max_depth, planner.time_per_step, planner.seed) == (3, 0.5, 4)
    assert planner.determinisation == "most-likely" and planner.outcomes == 0
    assert set(ReplanPlanner.options) == {
        "determinisation",
        "time_per_step",
        "max_depth",
        "expand",
        "outcomes",
        "max_actions",
        "refine",
        "seed",
        "startup",
        "memory",
    }
    with pytest.raises(PlannerError, match="determinisation.*most-likely or all-outcomes"):
        ReplanPlanner(determinisation="sometimes")
    with pytest.raises(PlannerError, match="has no option 'depth'"):
        ReplanPlanner(depth="3")
    with pytest.raises(PlannerError, match="max_depth.*>= 1"):
        ReplanPlanner(max_depth="0")
    with pytest.raises(PlannerError, match="before start_session"):
        ReplanPlanner().act(Observation(None, None, 1, 1, 1.0, 0.0, time.monotonic() + 1))


def test_max_depth_bounds_the_plan(models: dict[str, Model]) -> None:
    planner = ReplanPlanner(max_depth="2")
    sim = start(planner, models["chain_inst"])
    played = play(planner, sim, world_seed=0)
    # two steps ahead the goal is out of sight and a move only costs: the
    # best plan within the depth is to wait
    assert planner.last_search is not None and planner.last_search.depth == 2
    assert played.actions == [[]] * 8
    assert planner.replans == 0 and planner.searches == 4  # a new plan every two steps


# ------------------------------------------------------------ sessions


async def _session(
    paths: list[Path], name: str, planner_name: str, options: dict[str, str], rounds: int
) -> tuple[SessionResult, Planner, Watch]:
    """One whole session of `planner_name` against our server, over loopback."""
    async with our_server(*paths, rounds=rounds) as (port, _, store):
        inner = make_planner(planner_name, options)
        assert isinstance(inner, Planner)
        watch = Watch(inner)
        config = ClientConfig(
            port=port, instance=name, client_name=planner_name, timeout=30.0, seed=1
        )
        with trio.fail_after(60):
            result = await run_session(config, watch, planner_name)
        row = await settled(store, result.session_id)
        assert row["status"] == "finished" and row["total_reward"] == result.total_reward
        return result, inner, watch


@pytest.mark.trio
async def test_session_on_the_chain() -> None:
    result, planner, watch = await _session(
        [TINY / "chain.rddl"], "chain_inst", "replan", {"time_per_step": "0.2"}, rounds=2
    )
    assert isinstance(planner, ReplanPlanner)
    assert [r.reward for r in result.rounds] == [36.0, 36.0]
    assert [chosen for _, chosen in watch.turns] == ([FORWARD] * 4 + [[]] * 4) * 2
    assert planner.searches == 2 and planner.replans == 0


@pytest.mark.trio
async def test_session_on_print_jobs_beats_noop() -> None:
    paths = [DOMAINS / "print_jobs" / "domain.rddl", DOMAINS / "print_jobs" / "instance1.rddl"]
    noop, _, _ = await _session(paths, "print_jobs_inst_1", "noop", {}, rounds=2)
    replan, planner, watch = await _session(
        paths, "print_jobs_inst_1", "replan", {"time_per_step": "0.25"}, rounds=2
    )
    assert isinstance(planner, ReplanPlanner)
    assert len(watch.turns) == 40  # two whole rounds of 20 turns
    # noop never delivers: both documents pending for 20 steps each round
    assert noop.mean_round_reward == -20.0
    # replan fetches and delivers (+10 each) and ends far above noop
    assert replan.mean_round_reward > 0.0
    delivered = [a for _, chosen in watch.turns for a in chosen if a[0] == "deliver"]
    assert len(delivered) >= 2
    assert planner.searches >= 2


@pytest.mark.trio
async def test_session_on_a_pomdp_plays_open_loop() -> None:
    folder = DOMAINS / "print_jobs_pomdp"
    paths = [folder / "domain.rddl", folder / "instance1.rddl"]
    result, planner, watch = await _session(
        paths, "print_jobs_pomdp_inst_1", "replan", {"time_per_step": "0.2"}, rounds=1
    )
    assert isinstance(planner, ReplanPlanner)
    # the state is never shown, so nothing can surprise the planner: it
    # follows the plan it made from the initial state, all 20 turns
    assert all(obs.state is None for obs, _ in watch.turns)
    assert len(watch.turns) == 20 and result.rounds[0].ended_early is None
    # (a search cut short by a busy machine is refined later: counted apart)
    assert planner.replans == 0 and planner.searches == 1 + planner.refinements
    assert any(a[0] == "deliver" for _, chosen in watch.turns for a in chosen)
    assert result.total_reward > -20.0  # noop's reward there
