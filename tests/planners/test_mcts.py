"""MCTSPlanner on tiny hand-written domains whose best action is known
(tests/planners/tiny_domains), on the bundled domains (enum actions, a
POMDP), and in a loopback session through our server and client."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
import trio
from ippc.client.session import ClientConfig, run_session
from ippc.planners import (
    Observation,
    PlannerError,
    SessionInfo,
    WireFluent,
    find_planner,
    make_planner,
)
from ippc.planners.mcts import MCTSPlanner, _horizon_factor, enumerate_boolean
from ippc.rddl import Model, load
from ippc.rddl.simulator import Simulator, State
from ippc.rddl.wire import WireCodec

REPO = Path(__file__).resolve().parents[2]
TINY = Path(__file__).resolve().parent / "tiny_domains"

# Small searches: a few waves of a small batch, so every test takes well
# under a second.
FAST = {"iterations": "30", "batch": "64", "seed": "1"}


@pytest.fixture(scope="module")
def models() -> dict[str, Model]:
    return {**load(TINY), **load(REPO / "domains")}


@pytest.fixture(scope="module")
def sims(models: dict[str, Model]) -> dict[str, Simulator]:
    return {name: Simulator(m) for name, m in models.items()}


def planner_for(
    sims: dict[str, Simulator], instance: str, session_seed: int | None = None, **options: str
) -> MCTSPlanner:
    # (these tests read the wave search's tree: test_mcts_thts.py has thts's)
    planner = MCTSPlanner(**{"engine": "wave", **options})
    sim = sims[instance]
    planner.start_session(
        SessionInfo(instance, sim.model, sim, rounds=1, time_allowed=60.0, seed=session_seed)
    )
    planner.start_round(1)
    return planner


def observe(
    sim: Simulator,
    state: State | None,
    turn: int,
    steps_left: int | None = None,
    fluents: bool = True,
) -> Observation:
    horizon = sim.model.horizon or 1
    typed = None
    if state is not None and fluents:
        typed = {(n, a): v for n, a, v in WireCodec(sim).state(state)}
    return Observation(
        fluents=typed,
        state=state,
        turn=turn,
        steps_left=steps_left if steps_left is not None else horizon - turn + 1,
        time_left=60.0,
        immediate_reward=0.0,
        deadline=time.monotonic() + 10.0,
    )


def state_with(sim: Simulator, **values: object) -> State:
    state = sim.initial_state(1)
    for name, value in values.items():
        state.values[name][0] = value
    return state


def chosen(actions: list[WireFluent]) -> set[tuple[str, tuple[str, ...]]]:
    assert all(value is True for _, _, value in actions), actions
    return {(name, args) for name, args, _ in actions}


# ------------------------------------------------------------ best actions


def test_bandit_pulls_the_best_arm(sims: dict[str, Simulator]) -> None:
    sim = sims["tiny_bandit_inst"]
    planner = planner_for(sims, "tiny_bandit_inst", **FAST)
    actions = planner.act(observe(sim, sim.initial_state(1), 1))
    assert chosen(actions) == {("pull", ("a3",))}
    # every arm and noop were candidates; a3's estimate is near 5 * 0.8 = 4
    root = planner._root
    assert root is not None and len(root.acts) == 5
    q = root.q()
    assert abs(float(q.max()) - 4.0) < 1.0


@pytest.mark.parametrize(
    "steps_left,expected", [(10, "safe"), (5, "safe"), (2, "safe"), (1, "risky")]
)
def test_trap_is_avoided_while_it_matters(
    sims: dict[str, Simulator], steps_left: int, expected: str
) -> None:
    """`risky` has the better most likely outcome; only its 10% chance of
    the absorbing trap makes `safe` better, except in the last step."""
    sim = sims["tiny_trap_inst"]
    planner = planner_for(sims, "tiny_trap_inst", **{**FAST, "iterations": "60"})
    actions = planner.act(observe(sim, sim.initial_state(1), 11 - steps_left, steps_left))
    assert chosen(actions) == {(expected, ())}


@pytest.mark.parametrize("rollout_depth", ["10", "2"])
def test_trap_already_dead_knows_the_cost(sims: dict[str, Simulator], rollout_depth: str) -> None:
    """4 steps of -20, whatever is done; a rollout cut at 2 steps counts its
    mean reward for all 4."""
    sim = sims["tiny_trap_inst"]
    planner = planner_for(sims, "tiny_trap_inst", rollout_depth=rollout_depth, **FAST)
    planner.act(observe(sim, state_with(sim, dead=True), 7, 4))
    root = planner._root
    assert root is not None
    assert np.allclose(root.q(), -80.0)


def test_rollouts_cut_short_without_extrapolation(sims: dict[str, Simulator]) -> None:
    sim = sims["tiny_trap_inst"]
    planner = planner_for(sims, "tiny_trap_inst", rollout_depth="2", extrapolate="no", **FAST)
    planner.act(observe(sim, state_with(sim, dead=True), 7, 4))
    root = planner._root
    assert root is not None
    assert root.h == [-40.0] * 3  # two steps seen, two missing
    assert (root.q() > -80.0).all()


def test_horizon_factor() -> None:
    assert _horizon_factor(np.array([30, 10]), np.array([10, 10]), 1.0).tolist() == [3.0, 1.0]
    factor = _horizon_factor(np.array([3]), np.array([1]), 0.5)
    assert factor.tolist() == pytest.approx([(1 + 0.5 + 0.25) / 1.0])


@pytest.mark.parametrize("share", [True, False])
def test_transpositions(sims: dict[str, Simulator], share: bool) -> None:
    """In `pairs` every joint action leads to the same successor: one shared
    node with transpositions, one per action without."""
    sim = sims["tiny_pairs_inst"]
    planner = planner_for(sims, "tiny_pairs_inst", transpositions="yes" if share else "no", **FAST)
    planner.act(observe(sim, sim.initial_state(1), 1))
    root = planner._root
    assert root is not None
    successors = {id(o.node) for ch in root.children for o in ch.values()}
    assert len(successors) == (1 if share else 10)
    assert chosen(planner.act(observe(sim, sim.initial_state(1), 1))) == {
        ("flip", ("s2",)),
        ("flip", ("s3",)),
    }


def test_bellman_backup_reads_the_outcomes_current_values(sims: dict[str, Simulator]) -> None:
    """In `pairs` all joint actions share one successor node, whose value
    changes as the search goes on. With the partial Bellman backup every
    action of the root is worth its rollout estimate averaged with (reward +
    the successor's value as it is now), not as it was when that action
    was last tried."""
    sim = sims["tiny_pairs_inst"]
    planner = planner_for(sims, "tiny_pairs_inst", **FAST)
    planner.act(observe(sim, sim.initial_state(1), 1))
    root = planner._root
    assert root is not None
    (child,) = {o.node for ch in root.children for o in ch.values()}
    for a, outcomes in enumerate(root.children):
        (o,) = outcomes.values()
        expected = (root.h[a] + o.rsum + o.count * child.value) / (1.0 + root.cnt[a])
        assert root.qv[a] == pytest.approx(expected, rel=1e-12, abs=1e-12)
    assert root.value == max(root.qv)


def test_trial_depth_bounds_the_descent(sims: dict[str, Simulator]) -> None:
    """With trial_depth 1 every trial stops after one level, so (with one
    successor per action) the tree never grows below the root's child."""
    sim = sims["tiny_pairs_inst"]
    planner = planner_for(sims, "tiny_pairs_inst", trial_depth="1", **FAST)
    planner.act(observe(sim, sim.initial_state(1), 1))
    root = planner._root
    assert root is not None
    (child,) = {o.node for ch in root.children for o in ch.values()}
    assert child.expanded and all(not ch for ch in child.children)


def test_concurrent_actions_under_max_nondef_and_a_constraint(sims: dict[str, Simulator]) -> None:
    sim = sims["tiny_pairs_inst"]
    planner = planner_for(sims, "tiny_pairs_inst", **FAST)
    actions = planner.act(observe(sim, sim.initial_state(1), 1))
    assert chosen(actions) == {("flip", ("s2",)), ("flip", ("s3",))}
    root = planner._root
    assert root is not None and len(root.acts) == 10  # 11 joint actions, {s2, s4} is illegal
    assert planner.library is not None
    legal = planner.library.take(root.acts)
    assert sim.check_actions(sim.initial_state(1)[[0] * 10], legal).all()
    # 3 steps of 8, approached from below (the rollouts' first estimate is lower)
    assert 22.0 < float(root.q().max()) <= 24.0


def test_enumeration_of_joint_actions(sims: dict[str, Simulator]) -> None:
    acts = enumerate_boolean(sims["tiny_pairs_inst"], limit=100)
    assert acts is not None
    flips = acts["flip"]
    assert flips.shape == (11, 4) and not flips[0].any()  # noop first
    assert sorted(map(tuple, flips.astype(int).tolist())) == sorted(
        {
            tuple(int(i in c) for i in range(4))
            for c in [(), (0,), (1,), (2,), (3,), (0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
        }
    )
    assert enumerate_boolean(sims["tiny_pairs_inst"], limit=10) is None
    assert enumerate_boolean(sims["corridor_enum_inst_1"], limit=100) is None  # enum action


@pytest.mark.parametrize(
    "steps_left,expected", [(6, {("work", ())}), (3, {("work", ())}), (2, set()), (1, set())]
)
def test_delayed_reward_needs_enough_steps(
    sims: dict[str, Simulator], steps_left: int, expected: set[tuple[str, tuple[str, ...]]]
) -> None:
    sim = sims["tiny_delayed_inst"]
    planner = planner_for(sims, "tiny_delayed_inst", **FAST)
    actions = planner.act(observe(sim, sim.initial_state(1), 7 - steps_left, steps_left))
    assert chosen(actions) == expected


def test_depth_option_limits_the_lookahead(sims: dict[str, Simulator]) -> None:
    """With a lookahead of 2 the delayed reward is out of sight."""
    sim = sims["tiny_delayed_inst"]
    planner = planner_for(sims, "tiny_delayed_inst", depth="2", **FAST)
    assert planner.act(observe(sim, sim.initial_state(1), 1)) == []


def test_enum_actions_are_sampled(sims: dict[str, Simulator]) -> None:
    """corridor_enum: an enum action with preconditions; walking right
    towards the goal is best, and walking into the wall is never a candidate."""
    sim = sims["corridor_enum_inst_1"]
    planner = planner_for(sims, "corridor_enum_inst_1", **FAST)
    actions = planner.act(observe(sim, sim.initial_state(1), 1))
    assert actions == [("step", (), "@right")]
    root = planner._root
    assert root is not None and planner.library is not None
    values = set(planner.library.take(root.acts)["step"].tolist())
    codes = {name: i for i, name in enumerate(sim.model.types["direction"].members)}
    assert values == {codes["@stay"], codes["@right"]}  # @left is illegal at pos 0


# ----------------------------------------------------------- reuse, seeds, time


def test_subtree_reused_for_the_observed_successor(sims: dict[str, Simulator]) -> None:
    sim = sims["tiny_pairs_inst"]
    planner = planner_for(sims, "tiny_pairs_inst", **FAST)
    state = sim.initial_state(1)
    actions = planner.act(observe(sim, state, 1))
    old_root = planner._root
    assert old_root is not None and planner._last is not None
    arrays = sim.actions_from_names({(n, a): v for n, a, v in actions})
    nxt = sim.step(state, arrays, np.random.default_rng(0)).next_state
    planner.act(observe(sim, nxt, 2))
    assert planner.last_turn.reused == 1
    new_root = planner._root
    assert new_root is not None and new_root is not old_root
    assert any(o.node is new_root for ch in old_root.children for o in ch.values())
    # a state the tree has never seen gets a fresh root
    planner.act(observe(sim, state_with(sim, steps=7), 3))
    assert planner.last_turn.reused == 0


def play(
    sims: dict[str, Simulator], instance: str, options: dict[str, str], rounds: int = 1
) -> list[list[WireFluent]]:
    sim = sims[instance]
    planner = planner_for(sims, instance, **options)
    env = np.random.default_rng(5)
    out = []
    for r in range(rounds):
        planner.start_round(r + 1)
        state = sim.initial_state(1)
        for turn in range(1, (sim.model.horizon or 1) + 1):
            actions = planner.act(observe(sim, state, turn))
            out.append(actions)
            arrays = sim.actions_from_names({(n, a): v for n, a, v in actions})
            state = sim.step(state, arrays, env).next_state
    return out


def test_reproducible_with_a_seed(sims: dict[str, Simulator]) -> None:
    options = {"iterations": "3", "batch": "16", "rollouts": "1", "exploration": "2"}
    first = play(sims, "tiny_bandit_inst", {**options, "seed": "7"}, rounds=2)
    again = play(sims, "tiny_bandit_inst", {**options, "seed": "7"}, rounds=2)
    assert first == again
    others = [
        play(sims, "tiny_bandit_inst", {**options, "seed": str(s)}, rounds=2) for s in range(8, 12)
    ]
    assert any(o != first for o in others)  # the seed matters (with so little search)


def test_session_seed_is_used_without_the_option(sims: dict[str, Simulator]) -> None:
    options = {"iterations": "3", "batch": "16"}
    sim = sims["tiny_bandit_inst"]
    runs = []
    for _ in range(2):
        planner = planner_for(sims, "tiny_bandit_inst", session_seed=99, **options)
        planner.act(observe(sim, sim.initial_state(1), 1))
        root = planner._root
        assert root is not None
        runs.append(root.q().tolist())
    assert runs[0] == runs[1]


def test_fixed_time_per_step_is_respected(sims: dict[str, Simulator]) -> None:
    sim = sims["tiny_trap_inst"]
    planner = planner_for(sims, "tiny_trap_inst", time_per_step="0.3", batch="64", seed="3")
    obs = observe(sim, sim.initial_state(1), 1)
    obs = Observation(**{**obs.__dict__, "deadline": time.monotonic() + 30.0})  # ignored
    t0 = time.monotonic()
    planner.act(obs)
    took = time.monotonic() - t0
    # well under the 30 s deadline it was given, with room for a busy machine
    # (the deadline itself is tested under load in test_mcts_deadline.py)
    assert 0.15 <= took < 2.0
    stats = planner.last_turn
    assert stats.waves > 1 and stats.sim_steps > 0
    assert stats.steps_per_second == pytest.approx(stats.sim_steps / stats.seconds)
    assert planner.stats.sim_steps == stats.sim_steps


def test_observation_deadline_is_the_default(sims: dict[str, Simulator]) -> None:
    sim = sims["tiny_trap_inst"]
    planner = planner_for(sims, "tiny_trap_inst", batch="64", seed="3")
    obs = observe(sim, sim.initial_state(1), 1)
    obs = Observation(**{**obs.__dict__, "deadline": time.monotonic() + 0.1})
    t0 = time.monotonic()
    planner.act(obs)
    assert time.monotonic() - t0 < 2.0
    # a deadline already gone: one wave, an answer all the same
    obs = Observation(**{**obs.__dict__, "deadline": time.monotonic() - 1.0})
    assert chosen(planner.act(obs)) <= {("safe", ()), ("risky", ())}
    assert planner.last_turn.waves == 1


# ------------------------------------------------------------------ POMDP


def test_pomdp_plans_from_a_belief(sims: dict[str, Simulator], models: dict[str, Model]) -> None:
    """Without a state the planner keeps particles of the initial state and
    its own actions; its actions are legal in the true state."""
    name = "print_jobs_pomdp_inst_1"
    sim = sims[name]
    planner = planner_for(sims, name, particles="16", **FAST)
    codec = WireCodec(sim)
    env = np.random.default_rng(2)
    state = sim.initial_state(1)
    observation = None
    for turn in range(1, 6):
        fluents = None
        if observation is not None:
            fluents = {(n, a): v for n, a, v in codec.observation(observation)}
        obs = Observation(fluents, None, turn, 40 - turn + 1, 60.0, 0.0, time.monotonic() + 10.0)
        actions = planner.act(obs)
        arrays = sim.actions_from_names({(n, a): v for n, a, v in actions})
        assert sim.check_actions(state, arrays).all()
        out = sim.step(state, arrays, env)
        state, observation = out.next_state, out.observation
        assert planner._belief is not None and planner._belief.batch == 16


# ----------------------------------------------------------------- options


def test_registered_by_name() -> None:
    assert find_planner("mcts") is MCTSPlanner
    planner = make_planner("mcts", {"exploration": "1.5", "rollout-depth": "7", "batch": "32"})
    assert isinstance(planner, MCTSPlanner)
    st = planner.settings
    assert (st.exploration, st.rollout_depth, st.batch) == (1.5, 7, 32)
    assert set(MCTSPlanner.options) >= {
        "time_per_step",
        "exploration",
        "rollout_depth",
        "batch",
        "seed",
    }


@pytest.mark.parametrize(
    "options,message",
    [
        (
            {"explore": "1"},
            r"planner 'mcts' has no option 'explore' \(valid options: batch, bellman_outcomes, blind_future, blind_weight, compiled, depth",
        ),
        ({"batch": "0"}, "option 'batch' must be an integer >= 1, got '0'"),
        ({"time_per_step": "soon"}, "option 'time_per_step' must be a number, got 'soon'"),
        (
            {"rollout_policy": "greedy"},
            "option 'rollout_policy' must be one of random, noop, best, got 'greedy'",
        ),
    ],
)
def test_bad_options(options: dict[str, str], message: str) -> None:
    with pytest.raises(PlannerError, match=message):
        MCTSPlanner(**options)


def test_act_before_the_session() -> None:
    with pytest.raises(PlannerError, match="before start_session"):
        MCTSPlanner().act(Observation(None, None, 1, 1, 1.0, 0.0, time.monotonic()))


@pytest.mark.parametrize("policy", ["random", "noop", "best"])
def test_rollout_policies(sims: dict[str, Simulator], policy: str) -> None:
    sim = sims["tiny_bandit_inst"]
    planner = planner_for(sims, "tiny_bandit_inst", rollout_policy=policy, **FAST)
    assert chosen(planner.act(observe(sim, sim.initial_state(1), 1))) == {("pull", ("a3",))}


# --------------------------------------------------------------- loopback


@pytest.mark.trio
async def test_session_through_server_and_client() -> None:
    from ..client.loopback import Watch, our_server

    # (thts, the default engine: trials enough to see through IDS, which values risky
    # at 6 a step on the determinisation where it never falls)
    planner = make_planner("mcts", {"iterations": "500", "seed": "4"})
    assert isinstance(planner, MCTSPlanner)
    watch = Watch(planner)
    with trio.fail_after(60):
        async with our_server(TINY / "trap.rddl", rounds=2, timeout=60) as (port, _, _):
            config = ClientConfig(
                port=port, instance="tiny_trap_inst", client_name="mcts-test", timeout=30.0
            )
            result = await run_session(config, watch, "mcts")
    assert [r.turns for r in result.rounds] == [10, 10]
    assert planner.stats.turns == 20 and planner.stats.steps_per_second > 0
    # safe while the trap matters (the last turn of each round may go either way)
    for obs, actions in watch.turns:
        if obs.steps_left > 1:
            assert actions == [("safe", (), True)], (obs.turn, actions)
    assert all(r.reward in (50.0, 51.0) for r in result.rounds), result.rounds
