"""`mcts`'s thts engine in C (option `compiled`; the step in
`rddl/sim/cstep.py`, the search in planners/mcts/csrc): the option's values,
the wave engine where no C step can be built (a failing or missing compiler)
or `compiled=no`, and the session failing instead with `compiled=yes`; then
the C tree where the candidates depend on the state (tiny_gated: the
chooser's candidates through a callback, IDS through it too) and on
tiny_trap: values against `exact`'s, the exact last step, equivalent
actions against the Python reference (tests/planners/thts_reference.py),
the same search for the same seed. (tests/conftest.py points IPPC_CACHE at
the run's temporary folder.)"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ippc.planners import PlannerError, SessionInfo
from ippc.planners.exact import solve
from ippc.planners.mcts import MCTSPlanner
from ippc.rddl import Model, load_model, load_pair
from ippc.rddl.sim.cstep import find_compiler
from ippc.rddl.simulator import Simulator

from ..conftest import ippc_files
from . import test_mcts_search
from .test_mcts import observe
from .test_mcts_thts import EQUIVALENT, KEPT_OTHERS, names, planner_on, root_of

models = test_mcts_search.models  # the tiny domains (a fixture)

needs_cc = pytest.mark.skipif(find_compiler() is None, reason="no C compiler")


def sysadmin() -> Model:
    return load_pair(*ippc_files("IPPC2011", "SysAdmin", 1))


@needs_cc
@pytest.mark.parametrize(
    "value,compiled", [("yes", True), ("auto", True), ("on", True), ("no", False), ("off", False)]
)
def test_the_option_picks_the_engine(value: str, compiled: bool) -> None:
    """yes (on) and auto: the search in C; no (off): the wave engine."""
    model = sysadmin()
    planner = start(model, compiled=value, iterations="20", seed="1")
    sim = Simulator(model)
    planner.start_round(1)
    assert planner.engine == ("thts" if compiled else "wave")
    assert planner.compiled is compiled
    assert (planner._thts is not None) is compiled
    if compiled:
        assert planner._thts is not None and planner._thts.tree is not None
    acts = planner.act(observe(sim, sim.initial_state(1), 1))
    assert isinstance(acts, list)
    assert (planner.last_turn.trials if compiled else planner.last_turn.waves) == 20


def test_a_bad_value_is_an_option_error() -> None:
    with pytest.raises(PlannerError, match="option 'compiled' must be one of auto, yes, no"):
        MCTSPlanner(compiled="bad")


def start(model: Model, **options: str) -> MCTSPlanner:
    planner = MCTSPlanner(engine="thts", **options)
    planner.start_session(
        SessionInfo(model.name, model, Simulator(model), rounds=1, time_allowed=60.0, seed=1)
    )
    return planner


@pytest.mark.parametrize("broken", ["failing", "missing"])
def test_without_a_c_step_auto_falls_back_and_yes_fails(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
    broken: str,
) -> None:
    """CC=false (every build fails) or CC naming no program, with an empty
    cache: `compiled=auto` runs the wave engine (and plays), with a warning
    naming why; `compiled=yes` fails the session's start naming why;
    `compiled=no` never asks."""
    monkeypatch.setenv("IPPC_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("CC", "false" if broken == "failing" else str(tmp_path / "no-cc"))
    why = "false failed" if broken == "failing" else "no C compiler"
    model = sysadmin()
    with caplog.at_level("WARNING", logger="ippc.planners.mcts.planner"):
        planner = start(model, compiled="auto", iterations="20")
    assert planner.engine == "wave" and planner.compiled is False and planner._thts is None
    assert f"no C step ({why}" in caplog.text and "the wave engine" in caplog.text
    sim = Simulator(model)
    planner.start_round(1)
    assert isinstance(planner.act(observe(sim, sim.initial_state(1), 1)), list)
    assert planner.last_turn.waves == 20
    with pytest.raises(PlannerError, match=f"compiled=yes, but no C step: {why}"):
        start(model, compiled="yes", iterations="20")
    assert start(model, compiled="no", iterations="20").compiled is False


# work pays 3 but may tire (p 0.5); a tired worker may not work (a
# precondition that reads the state: the candidates depend on the state, so
# the C tree asks the chooser through a callback); rest recovers with p 0.8
GATED = """
domain tiny_gated {
    requirements = { concurrent, preconditions };
    pvariables {
        tired : { state-fluent, bool, default = false };
        work : { action-fluent, bool, default = false };
        rest : { action-fluent, bool, default = false };
    };
    cpfs {
        tired' = if (work) then Bernoulli(0.5)
                 else if (rest) then (tired ^ Bernoulli(0.2))
                 else tired;
    };
    reward = 3.0 * work + 0.5 * rest;
    action-preconditions {
        work => ~tired;
    };
}
instance tiny_gated_inst {
    domain = tiny_gated;
    init-state { tired = false; };
    max-nondef-actions = 1;
    horizon = 8;
    discount = 1.0;
}
"""


@pytest.fixture(scope="module")
def gated(tmp_path_factory: pytest.TempPathFactory) -> Model:
    f = tmp_path_factory.mktemp("gated") / "gated.rddl"
    f.write_text(GATED)
    return load_model(f)


def check_root_values(model: Model, steps_left: int, **options: str) -> None:
    """After 3000 trials every root action's value is near its exact
    expected return (as test_mcts_thts's test), and the best is chosen."""
    exact = solve(model)
    planner, sim = planner_on(model, iterations="3000", seed="2", compiled="yes", **options)
    state = sim.initial_state(1)
    horizon = model.horizon or 10
    planner.act(observe(sim, state, horizon + 1 - steps_left, steps_left))
    root = root_of(planner, state, steps_left)
    assert planner.library is not None
    q_exact = exact.q[steps_left][exact.index(state)]
    for row, q, n in zip(root.rows, root.q, root.n, strict=True):
        act = planner.library.take(np.array([row]))
        expected = float(q_exact[exact.action_index(act)])
        tol = 0.5 + (0.05 if n >= 300 else 0.2) * 20 * steps_left
        assert q == pytest.approx(expected, abs=tol), (names(planner, sim, row), root.q, root.n)
    chosen = planner.library.take(np.array([root.rows[int(np.argmax(root.q))]]))
    assert exact.action_index(chosen) == int(np.argmax(q_exact))


@needs_cc
@pytest.mark.parametrize("heuristic", ["rollout", "ids"])
@pytest.mark.parametrize("steps_left", [2, 5])
def test_c_tree_values_near_exact(
    models: dict[str, Model], gated: Model, heuristic: str, steps_left: int
) -> None:
    """tiny_trap and tiny_gated (state-dependent candidates: IDS's
    recursion and each node's probes over the chooser's candidates of its
    state, through the callback)."""
    check_root_values(models["tiny_trap_inst"], steps_left, heuristic=heuristic)
    check_root_values(gated, steps_left, heuristic=heuristic)


@needs_cc
def test_c_tree_last_step_and_pruning_as_the_reference(
    models: dict[str, Model], gated: Model, tmp_path: Path
) -> None:
    """The last step's values are the rewards, solved at once; a tired
    worker's root has no `work`; of press-a and press-b one is kept, with
    the others and noop (KEPT_OTHERS), as with the Python reference."""
    planner, sim = planner_on(models["tiny_trap_inst"], iterations="50", compiled="yes")
    state = sim.initial_state(1)
    planner.act(observe(sim, state, 10, 1))
    root = root_of(planner, state, 1)
    assert root.solved and planner.last_turn.trials == 0
    values = {tuple(names(planner, sim, r)): q for r, q in zip(root.rows, root.q, strict=True)}
    assert values == {(): 0.0, ("safe = true",): 5.0, ("risky = true",): 6.0}

    planner, sim = planner_on(gated, iterations="100", compiled="yes")
    tired = sim.initial_state(1)
    tired.values["tired"][0] = True
    planner.act(observe(sim, tired, 1, 8))
    kept = sorted(tuple(names(planner, sim, r)) for r in root_of(planner, tired, 8).rows)
    assert kept == [(), ("rest = true",)]

    (tmp_path / "equivalent.rddl").write_text(EQUIVALENT)
    model = load_model(tmp_path / "equivalent.rddl")
    found = {}
    for compiled in ("yes", "no"):
        planner, sim = planner_on(model, iterations="200", seed="3", compiled=compiled)
        state = sim.initial_state(1)
        planner.act(observe(sim, state, 1, 5))
        node = root_of(planner, state, 5)
        found[compiled] = sorted(tuple(names(planner, sim, r)) for r in node.rows)
    assert found["yes"] == found["no"]
    one = [k for k in found["yes"] if k in (("press-a = true",), ("press-b = true",))]
    assert len(one) == 1
    assert found["yes"] == sorted([(), one[0], *KEPT_OTHERS])


def _play(model: Model, options: dict[str, str], turns: int) -> tuple[list[Any], list[Any]]:
    planner, sim = planner_on(model, **options)
    assert planner._thts is not None and planner._thts.tree is not None
    rng = np.random.default_rng(4)
    state = sim.initial_state(1)
    chosen: list[list[str]] = []
    counts: list[tuple[int, ...]] = []
    for turn in range(1, turns + 1):
        planner.act(observe(sim, state, turn))
        assert planner._last_action is not None
        chosen.append(sim.actions_to_names(planner._last_action))
        t = planner.last_turn
        # (the root's values too: this domain's counts alone hardly vary)
        root = root_of(planner, state, (model.horizon or 1) - turn + 1)
        counts.append((t.trials, t.leaves, t.ids_leaves, t.sim_steps, *root.q))
        state = sim.step(state, planner._last_action, rng).next_state
    return chosen, counts


@needs_cc
@pytest.mark.parametrize("heuristic", ["rollout", "ids"])
def test_the_same_seed_gives_the_same_search_with_state_dependent_candidates(
    gated: Model, heuristic: str
) -> None:
    """With `iterations` and a seed, two sessions of the C tree search alike (the same trials, expansions and simulated
    steps, the same root values: the C generator is seeded from the
    search's) and choose alike; another seed searches otherwise."""
    options = {"iterations": "60", "seed": "11", "compiled": "yes", "heuristic": heuristic}
    first = _play(gated, options, 5)
    assert all(c[0] <= 60 for c in first[1]) and first[1][0][0] == 60
    assert _play(gated, options, 5) == first
    assert _play(gated, {**options, "seed": "12"}, 5)[1] != first[1]
