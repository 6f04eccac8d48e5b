"""The search's arithmetic against exact values, its initialisation by IDS
and its reward-lock check: `mcts` on the tiny domains, compared with what
`ippc.planners.exact` and `ippc.planners.mcts.heuristic` compute on their
own."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ippc.planners import SessionInfo
from ippc.planners.exact import solve
from ippc.planners.mcts import MCTSPlanner
from ippc.rddl import Model, load
from ippc.rddl.simulator import Simulator

from .test_mcts import observe, state_with

TINY = Path(__file__).resolve().parent / "tiny_domains"


@pytest.fixture(scope="module")
def models() -> dict[str, Model]:
    return load(TINY)


def planner_on(model: Model, **options: str) -> tuple[MCTSPlanner, Simulator]:
    sim = Simulator(model)
    planner = MCTSPlanner(**{"engine": "wave", **options})
    planner.start_session(SessionInfo(model.name, model, sim, rounds=1, time_allowed=60.0, seed=1))
    planner.start_round(1)
    return planner, sim


@pytest.mark.parametrize("heuristic", ["rollout", "ids"])
@pytest.mark.parametrize("steps_left", [1, 2, 3, 5])
def test_root_values_converge_to_the_exact_q_values(
    models: dict[str, Model], heuristic: str, steps_left: int
) -> None:
    """After enough trials every root action's value is near its exact
    expected return (value iteration over the same model): the backups
    average the sampled outcomes by their frequencies and take the best
    action below, whatever the first estimate was."""
    model = models["tiny_trap_inst"]
    exact = solve(model)
    planner, sim = planner_on(
        model, heuristic=heuristic, iterations="400", batch="64", seed="2", trial_depth="0"
    )
    state = sim.initial_state(1)
    planner.act(observe(sim, state, 11 - steps_left, steps_left))
    root = planner._root
    assert root is not None and planner.library is not None
    q_exact = exact.q[steps_left][exact.index(state)]
    for a, row in enumerate(root.acts.tolist()):
        act = planner.library.take(np.array([row]))
        expected = float(q_exact[exact.action_index(act)])
        # the trap costs 20 a step with probability 0.1 a risky step: the
        # sampled frequencies err by a few percent of that
        assert root.qv[a] == pytest.approx(expected, abs=0.05 * 20 * steps_left + 0.5), (
            sim.actions_to_names(act),
            root.qv,
        )


def test_ids_gives_new_nodes_their_first_values(models: dict[str, Model]) -> None:
    """With `heuristic=ids` a new node's actions start at IDS's estimate on
    the most-likely determinisation (trap: `risky` never falls there, so it
    looks better, 6 a step against 5)."""
    # (the search's value of this state is tested above: the trials correct it)
    model = models["tiny_trap_inst"]
    planner, sim = planner_on(model, heuristic="ids", iterations="1", batch="8", seed="1")
    ids = planner._expander.ids if planner._expander is not None else None
    assert ids is not None and not ids.fallback
    state = sim.initial_state(1)
    planner.act(observe(sim, state, 7, 4))
    root = planner._root
    assert root is not None and planner.library is not None
    q = ids.estimate(state, [4], [planner.library.take(root.acts)])[0]
    assert root.h == pytest.approx(q.tolist())
    names = [sim.actions_to_names(planner.library.take(np.array([r]))) for r in root.acts]
    h = dict(zip(map(tuple, names), root.h, strict=True))
    assert h[("risky = true",)] == pytest.approx(24.0)
    # (IDS stops at depth 2, where the actions differ from noop: safe then
    # risky, 11 in two steps, 22 in four)
    assert h[("safe = true",)] == pytest.approx(22.0)
    assert h[()] < h[("safe = true",)]


def test_heuristic_weight_scales_the_estimate(models: dict[str, Model]) -> None:
    model = models["tiny_trap_inst"]
    planner, sim = planner_on(
        model, heuristic="ids", heuristic_weight="0.5", iterations="1", batch="8", seed="1"
    )
    planner.act(observe(sim, sim.initial_state(1), 7, 4))
    root = planner._root
    assert root is not None
    assert sorted(root.h) == pytest.approx([6.0, 11.0, 12.0])


def test_rollouts_where_ids_cannot_tell_the_actions_apart(models: dict[str, Model]) -> None:
    """Dead in the trap, IDS values every action alike (-20 a step): those
    leaves get rollouts instead, which the counters tell apart."""
    model = models["tiny_trap_inst"]
    planner, sim = planner_on(model, heuristic="ids", iterations="1", batch="8", seed="1")
    planner.act(observe(sim, state_with(sim, dead=True), 7, 4))
    assert planner.last_turn.leaves >= 1 and planner.last_turn.ids_leaves == 0
    planner.act(observe(sim, sim.initial_state(1), 7, 4))
    assert planner.last_turn.ids_leaves >= 1


@pytest.mark.parametrize("locks", ["yes", "no"])
def test_a_reward_lock_is_solved_at_once(models: dict[str, Model], locks: str) -> None:
    """Dead in the trap, every step costs 20 whatever is done: with the
    reward-lock check the node keeps one action, worth exactly -20 a step,
    and no trial goes below it; without it every action is searched."""
    model = models["tiny_trap_inst"]
    planner, sim = planner_on(model, reward_locks=locks, iterations="5", batch="8", seed="1")
    planner.act(observe(sim, state_with(sim, dead=True), 7, 4))
    root = planner._root
    assert root is not None
    if locks == "yes":
        assert len(root.acts) == 1 and root.terminal
        assert root.value == pytest.approx(-80.0)
        assert planner.last_turn.locks == 1 and planner.last_turn.trials == 0
    else:
        assert len(root.acts) == 3 and not root.terminal
        assert planner.last_turn.locks == 0 and planner.last_turn.trials > 0


@pytest.mark.parametrize(("new_nodes", "deepest"), [("1", 1), ("3", 3), ("0", 6)])
def test_new_nodes_lets_a_trial_go_on_below_the_leaf_it_expanded(
    models: dict[str, Model], new_nodes: str, deepest: int
) -> None:
    """One wave: a trial stops at the first new node; with `new_nodes` k it
    goes on below it once it is expanded, through k new nodes in all (0:
    down to `trial_depth`), so the tree grows that many levels a wave."""
    model = models["tiny_trap_inst"]
    planner, sim = planner_on(
        model, new_nodes=new_nodes, trial_depth="6", iterations="1", batch="8", seed="1"
    )
    planner.act(observe(sim, sim.initial_state(1), 1, 10))
    expanded = [
        10 - steps
        for steps, bucket in planner._table.items()
        for node in bucket.values()
        if node.expanded and steps < 10
    ]
    assert max(expanded) == deepest
