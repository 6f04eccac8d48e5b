"""Sinks in the thts engine: a new node whose every action is deterministic
and leaves the state as it is can never leave it, so it is solved at once,
each action at its reward plus the best reward every step after (in the
Python tree and in the C tree alike). TriangleTireworld's dead ends (a flat
tire, no spare in the car or at the place) are such states. (The tiny
domains' `fix` only costs: `prune_useless` would leave it out, so these
tests turn it off.)"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ippc.rddl import load_pair
from ippc.rddl.simulator import Simulator

from ..conftest import ippc_files
from .test_exact import model_of
from .test_mcts import observe
from .test_mcts_actions_c import needs_cc
from .test_mcts_thts import planner_on, root_of

# Broken, the car goes nowhere and `fix` only costs; whole, `go` moves it on and
# may break it. The reward is read in the current state.
SINK = """
domain tiny_sink {
    requirements = { concurrent, reward-deterministic };
    pvariables {
        broken : { state-fluent, bool, default = false };
        pos : { state-fluent, int, default = 0 };
        go : { action-fluent, bool, default = false };
        fix : { action-fluent, bool, default = false };
    };
    cpfs {
        broken' = if (broken) then true else if (go) then Bernoulli(0.5) else false;
        pos' = if (go ^ ~broken) then pos + 1 else pos;
    };
    reward = (if (broken) then -1 else 0) - 0.5 * fix;
}
instance tiny_sink_inst {
    domain = tiny_sink;
    init-state { broken = true; };
    max-nondef-actions = 1;
    horizon = 6;
    discount = 1.0;
}
instance tiny_sink_discounted {
    domain = tiny_sink;
    init-state { broken = true; };
    max-nondef-actions = 1;
    horizon = 6;
    discount = 0.9;
}
instance tiny_sink_whole {
    domain = tiny_sink;
    max-nondef-actions = 1;
    horizon = 6;
    discount = 1.0;
}
"""

TREES = pytest.mark.parametrize("compiled", ["no", pytest.param("yes", marks=needs_cc)])


def acts_values(planner, sim: Simulator, root) -> dict[str, float]:  # type: ignore[no-untyped-def]
    assert planner.library is not None
    out = {}
    for row, q in zip(root.rows, root.q, strict=True):
        names = sim.actions_to_names(planner.library.take(np.array([row])))
        out["+".join(n.split(" ")[0] for n in names) or "noop"] = float(q)
    return out


@TREES
@pytest.mark.parametrize("instance,gamma", [("tiny_sink_inst", 1.0), ("tiny_sink_discounted", 0.9)])
def test_a_sink_is_solved_at_once_at_its_exact_value(
    tmp_path: Path, compiled: str, instance: str, gamma: float
) -> None:
    model = model_of(tmp_path, SINK, instance)
    planner, sim = planner_on(
        model, iterations="50", seed="1", compiled=compiled, ids_depth="3", prune_useless="no"
    )
    state = sim.initial_state(1)
    steps = 6
    planner.act(observe(sim, state, 1, steps))
    root = root_of(planner, state, steps)
    assert root.solved
    assert planner.last_turn.locks == 1
    assert planner.last_turn.trials == 0  # a solved root ends the search
    rest = sum(gamma**i for i in range(1, steps))  # the steps after this one
    values = acts_values(planner, sim, root)
    # go does what noop does (equivalent, dropped); fix costs 0.5 more now, and
    # the best reward (noop's -1) follows every step after
    assert set(values) == {"noop", "fix"}
    assert values["noop"] == pytest.approx(-1 - rest, abs=1e-9)
    assert values["fix"] == pytest.approx(-1.5 - rest, abs=1e-9)
    assert root.value == pytest.approx(-1 - rest, abs=1e-9)


@TREES
def test_a_state_an_action_can_change_is_no_sink(tmp_path: Path, compiled: str) -> None:
    model = model_of(tmp_path, SINK, "tiny_sink_whole")
    planner, sim = planner_on(
        model, iterations="5", seed="1", compiled=compiled, ids_depth="3", prune_useless="no"
    )
    state = sim.initial_state(1)
    planner.act(observe(sim, state, 1, 6))
    root = root_of(planner, state, 6)
    assert not root.solved
    assert planner.last_turn.trials == 5
    # noop leaves the state as it is, deterministically; go does not
    assert set(acts_values(planner, sim, root)) == {"noop", "go", "fix"}


@TREES
def test_the_dead_ends_of_triangle_tireworld_are_sinks(compiled: str) -> None:
    """A flat tire, no spare in the car and none where it stands: nothing
    moves again, every step costs 1. Where a spare lies the state is no sink."""
    model = load_pair(*ippc_files("IPPC2014", "TriangleTireworld", 1))
    planner, sim = planner_on(model, iterations="20", seed="1", compiled=compiled, ids_depth="3")
    locations = model.types["location"].members
    state = sim.initial_state(1)
    spares = state.values["spare-in"][0]
    goal = {args[0] for (name, args) in sim.model.non_fluent_values if name == "goal-location"}
    bare = next(i for i, loc in enumerate(locations) if not spares[i] and loc not in goal)
    state.values["vehicle-at"][0][:] = False
    state.values["vehicle-at"][0][bare] = True
    state.values["not-flattire"][0] = False
    state.values["hasspare"][0] = False
    planner.act(observe(sim, state, 2, 30))
    root = root_of(planner, state, 30)
    assert root.solved and planner.last_turn.locks >= 1
    assert root.value == pytest.approx(-30.0)
    # the same place with a spare in the car: a tire change away from moving on
    state.values["hasspare"][0] = True
    planner.act(observe(sim, state, 3, 29))
    root = root_of(planner, state, 29)
    assert not root.solved


# Every step costs 1 whatever happens: IDS values every action alike everywhere.
# Broken is a sink; whole, `go` moves the car on and may break it.
BLIND = """
domain tiny_blind {
    requirements = { concurrent, reward-deterministic };
    pvariables {
        broken : { state-fluent, bool, default = false };
        pos : { state-fluent, int, default = 0 };
        go : { action-fluent, bool, default = false };
    };
    cpfs {
        broken' = if (broken) then true else if (go) then Bernoulli(0.5) else false;
        pos' = if (go ^ ~broken) then pos + 1 else pos;
    };
    reward = -1;
}
instance tiny_blind_inst {
    domain = tiny_blind;
    max-nondef-actions = 1;
    horizon = 6;
    discount = 1.0;
}
"""


@TREES
@pytest.mark.parametrize("blind_weight", ["0.5", "0"])
def test_blind_ids_values_stand_in_for_rollouts_once_a_sink_was_met(
    tmp_path: Path, compiled: str, blind_weight: str
) -> None:
    """Before any sink, a node whose IDS values are all alike gets roll-outs
    (-1 every step: -6 with 6 steps left); once the session has solved a
    sink, the IDS values times `blind_weight` instead (-6 x 0.5), unless
    that is 0."""
    model = model_of(tmp_path, BLIND, "tiny_blind_inst")
    planner, sim = planner_on(
        model,
        iterations="1",
        seed="1",
        compiled=compiled,
        ids_depth="3",
        blind_weight=blind_weight,
        prune_useless="no",
    )
    whole = sim.initial_state(1)
    planner.act(observe(sim, whole, 1, 6))
    before = root_of(planner, whole, 6)
    assert not before.solved and len(before.q) == 2
    assert max(before.q) == pytest.approx(-6.0)  # roll-outs, and one trial as long
    assert planner.last_turn.locks == 0
    broken = sim.initial_state(1)
    broken.values["broken"][0] = True
    planner.act(observe(sim, broken, 1, 6))
    assert planner.last_turn.locks == 1 and root_of(planner, broken, 6).solved
    whole.values["pos"][0] = 3  # a state not searched yet
    planner.act(observe(sim, whole, 1, 6))
    after = root_of(planner, whole, 6)
    if blind_weight == "0":
        assert max(after.q) == pytest.approx(-6.0)
    else:
        # -3 each, and the one trial's action -1 + 0.5 x -5 averaged in
        assert sorted(np.round(after.q, 9)) == [-3.25, -3.0]


# `go` costs 1 and moves the car on; the goal pays 10 a step from pos 4 on.
FAR = """
domain tiny_far {
    requirements = { concurrent, reward-deterministic };
    pvariables {
        pos : { state-fluent, int, default = 0 };
        go : { action-fluent, bool, default = false };
    };
    cpfs {
        pos' = if (go) then pos + 1 else pos;
    };
    reward = 10 * [pos >= 4] - go;
}
instance tiny_far_inst {
    domain = tiny_far;
    max-nondef-actions = 1;
    horizon = 8;
    discount = 1.0;
}
"""


@TREES
@pytest.mark.parametrize("blind_future", ["yes", "no"])
def test_ids_values_that_differ_only_by_the_first_reward_are_blind(
    tmp_path: Path, compiled: str, blind_future: str
) -> None:
    """From pos 0, IDS at depth 2 sees no goal: go's value is noop's less its
    cost (every action but noop costs now, and what follows is worth the same). With `blind_future` (the default) roll-outs value the root (and the
    node one trial reaches below it) instead; without it IDS's values do, and
    noop ranks first. A step from the goal (pos 3) IDS sees it, and its values
    stand either way."""
    model = model_of(tmp_path, FAR, "tiny_far_inst")
    planner, sim = planner_on(
        model, iterations="1", seed="1", compiled=compiled, ids_depth="2", blind_future=blind_future
    )
    far = sim.initial_state(1)
    planner.act(observe(sim, far, 1, 8))
    root = root_of(planner, far, 8)
    assert len(root.q) == 2
    if blind_future == "yes":
        assert planner.last_turn.ids_leaves == 0
    else:
        assert planner.last_turn.ids_leaves == 2
        if compiled == "no":  # (the C tree's view holds no first estimates)
            # depth 2: noop 0 + 0, go -1 + 0, scaled to the 8 steps left (x 4)
            assert sorted(np.round(root.h, 9)) == [-4.0, 0.0]
    near = sim.initial_state(1)
    near.values["pos"][0] = 3
    planner.act(observe(sim, near, 1, 8))
    assert planner.last_turn.ids_leaves >= 1
    if compiled == "no":
        # noop 0 + 0, go -1 + 10 (x 4)
        assert sorted(np.round(root_of(planner, near, 8).h, 9)) == [0.0, 36.0]


# As tiny_far, and `paint` is free: it counts only at pos 6 and more, out of IDS's sight.
FAR_PAINT = (
    FAR.replace("tiny_far", "tiny_far_paint")
    .replace(
        "go : { action-fluent, bool, default = false };",
        "go : { action-fluent, bool, default = false };\n"
        "        paint : { action-fluent, bool, default = false };\n"
        "        painted : { state-fluent, bool, default = false };",
    )
    .replace(
        "pos' = if (go) then pos + 1 else pos;",
        "pos' = if (go) then pos + 1 else pos;\n        painted' = painted | paint;",
    )
    .replace("- go;", "- go + 5 * [painted ^ pos >= 6];")
)


@TREES
def test_ids_values_stand_where_an_action_but_noop_costs_nothing_now(
    tmp_path: Path, compiled: str
) -> None:
    """The same far state, and `paint` costs nothing now: IDS's values are
    not blind (`blind_future` asks that every action but noop cost now)."""
    model = model_of(tmp_path, FAR_PAINT, "tiny_far_paint_inst")
    planner, sim = planner_on(model, iterations="1", seed="1", compiled=compiled, ids_depth="2")
    far = sim.initial_state(1)
    planner.act(observe(sim, far, 1, 8))
    assert len(root_of(planner, far, 8).q) == 3
    assert planner.last_turn.ids_leaves >= 1
