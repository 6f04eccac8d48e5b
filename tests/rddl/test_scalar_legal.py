"""`ScalarStep.legal` (the preconditions and state-action constraints as a
function over the step's scalars) and its C translation (`CStep.legal`),
against the batched simulator's `check_actions`, on the corpus domains
with such constraints, over states of random walks and every enumerated
joint action (or a sample of them)."""

from __future__ import annotations

import numpy as np
import pytest
from ippc.planners.mcts.actions import enumerate_boolean
from ippc.rddl import load_pair
from ippc.rddl.sim.cstep import CStep, find_compiler
from ippc.rddl.sim.scalar import ScalarStep
from ippc.rddl.simulator import Simulator, State

from ..conftest import ippc_files

# (year, domain, whether some joint action within max-nondef-actions is illegal
# in the states of the walk: Elevators' and GameOfLife's constraints only
# repeat max-nondef-actions)
CONSTRAINED = [
    ("IPPC2011", "Elevators", False),
    ("IPPC2011", "GameOfLife", False),
    ("IPPC2018", "AcademicAdvising", True),
    ("IPPC2018", "EarthObservation", True),
    ("IPPC2018", "WildlifePreserve", True),
    ("IPPC2018", "PushYourLuck", True),
]


@pytest.mark.parametrize(("year", "domain", "some_illegal"), CONSTRAINED)
def test_legal_is_check_actions(year: str, domain: str, some_illegal: bool) -> None:
    sim = Simulator(load_pair(*ippc_files(year, domain, 1)))
    fast = ScalarStep(sim)
    assert fast.constrained and fast.legal is not None, fast.legal_error
    c = CStep(fast) if find_compiler() else None
    every = enumerate_boolean(sim, 100_000)
    assert every is not None
    n = next(iter(every.values())).shape[0]
    rng = np.random.default_rng(0)
    state = sim.initial_state(1)
    seen = {True: 0, False: 0}
    for _ in range(25):
        pick = rng.choice(n, min(n, 48), replace=False)
        acts = {k: v[pick] for k, v in every.items()}
        states = State({k: np.repeat(v, len(pick), axis=0) for k, v in state.values.items()})
        expected = sim.check_actions(states, acts)
        s = fast.encode_state(state)
        for j in range(len(pick)):
            a = fast.encode_actions(acts, j)
            assert fast.legal(s, a) == bool(expected[j]), (j, sim.actions_to_names(acts, j))
            if c is not None:
                assert c.legal(s, a) == bool(expected[j])
            seen[bool(expected[j])] += 1
        state = sim.step(state, sim.random_actions(state, rng), rng, check=False).next_state
    assert seen[True] and bool(seen[False]) == some_illegal


def test_an_unconstrained_model_has_no_legal_function() -> None:
    fast = ScalarStep(Simulator(load_pair(*ippc_files("IPPC2011", "SysAdmin", 1))))
    assert not fast.constrained and fast.legal is None and fast.legal_source is None
