"""Gymnasium's own checker (`gymnasium.utils.env_checker.check_env`) passes on
ippc.gym's environment, and on its flat one (`FlatRDDLEnv`), for every MDP
instance 1 of IPPC 2011, 2014, 2018 and 2023 (a sample here, the sweeps marked
slow), made through `gymnasium.make` so that it checks the 'ansi' render mode
and closing too."""

from __future__ import annotations

import warnings

import gymnasium
import ippc.gym  # registers ippc/RDDL-v0 and ippc/RDDLFlat-v0
import pytest
from gymnasium.utils.env_checker import check_env

from .conftest import GYMTEST, GYMTEST_POMDP, ippc_mdp_problems

#: one instance per year, and the domains whose noop is illegal
SAMPLE = [
    "SysAdmin_MDP_ippc2011",
    "AcademicAdvising_MDP_ippc2014",
    "ChromaticDice_ippc2018",
    "Reservoir_ippc2023",
]


def checked(domain: object, instance: object, env_id: str = ippc.gym.ENV_ID) -> list[str]:
    """Run check_env; the warnings it gives (the API breaches it does not fail on)."""
    env = gymnasium.make(env_id, domain=domain, instance=instance, render_mode="ansi")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    # unbounded Box spaces draw a warning; they are what the domain declares
    return [
        str(w.message)
        for w in caught
        if "infinity" not in str(w.message) and "symmetric and normalized" not in str(w.message)
    ]


def test_all_ippc_years_are_in_the_corpus() -> None:
    problems = ippc_mdp_problems()
    for year in (2011, 2014, 2018, 2023):
        assert sum(p.endswith(f"_ippc{year}") for p in problems) >= 5, year
    assert set(SAMPLE) <= set(problems)


@pytest.mark.parametrize("problem", SAMPLE)
def test_check_env_passes_on_a_sample(problem: str) -> None:
    assert checked(problem, "1") == []


@pytest.mark.parametrize("path", [GYMTEST, GYMTEST_POMDP], ids=["every-range", "pomdp"])
def test_check_env_passes_on_the_test_domains(path: object) -> None:
    assert checked(path, None) == []


@pytest.mark.slow
@pytest.mark.parametrize("problem", ippc_mdp_problems())
def test_check_env_passes_on_every_ippc_instance_1(problem: str) -> None:
    assert checked(problem, "1") == []


#: the flat environment's sample: a Discrete action space over several non-default
#: actions (Traffic), MultiBinary where the constraints read the state
#: (ChromaticDice, whose noop is illegal in some phases), Box with real actions
FLAT_SAMPLE = [
    "SysAdmin_MDP_ippc2011",
    "Traffic_MDP_ippc2014",
    "ChromaticDice_ippc2018",
    "Reservoir_ippc2023",
]


def flat_checked(problem: object, instance: object) -> tuple[str, list[str]]:
    """check_env on FlatRDDLEnv: its action space's kind and the warnings."""
    warned = checked(problem, instance, ippc.gym.FLAT_ENV_ID)
    env = ippc.gym.FlatRDDLEnv(problem, instance)  # type: ignore[arg-type]
    return env.flat.kind, warned


@pytest.mark.parametrize("problem", FLAT_SAMPLE)
def test_check_env_passes_on_the_flat_env_on_a_sample(problem: str) -> None:
    kind, warned = flat_checked(problem, "1")
    assert warned == []
    assert kind == {"ChromaticDice_ippc2018": "multibinary", "Reservoir_ippc2023": "box"}.get(
        problem, "discrete"
    )


@pytest.mark.parametrize("path", [GYMTEST, GYMTEST_POMDP], ids=["every-range", "pomdp"])
def test_check_env_passes_on_the_flat_env_on_the_test_domains(path: object) -> None:
    # every-range has a real action (Box); the POMDP's actions are bools and an int
    assert flat_checked(path, None) == ("box" if path == GYMTEST else "discrete", [])


@pytest.mark.slow
@pytest.mark.parametrize("problem", ippc_mdp_problems())
def test_check_env_passes_on_the_flat_env_on_every_ippc_instance_1(problem: str) -> None:
    kind, warned = flat_checked(problem, "1")
    assert warned == []
    # the Discrete space wherever the constraints read no state and the actions are not real
    env = ippc.gym.FlatRDDLEnv(problem, "1")
    assert (kind == "discrete") == (env.flat.why_not_discrete == "")
