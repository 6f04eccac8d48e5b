"""The code for small and for large batches agree on the corpus: the first
instance of every rddlrepository domain (and the benchmark's), stepped
with both from the same states, actions and seed, give the same values
and make the same draws. Slow: marked, and run in CI by `make test`."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from ippc.rddl import load_pair
from ippc.rddl.simulator import SimulationError, Simulator

from ..conftest import corpus_pairs, corpus_root
from .test_corpus_sim import _expected, _rel
from .test_sim_compiler import compare_variants

pytestmark = pytest.mark.slow

BENCHMARK = {
    "competitions/IPPC2011/SysAdmin/MDP/instance10.rddl",
    "competitions/IPPC2011/GameOfLife/MDP/instance10.rddl",
    "competitions/IPPC2011/Elevators/MDP/instance10.rddl",
    "competitions/IPPC2011/CrossingTraffic/MDP/instance10.rddl",
    "competitions/IPPC2014/AcademicAdvising/MDP/instance10.rddl",
    "competitions/IPPC2011/Traffic/MDP/instance10.rddl",
    "competitions/IPPC2014/Wildfire/MDP/instance10.rddl",
    "competitions/IPPC2023/Reservoir/instance5.rddl",
    "competitions/IPPC2023/HVAC/instance5.rddl",
}


def _chosen() -> list[tuple[Path, Path]]:
    root = corpus_root()
    seen: set[Path] = set()
    out = []
    for domain, instance in corpus_pairs():
        assert root is not None
        rel = instance.relative_to(root / "archive").as_posix()
        if domain not in seen or rel in BENCHMARK:
            seen.add(domain)
            out.append((domain, instance))
    return out


PAIRS = _chosen()


@pytest.mark.parametrize(
    "pair", PAIRS, ids=[p[1].relative_to(p[1].parents[2]).as_posix() for p in PAIRS]
)
def test_variants_agree(pair: tuple[Path, Path]) -> None:
    logging.disable(logging.WARNING)
    try:
        expected = _expected(_rel(pair[1]))
        if expected is not None and expected[0] == "build":
            # not simulated (see test_corpus_sim's list): the refusal is what is tested
            with pytest.raises(SimulationError, match=expected[1]):
                Simulator(load_pair(*pair))
            return
        compare_variants(Simulator(load_pair(*pair)), batch=16, steps=4)
    finally:
        logging.disable(logging.NOTSET)
