"""ippc.gym's flat spaces (`FlatRDDLEnv`, `FlatSpaces`): a Box observation in the
Dict's key order, a Discrete action over the legal joint actions where the
constraints read no state (noop first), MultiBinary or Box otherwise, and what
an illegal or malformed flat action does."""

from __future__ import annotations

import subprocess
import sys

import gymnasium
import numpy as np
import pytest
from ippc.gym import FLAT_ENV_ID, FlatRDDLEnv, RDDLEnv

from .conftest import GYMTEST, GYMTEST_POMDP


def test_sysadmin_is_noop_or_one_reboot() -> None:
    env = FlatRDDLEnv("SysAdmin_MDP_ippc2011", "1")
    assert env.action_space == gymnasium.spaces.Discrete(11)
    assert env.flat.kind == "discrete" and env.flat.why_not_discrete == ""
    # noop first, then each single reboot in key order (max-nondef-actions = 1)
    # (a Discrete index's Dict action holds its non-default values only)
    assert env.flat.action(0) == {}
    for i in range(1, 11):
        assert env.flat.action(i) == {f"reboot___c{i}": 1}
    assert env.observation_space.shape == (10,) and env.observation_space.dtype == np.float32


def test_flat_steps_are_the_dict_steps() -> None:
    """Each index steps the joint action it stands for: same observations and rewards
    as the Dict environment given that action, with the same seed."""
    flat = FlatRDDLEnv("SysAdmin_MDP_ippc2011", "1")
    plain = RDDLEnv("SysAdmin_MDP_ippc2011", "1")
    obs, _ = flat.reset(seed=3)
    dobs, _ = plain.reset(seed=3)
    assert obs.tolist() == [float(dobs[k]) for k in plain.observation_space.spaces]
    rng = np.random.default_rng(0)
    for _ in range(plain.horizon):
        i = int(rng.integers(11))
        obs, reward, terminated, truncated, info = flat.step(i)
        dobs, dreward, dterm, dtrunc, dinfo = plain.step(flat.flat.action(i))
        assert obs.tolist() == [float(dobs[k]) for k in plain.observation_space.spaces]
        assert (reward, terminated, truncated, info) == (dreward, dterm, dtrunc, dinfo)
        assert info == {"illegal_action": False}
    assert truncated


def test_every_combination_within_max_nondef() -> None:
    # Traffic 2014: four bool actions, max-nondef-actions 4: all 16 subsets
    env = FlatRDDLEnv("Traffic_MDP_ippc2014", "1")
    assert env.action_space == gymnasium.spaces.Discrete(16)
    # noop, the four singles, the six pairs, the four triples, all four; in key order
    keys = list(env.env.action_space.spaces)
    on = [tuple(keys.index(k) for k, v in env.flat.action(i).items() if v) for i in range(16)]
    assert on == [(), (0,), (1,), (2,), (3,), (0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)] + [
        (0, 1, 2),
        (0, 1, 3),
        (0, 2, 3),
        (1, 2, 3),
        (0, 1, 2, 3),
    ]
    assert env.action_masks().tolist() == [True] * 16


def test_the_size_cap() -> None:
    env = FlatRDDLEnv("Traffic_MDP_ippc2014", "1", max_actions=8)
    assert env.action_space == gymnasium.spaces.MultiBinary(4)
    assert "16 legal joint actions, more than max_actions=8" in env.flat.why_not_discrete
    with pytest.raises(ValueError, match="more than max_actions=8"):
        FlatRDDLEnv("Traffic_MDP_ippc2014", "1", actions="discrete", max_actions=8)


def test_state_dependent_constraints_give_multibinary() -> None:
    env = FlatRDDLEnv("ChromaticDice_ippc2018", "1")
    assert env.action_space == gymnasium.spaces.MultiBinary(29)
    assert "depend on the state" in env.flat.why_not_discrete
    assert "current-phase" in env.flat.why_not_discrete
    with pytest.raises(TypeError, match="Discrete"):
        env.action_masks()
    with pytest.raises(ValueError, match="depend on the state"):
        FlatRDDLEnv("ChromaticDice_ippc2018", "1", actions="discrete")


def test_an_illegal_multibinary_action_is_replaced_and_reported() -> None:
    # SysAdmin with MultiBinary: two reboots break max-nondef-actions = 1
    env = FlatRDDLEnv("SysAdmin_MDP_ippc2011", "1", actions="multibinary")
    noop = FlatRDDLEnv("SysAdmin_MDP_ippc2011", "1")
    env.reset(seed=5)
    noop.reset(seed=5)
    two = np.zeros(10, dtype=np.int8)
    two[[0, 4]] = 1
    obs, reward, _, _, info = env.step(two)
    nobs, nreward, _, _, _ = noop.step(0)
    assert info == {"illegal_action": True}
    assert obs.tolist() == nobs.tolist() and reward == nreward
    one = np.zeros(10, dtype=np.int8)
    one[3] = 1
    assert env.step(one)[4] == {"illegal_action": False}
    with pytest.raises(ValueError, match="other than 0 and 1"):
        env.step(np.full(10, 0.5))
    strict = FlatRDDLEnv(
        "SysAdmin_MDP_ippc2011", "1", actions="multibinary", illegal_actions="raise"
    )
    strict.reset(seed=0)
    with pytest.raises(Exception, match="max-nondef-actions"):
        strict.step(two)


