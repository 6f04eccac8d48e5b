"""LegalActions with groundings held at their default (`fixed`): the spaces are those
of the other groundings, so that a planner that leaves some groundings out draws its
samples among the joint actions it can use (TriangleTireworld: the car's own moves,
not thousands of moves along roads that do not exist)."""

from __future__ import annotations

import numpy as np
from ippc.rddl import load_pair
from ippc.rddl.legal import LegalActions
from ippc.rddl.sim.scalar import ScalarStep
from ippc.rddl.simulator import Simulator

from ..conftest import ippc_files


def _sets(sim: Simulator, arrays: dict[str, np.ndarray]) -> set[tuple[str, ...]]:
    n = next(iter(arrays.values())).shape[0]
    return {tuple(sorted(sim.actions_to_names(arrays, i))) for i in range(n)}


def test_fixed_groundings_stay_at_their_default_and_the_rest_is_whole() -> None:
    sim = Simulator(load_pair(*ippc_files("IPPC2014", "TriangleTireworld", 1)))
    inert = list(ScalarStep(sim).inert_actions)
    assert inert  # moves along roads that do not exist
    free = LegalActions(sim)
    held = LegalActions(sim, fixed=inert)
    state = sim.initial_state(1)
    everything = _sets(sim, free.enumerate(state))
    kept = _sets(sim, held.enumerate(state))
    inert_names = {sim.actions_to_names(_one(sim, name, idx), 0)[0] for name, idx in inert}
    # exactly the legal joint actions that set no inert grounding
    assert kept == {a for a in everything if not set(a) & inert_names}
    assert () in kept and len(kept) < len(everything)
    # a small sample is drawn among those alone, and holds every one of them when it may
    rng = np.random.default_rng(3)
    sample = _sets(sim, held.candidates(state, rng, 4, 0))
    assert sample <= kept and () in sample and len(sample) == min(4, len(kept))
    assert _sets(sim, held.candidates(state, rng, len(kept), 0)) == kept


def _one(sim: Simulator, name: str, idx: tuple[int, ...]) -> dict[str, np.ndarray]:
    acts = sim.noop(1)
    acts[name][(0, *idx)] = True
    return acts
