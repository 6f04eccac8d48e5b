"""Every rddlrepository instance simulates: noop and rddlsim's random policy,
each to its horizon (two episodes each). Slow: marked, and run in CI by
`make test`; the whole file takes about 1.5 minutes of one core, the largest
instance (IPPC 2023 RecSim 5: 400,000 action groundings, a legality test
over all of them for each candidate action the random policy tries) about
15 s of that.

Where a domain forbids noop, or its dynamics break its own invariants, or it
uses what the simulator does not support, the instance is listed here with
the error the simulator gives, and the test asserts that error.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np
import pytest
from ippc.rddl import load_pair
from ippc.rddl.rollout import run_episodes
from ippc.rddl.simulator import SimulationError, Simulator

from ..conftest import corpus_pairs, corpus_root

pytestmark = pytest.mark.slow

# Folder (relative to the package) -> (policy that fails, error it must give).
NOOP_ILLEGAL = "constraint violated"
EXPECTED_FAILURES: dict[str, tuple[str, str]] = {
    # action preconditions that require an action every step
    "archive/arcade/Tetris": ("noop", NOOP_ILLEGAL),
    "archive/competitions/IPPC2018/ChromaticDice": ("noop", NOOP_ILLEGAL),
    "archive/competitions/IPPC2018/EarthObservation": ("noop", NOOP_ILLEGAL),
    "archive/competitions/IPPC2018/PushYourLuck": ("noop", NOOP_ILLEGAL),
    "archive/competitions/IPPC2018/WildlifePreserve": ("noop", NOOP_ILLEGAL),
    "archive/or/BinPacking": ("noop", NOOP_ILLEGAL),
    "archive/or/TSP": ("noop", NOOP_ILLEGAL),
    # doing nothing lets the pole fall past the angle the invariant allows
    "archive/gym/CartPole": ("noop", "state invariant violated"),
    # random moves (seed 0) put two people on one cell, which the invariant forbids
    "archive/rddlsim/Sidewalk/instance1.rddl": ("random", "state invariant violated"),
    # broken domain: @good gets probability 1 - 1 - 0.05 when every computer runs
    "archive/rddlsim/ComplexSysAdmin": ("noop", "Discrete has a negative probability"),
    # pyRDDLGym's matrix functions are not simulated
    "archive/or/Option": ("build", "MatrixOp is not supported"),
}

PAIRS = corpus_pairs()


def _rel(path: Path) -> str:
    root = corpus_root()
    assert root is not None
    return path.relative_to(root).as_posix()


def _expected(rel: str) -> tuple[str, str] | None:
    for folder, outcome in EXPECTED_FAILURES.items():
        if rel == folder or rel.startswith(folder + "/"):
            return outcome
    return None


@pytest.mark.parametrize("pair", PAIRS, ids=[_rel(p[1]) for p in PAIRS])
def test_instance_simulates(pair: tuple[Path, Path]) -> None:
    logging.disable(logging.WARNING)
    try:
        domain, instance = pair
        rel = _rel(instance)
        model = load_pair(domain, instance)
        expected = _expected(rel)
        failed: tuple[str, str] | None = None
        try:
            sim = Simulator(model)
        except SimulationError as err:
            failed = ("build", str(err))
        else:
            for policy in ("noop", "random"):
                try:
                    stats = run_episodes(model, policy, episodes=2, seed=0, simulator=sim)
                except SimulationError as err:
                    failed = (policy, str(err))
                    break
                assert np.isfinite(stats.returns).all(), (policy, stats.returns)
                # to the horizon, unless a termination condition ends it first
                assert model.horizon is not None
                if model.domain.termination:
                    assert 0 < stats.steps <= 2 * model.horizon
                else:
                    assert stats.steps == 2 * model.horizon, (policy, stats.steps)
        if expected is None:
            assert failed is None, failed
        else:
            assert failed is not None, f"expected {expected} but it ran"
            assert failed[0] == expected[0] and re.search(expected[1], failed[1]), failed
    finally:
        logging.disable(logging.NOTSET)


def test_expected_failure_folders_exist() -> None:
    rels = {_rel(p[1]) for p in PAIRS}
    for folder in EXPECTED_FAILURES:
        assert any(r == folder or r.startswith(folder + "/") for r in rels), folder