def test_box_actions_are_rounded_clipped_and_checked() -> None:
    env = FlatRDDLEnv(GYMTEST)
    # move, light c1..c3, shift, speed (real, 0..2.5), refuel (int, 0..3)
    assert env.flat.kind == "box"
    assert env.action_space.low.tolist() == [0, 0, 0, 0, 0, 0, 0]
    assert env.action_space.high.tolist() == [1, 1, 1, 1, 1, 2.5, 3]
    assert env.flat.action([0.4, 0.6, 0, 0, 1.2, 9.0, 2.6]) == {
        "move": 0,
        "light___c1": 1,
        "light___c2": 0,
        "light___c3": 0,
        "shift": 1,
        "speed": 2.5,
        "refuel": 3,
    }
    env.reset(seed=0)
    # light c3 breaks a precondition (GOAL(c3)): reported, noop stepped
    assert env.step([0, 0, 0, 1, 0, 0, 0])[4] == {"illegal_action": True}
    assert env.step([1, 1, 0, 0, 0, 0, 0])[4] == {"illegal_action": False}
    with pytest.raises(ValueError, match="NaN"):
        env.step([np.nan, 0, 0, 0, 0, 0, 0])
    with pytest.raises(ValueError, match=r"shape \(7,\)"):
        env.step([0, 0])


def test_discrete_actions_are_checked() -> None:
    env = FlatRDDLEnv("SysAdmin_MDP_ippc2011", "1")
    env.reset(seed=0)
    for bad in (11, -1, 2.5, [1, 2], "a"):
        with pytest.raises(ValueError, match=r"Discrete\(11\)"):
            env.step(bad)
    assert env.step(np.int64(2))[4] == {"illegal_action": False}
    assert env.step(np.array([3]))[4] == {"illegal_action": False}


def test_observations_follow_the_dict_and_its_bounds() -> None:
    env = FlatRDDLEnv(GYMTEST)
    dict_space = env.env.observation_space
    assert env.flat.obs_keys == list(dict_space.spaces)
    # at (object of 3), lit c1..c3, gear (enum of 2), fuel (0..100), odometer, heat
    assert env.observation_space.low[:6].tolist() == [0, 0, 0, 0, 0, 0]
    assert env.observation_space.high[:6].tolist() == [2, 1, 1, 1, 1, 100]
    assert env.observation_space.high[7] == np.inf
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    obs, *_ = env.step([1, 1, 0, 0, 0, 0, 0])
    assert obs[:2].tolist() == [1.0, 1.0]  # at c2, lit c1


def test_a_pomdp_observes_its_observ_fluents_flat() -> None:
    env = FlatRDDLEnv(GYMTEST_POMDP)
    assert env.flat.obs_keys == list(env.env.observation_space.spaces)
    obs, _ = env.reset(seed=0)
    assert obs.shape == env.observation_space.shape and env.observation_space.contains(obs)


def test_made_through_gymnasium_and_wrapping_an_env() -> None:
    env = gymnasium.make(FLAT_ENV_ID, domain="CrossingTraffic_MDP_ippc2011", instance=1)
    assert env.action_space == gymnasium.spaces.Discrete(5)
    inner = RDDLEnv("Elevators_MDP_ippc2011", "1")
    flat = FlatRDDLEnv(inner)
    assert flat.env is inner and flat.action_space == gymnasium.spaces.Discrete(5)
    with pytest.raises(ValueError, match="actions must be"):
        FlatRDDLEnv(inner, actions="dict")
    with pytest.raises(ValueError, match="every action fluent to be a bool"):
        FlatRDDLEnv(GYMTEST, actions="multibinary")


def test_where_noop_is_illegal_the_discrete_space_leaves_it_out() -> None:
    # PushYourLuck 2018: exactly one of roll or cash-out each step; noop is illegal
    env = FlatRDDLEnv("PushYourLuck_ippc2018", "1")
    assert env.action_space == gymnasium.spaces.Discrete(2)
    assert [env.flat.action(i) for i in range(2)] == [{"roll___d1": 1}, {"cash-out": 1}]
    env.reset(seed=0)
    env.action_space.seed(0)
    for _ in range(10):
        assert env.action_masks().tolist() == [True, True]
        assert env.step(env.action_space.sample())[4] == {"illegal_action": False}


def test_importing_ippc_gym_does_not_import_stable_baselines3() -> None:
    # stable-baselines3 (and torch) are the optional rl extra: only ippc.gym.baselines needs them
    code = (
        "import sys, ippc.gym; "
        "print(sorted(m for m in ('stable_baselines3', 'torch') if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    assert out.stdout.strip() == "[]"
