"""`mcts`'s single-state engine (`engine=thts`, `planners/mcts/thts.py`):
its values against `exact`'s on the tiny domains, the exact last step,
solved labelling on a deterministic domain, equivalent-action pruning on a
hand-made domain, the fallback to the wave search, and the same search for
the same seed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ippc.planners import SessionInfo
from ippc.planners.exact import solve
from ippc.planners.mcts import MCTSPlanner
from ippc.planners.mcts.thts import TNode
from ippc.rddl import Model, load_model, load_pair
from ippc.rddl.simulator import Simulator, State

from ..conftest import ippc_files
from . import test_mcts_search
from .test_mcts import observe
from .thts_reference import ReferencePlanner

models = test_mcts_search.models  # the tiny domains (a fixture)


def planner_on(model: Model, **options: str) -> tuple[MCTSPlanner, Simulator]:
    """mcts's thts engine on `model`: the C tree, or with `compiled="no"` the
    Python reference of the same search (tests/planners/thts_reference.py)."""
    sim = Simulator(model)
    kind = ReferencePlanner if options.get("compiled") == "no" else MCTSPlanner
    planner = kind(engine="thts", **options)
    planner.start_session(SessionInfo(model.name, model, sim, rounds=1, time_allowed=60.0, seed=1))
    planner.start_round(1)
    if options.get("compiled") == "yes":  # the C tree where it fits (these domains)
        assert planner._thts is not None and planner._thts.tree is not None
    return planner, sim


def root_of(planner: MCTSPlanner, state: State, steps: int) -> TNode:
    """The node of `state` after a turn: the reference tree's (`compiled=no`),
    or the view of the C tree's."""
    search = planner._thts
    assert search is not None
    key = search.fast.encode_state(state)
    if getattr(search, "tree", None) is not None:  # (the reference has no C tree)
        return search.root(key, steps)
    return search.table[steps][key]


# the Python reference of the search, and the search in C (planners/mcts/csrc/tree.c)
COMPILED = pytest.mark.parametrize("compiled", ["no", "yes"])


def names(planner: MCTSPlanner, sim: Simulator, row: int) -> list[str]:
    assert planner.library is not None
    return sim.actions_to_names(planner.library.take(np.array([row])))


@pytest.mark.parametrize("heuristic", ["rollout", "ids"])
@pytest.mark.parametrize("steps_left", [1, 2, 3, 5])
@COMPILED
def test_root_values_converge_to_the_exact_q_values(
    models: dict[str, Model], heuristic: str, compiled: str, steps_left: int
) -> None:
    """After enough trials every root action's value is near its exact
    expected return: the MaxMonteCarlo backups weight the sampled outcomes
    by their frequencies and take the best action below, whatever the first
    estimate (a roll-out, or IDS, which values `risky` too well)."""
    model = models["tiny_trap_inst"]
    exact = solve(model)
    planner, sim = planner_on(
        model, heuristic=heuristic, iterations="3000", seed="2", compiled=compiled
    )
    assert planner.engine == "thts"
    state = sim.initial_state(1)
    planner.act(observe(sim, state, 11 - steps_left, steps_left))
    root = root_of(planner, state, steps_left)
    assert planner.library is not None
    q_exact = exact.q[steps_left][exact.index(state)]
    assert len(root.rows) == 3
    for row, q, n in zip(root.rows, root.q, root.n, strict=True):
        act = planner.library.take(np.array([row]))
        expected = float(q_exact[exact.action_index(act)])
        # the fall (p 0.1) costs 20 a step: a rarely tried action's sample
        # frequencies err by more than a well tried one's
        tol = 0.5 + (0.05 if n >= 300 else 0.2) * 20 * steps_left
        assert q == pytest.approx(expected, abs=tol), (names(planner, sim, row), root.q, root.n)
    best = int(np.argmax(q_exact))
    chosen = planner.library.take(np.array([root.rows[int(np.argmax(root.q))]]))
    assert exact.action_index(chosen) == best


@COMPILED
def test_the_last_step_is_evaluated_exactly_and_solved(
    models: dict[str, Model], compiled: str
) -> None:
    """With one step left each action's value is its reward, without
    sampling, and the root is solved at once (no trial runs)."""
    model = models["tiny_trap_inst"]
    planner, sim = planner_on(model, iterations="50", compiled=compiled)
    state = sim.initial_state(1)
    planner.act(observe(sim, state, 10, 1))
    root = root_of(planner, state, 1)
    assert root.solved and all(root.asolved)
    values = {tuple(names(planner, sim, r)): q for r, q in zip(root.rows, root.q, strict=True)}
    assert values == {(): 0.0, ("safe = true",): 5.0, ("risky = true",): 6.0}
    assert planner.last_turn.trials == 0


