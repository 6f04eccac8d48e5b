"""ippc.gym.RDDLEnv: spaces from the model, the episode's semantics (horizon,
termination, reward), illegal actions, seeding, rendering, registration."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from gymnasium import spaces
from ippc.gym import ENV_ID, IllegalActionError, RDDLEnv, RDDLVectorEnv, grounded_name
from ippc.rddl import RDDLError, load_model
from ippc.rddl.simulator import Simulator

from ..conftest import DATA
from .conftest import GYMTEST, GYMTEST_POMDP


def test_grounded_names_are_pyrddlgyms() -> None:
    assert grounded_name("running", ("c1",)) == "running___c1"
    assert grounded_name("at", ("e0", "f1")) == "at___e0__f1"
    assert grounded_name("taken", ("@chance",)) == "taken___chance"
    assert grounded_name("move", ()) == "move"


def test_each_range_maps_to_its_space() -> None:
    env = RDDLEnv(GYMTEST)
    obs, act = env.observation_space, env.action_space
    assert list(obs.spaces) == [
        "at",
        "lit___c1",
        "lit___c2",
        "lit___c3",
        "gear",
        "fuel",
        "odometer",
        "heat",
    ]
    assert obs["at"] == spaces.Discrete(3)  # an object: its index among c1, c2, c3
    assert obs["lit___c2"] == spaces.Discrete(2)
    assert obs["gear"] == spaces.Discrete(2)  # an enum: @slow, @fast
    assert obs["fuel"] == spaces.Discrete(101)  # 0 <= fuel <= 100 (the invariant)
    lo, hi = np.iinfo(np.int32).min, np.iinfo(np.int32).max
    assert obs["odometer"] == spaces.Box(lo, hi, (), np.int64)  # an int without bounds
    assert obs["heat"] == spaces.Box(-np.inf, np.inf, (), np.float64)
    assert act["speed"] == spaces.Box(0.0, 2.5, (), np.float64)  # MAX-SPEED, a non-fluent
    assert act["refuel"] == spaces.Discrete(4)  # 0 <= refuel <= 3
    assert act["shift"] == spaces.Discrete(2)


def test_strict_and_flipped_comparisons_bound_by_the_next_integer(tmp_path) -> None:
    text = GYMTEST.read_text().replace(
        "refuel >= 0 ^ refuel <= 3;", "0 < refuel ^ refuel < 3 ^ refuel <= 9;"
    )
    (tmp_path / "d.rddl").write_text(text)
    env = RDDLEnv(tmp_path / "d.rddl")
    assert env.action_space["refuel"] == spaces.Discrete(2, start=1)


def test_the_observation_is_the_state_as_the_simulator_holds_it() -> None:
    env = RDDLEnv(GYMTEST)
    obs, info = env.reset(seed=3)
    assert info == {}
    assert obs["at"] == 0 and obs["fuel"] == 5 and obs["gear"] == 0
    obs, reward, terminated, truncated, info = env.step({"move": 1, "shift": 1, "refuel": 2})
    assert obs["at"] == 1 and obs["fuel"] == 6 and obs["gear"] == 1
    assert int(obs["odometer"]) == 1 and obs["odometer"].shape == ()
    assert info == {"illegal_action": False}
    assert obs in env.observation_space


def test_the_reward_is_the_simulators_with_the_same_draws() -> None:
    env = RDDLEnv(GYMTEST)
    env.reset(seed=11)
    sim = Simulator(load_model(GYMTEST))
    rng = np.random.default_rng(11)  # what reset(seed=11) seeds np_random with
    state = sim.initial_state(1)
    for _ in range(4):
        out = sim.step(state, sim.actions_from_names({("speed", ()): 1.0}), rng)
        _, reward, *_ = env.step({"speed": 1.0})
        assert reward == float(out.reward[0])
        state = out.next_state
    assert env.state.values["heat"][0] == state.values["heat"][0]


def test_the_horizon_truncates_and_a_terminal_state_terminates() -> None:
    env = RDDLEnv(GYMTEST)
    env.reset(seed=0)
    ends = [env.step({})[2:4] for _ in range(6)]
    assert ends == [(False, False)] * 5 + [(False, True)]  # horizon 6
    env.reset(seed=0)
    assert env.step({"move": 1})[2:4] == (False, False)  # c1 -> c2
    assert env.step({"move": 1})[2:4] == (True, False)  # c3 is terminal


def test_an_illegal_action_steps_noop_and_says_so() -> None:
    env = RDDLEnv(GYMTEST)
    env.reset(seed=0)
    # light(c3) is forbidden (GOAL(c3)); noop is stepped instead
    obs, _, _, _, info = env.step({"light___c3": 1, "move": 1})
    assert info == {"illegal_action": True}
    assert obs["at"] == 0 and obs["lit___c3"] == 0
    # four non-default actions, max-nondef-actions is 3
    obs, _, _, _, info = env.step({"light___c1": 1, "light___c2": 1, "move": 1, "shift": 1})
    assert info == {"illegal_action": True} and obs["lit___c1"] == 0
    obs, _, _, _, info = env.step({"light___c1": 1, "light___c2": 1, "move": 1})
    assert info == {"illegal_action": False} and obs["lit___c1"] == 1


def test_an_illegal_action_can_raise_naming_the_constraint() -> None:
    env = RDDLEnv(GYMTEST, illegal_actions="raise")
    env.reset(seed=0)
    with pytest.raises(IllegalActionError, match=r"domain\.rddl:37:9: constraint violated.*GOAL"):
        env.step({"light___c3": 1})
    with pytest.raises(IllegalActionError, match="max-nondef-actions is 3"):
        env.step({"light___c1": 1, "light___c2": 1, "move": 1, "shift": 1})


def test_an_illegal_action_can_end_the_episode() -> None:
    env = RDDLEnv(GYMTEST, illegal_actions="end")
    env.reset(seed=0)
    env.step({"move": 1})
    obs, reward, terminated, truncated, info = env.step({"speed": 9.0})
    assert (reward, terminated, truncated, info) == (0.0, False, True, {"illegal_action": True})
    assert obs["at"] == 1  # the state the episode ended in


def test_where_noop_is_illegal_a_legal_action_is_drawn() -> None:
    # ChromaticDice rolls all five dice in its roll phases: noop is illegal there
    env = RDDLEnv("ChromaticDice_ippc2018", "1")
    env.reset(seed=0)
    _, _, _, _, info = env.step({})
    assert info == {"illegal_action": True}
    assert env.state.values["die-value"].shape == (1, 5)
    with pytest.raises(IllegalActionError, match="constraint violated"):
        RDDLEnv("ChromaticDice_ippc2018", "1", illegal_actions="raise").step({})


def test_malformed_actions_are_value_errors() -> None:
    env = RDDLEnv(GYMTEST)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="unknown action 'jump'"):
        env.step({"jump": 1})
    with pytest.raises(ValueError, match=r"'move': 2 is not in Discrete\(2\)"):
        env.step({"move": 2})
    with pytest.raises(ValueError, match=r"'refuel': 0.5 is not in Discrete\(4\)"):
        env.step({"refuel": 0.5})
    with pytest.raises(ValueError, match="'speed'"):
        env.step({"speed": float("nan")})
    with pytest.raises(ValueError, match="a dict of grounded action names"):
        env.step([1, 0])  # type: ignore[arg-type]


def test_seeds_reproduce_trajectories() -> None:
    def run(seed: int) -> list[float]:
        env = RDDLEnv("SysAdmin_MDP_ippc2011", "1")
        env.reset(seed=seed)
        env.action_space.seed(seed)
        return [float(env.step(env.action_space.sample())[1]) for _ in range(40)]

    assert run(4) == run(4)
    assert run(4) != run(5)


def test_a_pomdp_observes_its_observ_fluents() -> None:
    env = RDDLEnv(GYMTEST_POMDP)
    assert list(env.observation_space.spaces) == ["seen", "noise"]
    obs, _ = env.reset(seed=2)
    assert obs == {"seen": 0, "noise": np.array(0.0)}  # their defaults before the first step
    seen = set()
    for _ in range(30):
        obs, reward, _, truncated, _ = env.step({"flip": 1})
        assert obs["seen"] == int(env.state.values["coin"][0] == 0)
        seen.add(obs["seen"])
        if truncated:
            env.reset()
    assert seen == {0, 1}


def test_render_ansi_shows_the_state() -> None:
    env = RDDLEnv(GYMTEST, render_mode="ansi")
    env.reset(seed=0)
    env.step({"move": 1, "light___c1": 1})
    text = env.render()
    assert text is not None
    lines = text.splitlines()
    assert lines[0].startswith("gymtest_inst_1  step 1/6  reward ")
    assert "  at = c2" in lines and "  lit(c1) = true" in lines and "  gear = @slow" in lines
    with pytest.warns(UserWarning, match="without a render_mode"):
        assert RDDLEnv(GYMTEST).render() is None


def test_instances_by_file_folder_and_repository_name(tmp_path) -> None:
    assert RDDLEnv(GYMTEST).model.name == "gymtest_inst_1"
    assert RDDLEnv(DATA / "gym", "gympomdp_inst_1").model.name == "gympomdp_inst_1"
    env = RDDLEnv("SysAdmin_MDP_ippc2011", "10")
    assert env.model.name == "sysadmin_inst_mdp__10" and len(env.action_space.spaces) == 50
    with pytest.raises(ValueError, match="has no instance 99"):
        RDDLEnv("SysAdmin_MDP_ippc2011", "99")
    with pytest.raises(ValueError, match="did you mean SysAdmin_MDP_ippc2011"):
        RDDLEnv("SysAdmin_MDP_ippc201")
    with pytest.raises(FileNotFoundError):
        RDDLEnv(tmp_path / "missing.rddl")
    (tmp_path / "bad.rddl").write_text(GYMTEST.read_text().replace("fuel - 1", "fuel - q"))
    with pytest.raises(RDDLError, match="bad.rddl:"):
        RDDLEnv(tmp_path / "bad.rddl")


def test_registered_for_make_and_make_vec() -> None:
    assert ENV_ID == "ippc/RDDL-v0"
    env = gymnasium.make(ENV_ID, domain="SysAdmin_MDP_ippc2011", instance="1")
    assert isinstance(env.unwrapped, RDDLEnv)
    env.reset(seed=0)
    envs = gymnasium.make_vec(
        ENV_ID,
        num_envs=3,
        vectorization_mode="vector_entry_point",
        domain="SysAdmin_MDP_ippc2011",
        instance="1",
    )
    assert isinstance(envs, RDDLVectorEnv) and envs.num_envs == 3
    obs, _ = envs.reset(seed=0)
    assert obs["running___c1"].shape == (3,)
