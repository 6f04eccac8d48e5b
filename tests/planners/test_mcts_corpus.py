"""mcts plays every discrete MDP domain of rddlrepository without raising
(issue 35): instance 0 or 1 of each domain folder (IPPC or not), one round
of at most TURNS turns at 0.02 s a step, every action legal as the server
checks it and every reward finite.

Left out, with the reason the test reports: POMDPs (observ-fluents: this is
about the MDP search), domains with real-valued action fluents (mcts samples
those rddlsim-style; their search is not what this checks), folders with no
instance 0 or 1 (IPPC 2018 WildlifePreserve's p2 to p20 hold one instance
each of the domain whose instance 1 is in p1). One domain the simulator
refuses, as a language limit: archive/or/Option uses pyRDDLGym's matrix
operations, which are not RDDL (the test asserts that error).

Slow: 50 domains played (and Option refused), 59 left out (22 real-valued actions, 18 POMDPs, 19
folders without instance 0 or 1); 77 s of CPU, 14 min 20 s of wall time on
3 December 2026 at 18:51 UTC (2 shared cores, load average about 17), mostly
loading and compiling the larger domains.
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path

import numpy as np
import pytest
from ippc.planners.base import Observation, SessionInfo
from ippc.planners.mcts import MCTSPlanner
from ippc.rddl import load_pair
from ippc.rddl.simulator import SimulationError, Simulator
from ippc.rddl.wire import WireCodec

from ..conftest import corpus_root

pytestmark = pytest.mark.slow

TURNS = 10
"""Turns played of the round (the planner is told the instance's real steps left)."""

REFUSED = {"archive/or/Option": "MatrixOp is not supported"}
"""Folder -> the simulator's error: matrix operations (pyRDDLGym's, not RDDL)."""


def domains() -> list[tuple[str, Path, Path | None]]:
    root = corpus_root()
    out = []
    for dom in sorted(root.rglob("domain.rddl")):
        folder = dom.parent
        inst = next(
            (
                folder / f"instance{k}.rddl"
                for k in (0, 1)
                if (folder / f"instance{k}.rddl").exists()
            ),
            None,
        )
        out.append((folder.relative_to(root).as_posix(), dom, inst))
    return out


DOMAINS = domains()


@pytest.mark.parametrize(("rel", "dom", "inst"), DOMAINS, ids=[d[0] for d in DOMAINS])
def test_mcts_plays_a_round(rel: str, dom: Path, inst: Path | None) -> None:
    if inst is None:
        pytest.skip("no instance 0 or 1 in this folder")
    logging.disable(logging.WARNING)
    try:
        model = load_pair(dom, inst)
        if any(p.kind == "observ-fluent" for p in model.pvariables.values()):
            pytest.skip("POMDP")
        try:
            sim = Simulator(model)
        except SimulationError as err:
            assert rel in REFUSED and REFUSED[rel] in str(err)
            return
        assert rel not in REFUSED
        if any(p.range == "real" for p in sim.action_fluents):
            pytest.skip("real-valued action fluents")
        codec = WireCodec(sim)
        planner = MCTSPlanner(time_per_step="0.02", seed="0")
        planner.start_session(
            SessionInfo(model.name, model, sim, rounds=1, time_allowed=3600.0, seed=0)
        )
        planner.start_round(1)
        rng = np.random.default_rng(0)
        state = sim.initial_state(1)
        horizon = model.horizon or 1
        previous = total = 0.0
        played = 0
        for turn in range(1, min(horizon, TURNS) + 1):
            obs = Observation(
                {(n, a): v for n, a, v in codec.state(state)},
                state,
                turn,
                horizon - turn + 1,
                3600.0,
                previous,
                time.monotonic() + 5.0,
            )
            decoded = codec.actions_from(planner.act(obs))
            assert codec.check(state, decoded) is None, f"turn {turn}"
            step = sim.step(state, decoded.arrays, rng)
            previous = float(step.reward[0])
            assert math.isfinite(previous)
            total += previous
            played += 1
            state = step.next_state
            if step.done[0]:
                break
        planner.end_round(total)
        planner.end_session(total)
        assert played >= 1
    finally:
        logging.disable(logging.NOTSET)
