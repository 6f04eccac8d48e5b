"""The example planner of docs/planners.md works: its code is taken from the page's
fenced block and run (legal actions, deterministic given the session seed)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from ippc.planners import Observation, Planner, PlannerError, SessionInfo, make_planner
from ippc.rddl import load
from ippc.rddl.simulator import Simulator
from ippc.rddl.wire import WireCodec

from ..docs import REPO, blocks


def _greedy_class() -> type[Planner]:
    """GreedyPlanner, defined by running the page's block that defines it."""
    text = (REPO / "docs" / "planners.md").read_text(encoding="utf-8")
    (block,) = [b for b in blocks(text) if b.lang == "python" and "class GreedyPlanner" in b.text]
    namespace: dict[str, object] = {"__name__": "docs_planners_example"}
    exec(compile(block.text, f"docs/planners.md:{block.line}", "exec"), namespace)
    cls = namespace["GreedyPlanner"]
    assert isinstance(cls, type) and issubclass(cls, Planner)
    return cls


GreedyPlanner = _greedy_class()


@pytest.mark.parametrize("name", ["print_jobs_inst_1", "elevators_inst_mdp__1"])
def test_greedy_example(rddlsim_rddl: Path, name: str) -> None:
    models = {**load(rddlsim_rddl), **load(REPO / "domains")}
    model = models[name]
    sim = Simulator(model)
    codec = WireCodec(sim)
    planner = GreedyPlanner(samples="4")
    planner.start_session(SessionInfo(name, model, sim, rounds=1, time_allowed=60.0, seed=1))
    state = sim.initial_state(1)
    rng = np.random.default_rng(0)
    for turn in range(1, 11):
        obs = Observation(None, state, turn, 41 - turn, 60.0, 0.0, time.monotonic() + 1)
        acts = planner.act(obs)
        decoded = codec.actions_from(acts)
        assert codec.check(state, decoded) is None
        state = sim.step(state, decoded.arrays, rng).next_state
    # a greedy planner is deterministic given the session seed
    again = GreedyPlanner(samples="4")
    again.start_session(SessionInfo(name, model, sim, rounds=1, time_allowed=60.0, seed=1))
    assert again.act(obs) == planner.act(obs)
    with pytest.raises(PlannerError, match="unknown planner 'greedy'"):
        make_planner("greedy", {})  # not registered: a package would declare the entry point