@COMPILED
def test_a_deterministic_domain_is_solved_with_its_exact_value(
    models: dict[str, Model], compiled: str
) -> None:
    """tiny_delayed has no draws: every action is deterministic, so the
    search labels nodes solved from the last step up and ends the turn
    when the root is solved, with the optimal value (work three times: 7,
    twice in six steps)."""
    model = models["tiny_delayed_inst"]
    planner, sim = planner_on(model, iterations="100000", compiled=compiled)
    state = sim.initial_state(1)
    planner.act(observe(sim, state, 1, 6))
    root = root_of(planner, state, 6)
    assert root.solved
    assert root.value == pytest.approx(14.0)
    assert planner.last_turn.trials < 100000  # it stopped when solved
    work = root.q[[names(planner, sim, r) for r in root.rows].index(["work = true"])]
    assert work == pytest.approx(14.0)


EQUIVALENT = """
domain tiny_equivalent {
    requirements = { concurrent };
    pvariables {
        lit : { state-fluent, bool, default = false };
        press-a : { action-fluent, bool, default = false };
        press-b : { action-fluent, bool, default = false };
        press-c : { action-fluent, bool, default = false };
        press-d : { action-fluent, bool, default = false };
        press-e : { action-fluent, bool, default = false };
    };
    cpfs {
        // a and b: the same deterministic effect; d the same as a but with a
        // cost; c and e the same Bernoulli, stochastic look-alikes
        lit' = if (press-a | press-b | press-d) then true
               else if (press-c | press-e) then Bernoulli(0.6)
               else lit;
    };
    reward = lit - 0.5 * press-d;
}
instance tiny_equivalent_inst {
    domain = tiny_equivalent;
    init-state { lit = false; };
    max-nondef-actions = 1;
    horizon = 5;
    discount = 1.0;
}
"""
# press-a and press-b are deterministic with the same successor and reward:
# one is kept. press-d's reward differs, and c and e are stochastic (two
# stochastic actions are never merged, however alike): all kept, as is noop.
KEPT_OTHERS = [("press-c = true",), ("press-d = true",), ("press-e = true",)]


@COMPILED
def test_equivalent_actions_are_pruned(tmp_path: Path, compiled: str) -> None:
    """Of EQUIVALENT's actions, one of press-a and press-b is kept, with the
    others and noop."""
    (tmp_path / "equivalent.rddl").write_text(EQUIVALENT)
    model = load_model(tmp_path / "equivalent.rddl")
    planner, sim = planner_on(model, iterations="200", seed="3", compiled=compiled)
    state = sim.initial_state(1)
    planner.act(observe(sim, state, 1, 5))
    root = root_of(planner, state, 5)
    kept = sorted(tuple(names(planner, sim, r)) for r in root.rows)
    one = [k for k in kept if k in (("press-a = true",), ("press-b = true",))]
    assert len(one) == 1  # the first of the two the candidates list
    assert kept == sorted([(), one[0], *KEPT_OTHERS])


def test_a_model_without_a_scalar_step_falls_back_to_the_wave_search() -> None:
    """A POMDP has no scalar step (`ScalarUnsupported`): `engine=thts`
    runs the wave search there, and still plays."""
    model = load_pair(*ippc_files("IPPC2011", "SysAdmin", 1))  # an MDP: thts
    planner, _ = planner_on(model, iterations="2")
    assert planner.engine == "thts"
    pomdp = load_pair(*_pomdp_files())
    planner, sim = planner_on(pomdp, iterations="1")
    assert planner.engine == "wave"
    acts = planner.act(observe(sim, None, 1, 40, fluents=False))
    assert isinstance(acts, list)


def _pomdp_files() -> tuple[Path, Path]:
    from ..conftest import corpus_root

    folder = corpus_root() / "archive" / "competitions" / "IPPC2011" / "SysAdmin" / "POMDP"
    return folder / "domain.rddl", folder / "instance1.rddl"


def _play(options: dict[str, str], turns: int) -> tuple[list[list[str]], list[tuple[int, ...]]]:
    model = load_pair(*ippc_files("IPPC2011", "Elevators", 1))
    planner, sim = planner_on(model, **options)
    rng = np.random.default_rng(4)
    state = sim.initial_state(1)
    chosen: list[list[str]] = []
    counts: list[tuple[int, ...]] = []
    for turn in range(1, turns + 1):
        planner.act(observe(sim, state, turn))
        assert planner._last_action is not None
        chosen.append(sim.actions_to_names(planner._last_action))
        t = planner.last_turn
        counts.append((t.trials, t.leaves, t.sim_steps))
        state = sim.step(state, planner._last_action, rng).next_state
    return chosen, counts


@COMPILED
def test_the_same_seed_gives_the_same_search(compiled: str) -> None:
    """With `iterations` and a seed, two sessions search alike (the same
    trials, expansions and simulated steps) and choose alike; another seed
    searches otherwise."""
    options = {"iterations": "150", "seed": "11", "compiled": compiled}
    first = _play(options, 6)
    assert _play(options, 6) == first
    assert _play({**options, "seed": "12"}, 6)[1] != first[1]
