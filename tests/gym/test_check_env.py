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


#: the flat action space of each instance 1 of 2011, 2014 and 2018 (docs/gym.md's table);
#: every 2023 one is a Box but RecSim, whose 150 bools allow 2^40 joint actions (over the cap)
FLAT_ACTIONS = {
    "Discrete(5)": "CrossingTraffic_MDP_ippc2011 CrossingTraffic_MDP_ippc2014 "
    "Elevators_MDP_ippc2011 Elevators_MDP_ippc2014 Navigation_MDP_ippc2011 "
    "SkillTeaching_MDP_ippc2011 SkillTeaching_MDP_ippc2014",
    "Discrete(2)": "PushYourLuck_ippc2018",
    "Discrete(9)": "Tamarisk_MDP_ippc2014",
    "Discrete(10)": "GameOfLife_MDP_ippc2011",
    "Discrete(11)": "AcademicAdvising_MDP_ippc2014 SysAdmin_MDP_ippc2011",
    "Discrete(16)": "Traffic_CTM_MDP_ippc2011 Traffic_MDP_ippc2014",
    "Discrete(19)": "Wildfire_MDP_ippc2014",
    "Discrete(20)": "CooperativeRecon_MDP_ippc2011",
    "Discrete(44)": "TriangleTireworld_MDP_ippc2014",
    "MultiBinary(4)": "EarthObservation_ippc2018",
    "MultiBinary(15)": "AcademicAdvising_ippc2018",
    "MultiBinary(21)": "RedFinnedBlueEye_ippc2018",
    "MultiBinary(24)": "Manufacturer_ippc2018",
    "MultiBinary(29)": "ChromaticDice_ippc2018",
    "MultiBinary(48)": "CooperativeRecon_ippc2018",
    "MultiBinary(150)": "RecSim_ippc2023",
}


@pytest.mark.slow
@pytest.mark.parametrize("problem", ippc_mdp_problems())
def test_check_env_passes_on_the_flat_env_on_every_ippc_instance_1(problem: str) -> None:
    kind, warned = flat_checked(problem, "1")
    assert warned == []
    env = ippc.gym.FlatRDDLEnv(problem, "1")
    # the Discrete space wherever the constraints read no state and the actions are not real
    assert (kind == "discrete") == (env.flat.why_not_discrete == "")
    expected = next((s for s, names in FLAT_ACTIONS.items() if problem in names.split()), "box")
    assert (str(env.action_space) if kind != "box" else "box") == expected
