"""The thts engine's trials in C (`planners/mcts/ctree.py`) where the legal
actions depend on the state: each new node asks the Python chooser for its
candidates through a callback. The root keeps exactly the legal actions,
the values near `exact`'s, and the C tree on a corpus domain with
state-dependent preconditions: legal root actions, the same choices for a
seed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ippc.planners.exact import solve
from ippc.rddl import load_model, load_pair

from ..conftest import ippc_files
from .test_mcts import observe
from .test_mcts_thts import names, planner_on, root_of

GATED = """
domain tiny_gated {
    requirements = { concurrent, preconditions };
    pvariables {
        open : { state-fluent, bool, default = false };
        gold : { state-fluent, bool, default = false };
        unlock : { action-fluent, bool, default = false };
        grab : { action-fluent, bool, default = false };
    };
    cpfs {
        // unlocking opens the door with probability 0.6; grabbing, only
        // legal through an open door, finds gold with probability 0.5
        open' = open | (unlock & Bernoulli(0.6));
        gold' = grab & Bernoulli(0.5);
    };
    reward = 3 * gold - 0.25 * unlock;
    action-preconditions {
        grab => open;
        unlock => ~open;
    };
}
instance tiny_gated_inst {
    domain = tiny_gated;
    init-state { open = false; };
    max-nondef-actions = 1;
    horizon = 6;
    discount = 1.0;
}
"""


@pytest.fixture(scope="module")
def gated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("gated") / "gated.rddl"
    path.write_text(GATED)
    return path


def test_the_root_keeps_exactly_the_legal_actions(gated: Path) -> None:
    """Closed door: noop and unlock (grab is illegal); open door: noop and
    grab (unlock is illegal). The C tree asked the chooser for them."""
    model = load_model(gated)
    planner, sim = planner_on(model, iterations="200", seed="1", compiled="yes")
    search = planner._thts
    assert search is not None and search.tree is not None and search.tree.dynamic
    closed = sim.initial_state(1)
    planner.act(observe(sim, closed, 1, 6))
    kept = sorted(tuple(names(planner, sim, r)) for r in root_of(planner, closed, 6).rows)
    assert kept == [(), ("unlock = true",)]
    opened = sim.initial_state(1)
    opened.values["open"][0] = True
    planner.act(observe(sim, opened, 2, 5))
    kept = sorted(tuple(names(planner, sim, r)) for r in root_of(planner, opened, 5).rows)
    assert kept == [(), ("grab = true",)]


@pytest.mark.parametrize("heuristic", ["rollout", "ids"])
def test_values_converge_to_exact_with_state_dependent_candidates(
    gated: Path, heuristic: str
) -> None:
    model = load_model(gated)
    exact = solve(model)
    planner, sim = planner_on(
        model, iterations="4000", seed="2", compiled="yes", heuristic=heuristic
    )
    state = sim.initial_state(1)
    planner.act(observe(sim, state, 1, 6))
    root = root_of(planner, state, 6)
    assert planner.library is not None
    q_exact = exact.q[6][exact.index(state)]
    for row, q in zip(root.rows, root.q, strict=True):
        act = planner.library.take(np.array([row]))
        assert q == pytest.approx(float(q_exact[exact.action_index(act)]), abs=0.6)
    chosen = planner.library.take(np.array([root.rows[int(np.argmax(root.q))]]))
    assert exact.action_index(chosen) == int(np.argmax(q_exact))


def test_the_c_tree_plays_a_corpus_domain_with_state_dependent_preconditions() -> None:
    """AcademicAdvising 2018 (a course only when its prerequisites are
    met): the C tree runs, every root action is legal in the state, and a
    seed gives the same choice twice."""
    model = load_pair(*ippc_files("IPPC2018", "AcademicAdvising", 1))

    def play() -> list[list[str]]:
        planner, sim = planner_on(model, iterations="30", seed="5", compiled="yes", ids_depth="2")
        search = planner._thts
        assert search is not None and search.tree is not None and search.tree.dynamic
        rng = np.random.default_rng(3)
        state = sim.initial_state(1)
        chosen = []
        for turn in range(1, 4):
            planner.act(observe(sim, state, turn))
            root = root_of(planner, state, model.horizon - turn + 1)
            assert planner.library is not None
            for row in root.rows:
                act = planner.library.take(np.array([row]))
                assert sim.check_actions(state, act).all()
            assert planner._last_action is not None
            chosen.append(sim.actions_to_names(planner._last_action))
            state = sim.step(state, planner._last_action, rng).next_state
        return chosen

    assert play() == play()
