"""Shared by the ippc.gym tests: the test domain of every range, and the MDP
instances 1 of IPPC 2011, 2014, 2018 and 2023 in rddlrepository."""

from __future__ import annotations

from pathlib import Path

import pytest

from ..conftest import DATA

#: tests/data/gym/domain.rddl: a bool, an enum, an object, a bounded and an
#: unbounded int and a bounded real; preconditions, an invariant, termination
GYMTEST = DATA / "gym" / "domain.rddl"
#: the same domain with an observ-fluent (a POMDP)
GYMTEST_POMDP = DATA / "gym" / "pomdp.rddl"


def ippc_mdp_problems() -> list[str]:
    """The rddlrepository problems of the MDP tracks of IPPC 2011, 2014, 2018 and 2023."""
    from rddlrepository.core.manager import RDDLRepoManager

    names = RDDLRepoManager().list_problems()
    return [
        n
        for n in names
        if any(n.endswith(f"_ippc{y}") for y in (2011, 2014, 2018, 2023)) and "_POMDP_" not in n
    ]


@pytest.fixture
def gymtest() -> Path:
    return GYMTEST
