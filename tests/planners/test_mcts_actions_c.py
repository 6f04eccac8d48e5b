"""What the thts engine's candidates are made of: inert action groundings
(never read by the step once the non-fluents are folded in) left out, the
legal joint actions of a state walked in C (`CStep.enumerate`, used only
where it finds what the Python solver finds), roll-outs over a state's legal
groundings (`CStep.walk_enum`), and IDS deepening from 2 (option
`ids_deepen`). (tests/conftest.py points IPPC_CACHE at the run's
temporary folder.)"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ippc.planners.mcts.actions import enumerate_boolean
from ippc.planners.mcts.heuristic import training_states
from ippc.planners.mcts.relevance import downward_closed
from ippc.planners.mcts.thts import THTS
from ippc.rddl import load_pair
from ippc.rddl.sim.cstep import find_compiler
from ippc.rddl.sim.scalar import ScalarStep
from ippc.rddl.simulator import Simulator

from ..conftest import ippc_files
from .test_exact import model_of
from .test_mcts import observe
from .test_mcts_thts import planner_on, root_of

needs_cc = pytest.mark.skipif(find_compiler() is None, reason="no C compiler")


def tireworld(n: int) -> Simulator:
    return Simulator(load_pair(*ippc_files("IPPC2014", "TriangleTireworld", n)))


def roads(sim: Simulator) -> set[tuple[str, str]]:
    return {args for (name, args) in sim.model.non_fluent_values if name == "road"}


def test_the_inert_groundings_of_triangle_tireworld_are_the_moves_without_a_road() -> None:
    sim = tireworld(1)
    fast = ScalarStep(sim)
    locations = sim.model.types["location"].members
    inert = fast.inert_actions
    assert inert, "TriangleTireworld #1 has moves between locations without a road"
    assert {name for name, _ in inert} == {"move-car"}
    moves = {(locations[i], locations[j]) for _, (i, j) in inert}
    everything = {(a, b) for a in locations for b in locations}
    assert moves == everything - roads(sim)


def test_every_grounding_is_read_where_the_non_fluents_rule_out_none() -> None:
    sim = Simulator(load_pair(*ippc_files("IPPC2011", "SysAdmin", 1)))
    assert ScalarStep(sim).inert_actions == []


def test_enumerate_boolean_leaves_the_skipped_groundings_at_their_default() -> None:
    sim = tireworld(1)
    inert = ScalarStep(sim).inert_actions
    whole = enumerate_boolean(sim, 4096)
    less = enumerate_boolean(sim, 4096, inert)
    assert whole is not None and less is not None
    n_grounds = sum(int(np.prod(v.shape[1:], dtype=int)) for v in sim.noop(1).values())
    # max-nondef-actions is 1: noop and one grounding each
    assert len(whole["move-car"]) == 1 + n_grounds
    assert len(less["move-car"]) == 1 + n_grounds - len(inert)
    for _, (i, j) in inert:
        assert not less["move-car"][:, i, j].any()


@needs_cc
def test_the_thts_candidates_and_rollout_pool_set_no_inert_grounding() -> None:
    model = load_pair(*ippc_files("IPPC2014", "TriangleTireworld", 2))
    planner, sim = planner_on(model, iterations="20", seed="1", compiled="yes")
    search = planner._thts
    assert search is not None and search._static
    state = sim.initial_state(1)
    planner.act(observe(sim, state, 1, 40))
    locations = model.types["location"].members
    road = roads(sim)
    rows = search._candidates(search.fast.encode_state(state))
    # noop, a move along each road, loadtire at each location, changetire
    assert len(rows) == 1 + len(road) + len(locations) + 1
    acts = search.chooser.lib.take(np.array(rows))
    moves = np.argwhere(acts["move-car"])
    assert {(locations[i], locations[j]) for _, i, j in moves} == road
    pool = search.chooser.lib.take(search.chooser.pool)
    assert {(locations[i], locations[j]) for _, i, j in np.argwhere(pool["move-car"])} == road


# -- the legal joint actions of a state in C -------------------------------------------


def _solver_sets(search: THTS, state: tuple[Any, ...]) -> set[tuple[str, ...]] | None:
    """The solver's legal joint actions of `state` (None where it does not
    list them all), each as the sorted names of what it sets."""
    sim = search.sim
    decoded = search.fast.decode_state(state)
    space = search.chooser.solver.space(decoded, 0)  # type: ignore[union-attr]
    if not space.complete or space.count > 4096:
        return None
    acts = search.chooser.solver.enumerate(decoded, 0)  # type: ignore[union-attr]
    n = len(next(iter(acts.values())))
    defaults = sim.noop(1)
    # the groundings the search leaves out (inert, and useless with prune_useless)
    keep = [
        all(
            acts[name][(i, *idx)] == defaults[name][(0, *idx)]
            for name, idx in search.chooser.skipped
        )
        for i in range(n)
    ]
    return {
        tuple(sorted(sim.actions_to_names({k: v[i : i + 1] for k, v in acts.items()})))
        for i in range(n)
        if keep[i]
    }


def _c_sets(search: THTS, state: tuple[Any, ...]) -> set[tuple[str, ...]]:
    sim = search.sim
    rows = search._candidates(state)
    acts = search.chooser.lib.take(np.array(rows))
    return {
        tuple(sorted(sim.actions_to_names({k: v[i : i + 1] for k, v in acts.items()})))
        for i in range(len(rows))
    }


@needs_cc
@pytest.mark.parametrize(
    ("year", "domain", "n"),
    [("IPPC2018", "CooperativeRecon", 1), ("IPPC2018", "AcademicAdvising", 1)],
)
@pytest.mark.parametrize("prune", ["no", "yes"])
def test_the_c_walk_finds_the_legal_actions_the_solver_finds(
    year: str, domain: str, n: int, prune: str
) -> None:
    """On random-walk states other than the 16 the session checked it on:
    the same set as the solver's (less those that set a grounding the
    search leaves out), noop first, and each one legal."""
    model = load_pair(*ippc_files(year, domain, n))
    planner, sim = planner_on(model, iterations="10", seed="1", compiled="yes", prune_useless=prune)
    search = planner._thts
    assert search is not None and search._cenum, "the C walk is on for this domain"
    if domain == "AcademicAdvising":
        # 9 of its 15 courses lead to no program requirement (tests/planners/test_mcts_relevance.py)
        assert len(search.chooser.skipped) == (9 if prune == "yes" else 0)
    states = training_states(sim, np.random.default_rng(77))
    compared = 0
    for i in range(states.batch):
        key = search.fast.encode_state(states, i)
        theirs = _solver_sets(search, key)
        if theirs is None:
            continue
        rows = search._candidates(key)
        assert rows[0] == 0  # noop first (library row 0)
        assert _c_sets(search, key) == theirs
        acts = search.chooser.lib.take(np.array(rows))
        one = states[np.full(len(rows), i)]
        assert sim.check_actions(one, acts).all()
        compared += 1
    assert compared >= 10


NON_MONOTONE = """
domain tiny_pair {
    requirements = { concurrent, preconditions };
    pvariables {
        ready : { state-fluent, bool, default = true };
        done : { state-fluent, bool, default = false };
        a : { action-fluent, bool, default = false };
        b : { action-fluent, bool, default = false };
    };
    cpfs {
        ready' = ready;
        done' = done | (a & b);
    };
    reward = 5 * [done' ^ ~done] - 0.1 * a;
    action-preconditions {
        // b only together with a: {b} alone is illegal, {a, b} legal
        b => a;
        a => ready;
    };
}
instance tiny_pair_inst {
    domain = tiny_pair;
    init-state { ready = true; };
    max-nondef-actions = 2;
    horizon = 4;
    discount = 0.9;
}
"""


@needs_cc
def test_constraints_the_c_walk_cannot_follow_keep_the_solver(tmp_path: Path) -> None:
    """`b => a`: the joint action {a, b} is legal though {b} alone is not, so
    the C walk (which only joins groundings legal alone) would miss it: the
    session checks, keeps the solver, and the search still finds {a, b}."""
    model = model_of(tmp_path, NON_MONOTONE, "tiny_pair_inst")
    planner, sim = planner_on(model, iterations="300", seed="1", compiled="yes")
    search = planner._thts
    assert search is not None and not search._static
    assert not search._cenum
    state = sim.initial_state(1)
    planner.act(observe(sim, state, 1, 4))
    chosen = sorted(sim.actions_to_names(planner._last_action))
    assert chosen == ["a = true", "b = true"]
    # (the walk itself would miss it: the constraints are not proven downward
    # closed, so the session never sets it up)
    assert not downward_closed(search.fast, search.chooser.skipped)
    assert search.c is not None
    n, combos = search.c.enumerate(search.fast.encode_state(state), 16)
    assert n == -1 and combos == []


# -- IDS deepening from 2 (ids_deepen) ------------------------------------------------

CHAIN = """
domain tiny_chain {
    requirements = { reward-deterministic };
    pvariables {
        pos : { state-fluent, int, default = 0 };
        go : { action-fluent, bool, default = false };
    };
    cpfs {
        pos' = if (go ^ pos < 3) then pos + 1 else pos;
    };
    // 10 a step once at the end of the chain; going costs a little
    reward = 10 * [pos == 3] - 0.5 * go;
}
instance tiny_chain_inst {
    domain = tiny_chain;
    init-state { pos = 0; };
    max-nondef-actions = 1;
    horizon = 8;
    discount = 1.0;
}
"""


@pytest.mark.parametrize("deepen", ["no", "yes"])
def test_ids_deepening_stops_at_the_first_depth_where_an_action_beats_noop(
    tmp_path: Path, deepen: str
) -> None:
    """From pos 0 going pays only from the fourth step on: with `ids_deepen`
    the search deepens 2, 3, 4 (go's value then exceeds noop's) and stops;
    without it, it searches at the whole depth (6) at once. (The Python
    reference, whose IDS calls are seen here; the next test holds the C
    tree to its values.)"""
    compiled = "no"
    model = model_of(tmp_path, CHAIN, "tiny_chain_inst")
    planner, sim = planner_on(  # (without the smoothing's second search one depth less)
        model,
        iterations="1",
        seed="1",
        compiled=compiled,
        ids_depth="6",
        ids_deepen=deepen,
        ids_smooth="no",
        blind_future="no",  # (nor its depth-1 search)
    )
    search = planner._thts
    assert search is not None
    depths: list[int] = []
    at = search._ids_at

    def recording(state: Any, kept: list[Any], d: int, check: bool) -> list[float]:
        depths.append(d)
        return at(state, kept, d, check)

    search._ids_at = recording  # type: ignore[method-assign]
    state = sim.initial_state(1)
    planner.act(observe(sim, state, 1, 8))
    root = root_of(planner, state, 8)
    assert len(root.rows) == 2
    if deepen == "yes":
        assert depths[:3] == [2, 3, 4]  # the root's: go beats noop at depth 4
    else:
        assert depths and set(depths) == {6}


@needs_cc
@pytest.mark.parametrize("deepen", ["no", "yes"])
def test_the_c_tree_values_the_root_as_the_python_reference(tmp_path: Path, deepen: str) -> None:
    """The trials in C deepen IDS the same way: one trial of the C tree and
    of the Python reference on the deterministic chain leaves the root with
    the same values."""
    model = model_of(tmp_path, CHAIN, "tiny_chain_inst")
    values = []
    for tree in (True, False):
        planner, sim = planner_on(
            model,
            iterations="1",
            seed="1",
            compiled="yes" if tree else "no",
            ids_depth="6",
            ids_deepen=deepen,
        )
        search = planner._thts
        assert search is not None and (getattr(search, "tree", None) is not None) is tree
        state = sim.initial_state(1)
        planner.act(observe(sim, state, 1, 8))
        root = root_of(planner, state, 8)
        values.append(sorted(zip(root.rows, np.round(root.q, 9), strict=True)))
    assert values[0] == values[1]


# -- roll-outs over the legal actions of a state, in C ----------------------------------

GUARDED = """
domain tiny_guarded {
    requirements = { concurrent, preconditions };
    pvariables {
        key : { state-fluent, bool, default = false };
        small : { action-fluent, bool, default = false };
        big : { action-fluent, bool, default = false };
    };
    cpfs {
        key' = key;
    };
    // what a step's reward says about its action: 0 noop, 1 small, 100 big
    reward = 1 * small + 100 * big;
    action-preconditions {
        big => key;
    };
}
instance tiny_guarded_inst {
    domain = tiny_guarded;
    init-state { key = false; };
    max-nondef-actions = 1;
    horizon = 3;
    discount = 1.0;
}
"""


@needs_cc
def test_c_rollouts_draw_noop_and_the_groundings_legal_in_the_state(tmp_path: Path) -> None:
    """Without a key `big` is illegal: one-step roll-outs give 0 (noop) or 1
    (small), both, and never 100; with the key all three come up."""
    model = model_of(tmp_path, GUARDED, "tiny_guarded_inst")
    planner, sim = planner_on(model, iterations="10", seed="1", compiled="yes")
    search = planner._thts
    assert search is not None and search._cenum and search.c is not None
    state = sim.initial_state(1)
    locked = search.fast.encode_state(state)
    state.values["key"][0] = True
    opened = search.fast.encode_state(state)
    seen_locked = {search.c.walk_enum(locked, 1, 1.0)[0] for _ in range(300)}
    seen_opened = {search.c.walk_enum(opened, 1, 1.0)[0] for _ in range(300)}
    assert seen_locked == {0.0, 1.0}
    assert seen_opened == {0.0, 1.0, 100.0}
    total, taken, ended = search.c.walk_enum(opened, 3, 1.0)
    assert taken == 3 and not ended and total in {0, 1, 2, 3, 100, 101, 102, 200, 201, 300}
