"""`SB3VecEnv` (gym/baselines.py) against stable-baselines3's own `DummyVecEnv` over
n `FlatRDDLEnv`s: the same observations, rewards, dones and infos step for step
(its autoreset included), and SB3's checker passes on `FlatRDDLEnv`. Skipped where
stable-baselines3 is not installed (it is the optional `rl` extra)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("stable_baselines3", reason="stable-baselines3 is not installed (ippc[rl])")

from gymnasium.vector import AutoresetMode  # noqa: E402
from ippc.gym import FlatRDDLEnv, RDDLVectorEnv  # noqa: E402
from ippc.gym.baselines import SB3VecEnv  # noqa: E402
from stable_baselines3.common.env_checker import check_env as sb3_check_env  # noqa: E402
from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor  # noqa: E402

from .conftest import GYMTEST  # noqa: E402


def compare(domain: object, instance: object, n: int, steps: int, **kw: object) -> int:
    """Step SB3VecEnv and DummyVecEnv with the same random actions; the episodes ended."""
    ours = SB3VecEnv(domain, instance, num_envs=n, **kw)  # type: ignore[arg-type]
    theirs = DummyVecEnv(
        [lambda: FlatRDDLEnv(domain, instance, **kw) for _ in range(n)]  # type: ignore[arg-type]
    )
    assert ours.action_space == theirs.action_space
    assert ours.observation_space == theirs.observation_space
    ours.seed(11)
    theirs.seed(11)
    assert np.array_equal(ours.reset(), theirs.reset())
    ours.action_space.seed(0)
    ended = 0
    for _ in range(steps):
        actions = np.stack([ours.action_space.sample() for _ in range(n)])
        obs, rewards, dones, infos = ours.step(actions)
        tobs, trewards, tdones, tinfos = theirs.step(actions)
        assert np.array_equal(obs, tobs)
        assert np.array_equal(rewards, trewards)
        assert np.array_equal(dones, tdones)
        for mine, other in zip(infos, tinfos, strict=True):
            assert mine.keys() == other.keys()
            for key in mine:
                assert np.array_equal(mine[key], other[key]), key
        ended += int(dones.sum())
    return ended


def test_equal_to_dummy_vec_env_on_sysadmin() -> None:
    # horizon 40: two episodes each, ended in the same step by the horizon
    assert compare("SysAdmin_MDP_ippc2011", "1", 4, 85) == 8


def test_equal_to_dummy_vec_env_with_box_actions_and_termination() -> None:
    # the test domain: Box actions (illegal ones replaced by noop), horizon 6, termination
    assert compare(GYMTEST, None, 5, 20) >= 10


def test_equal_with_multibinary_actions_where_noop_can_be_illegal() -> None:
    assert compare("ChromaticDice_ippc2018", "1", 3, 12) >= 0


def test_sb3_checker_passes_on_flat_env() -> None:
    sb3_check_env(FlatRDDLEnv("SysAdmin_MDP_ippc2011", "1"), warn=True)


def test_needs_same_step_autoreset() -> None:
    with pytest.raises(ValueError, match="SAME_STEP"):
        SB3VecEnv(RDDLVectorEnv("SysAdmin_MDP_ippc2011", "1", num_envs=2))
    envs = RDDLVectorEnv(
        "SysAdmin_MDP_ippc2011", "1", num_envs=2, autoreset_mode=AutoresetMode.SAME_STEP
    )
    vec = SB3VecEnv(envs)
    assert vec.num_envs == 2 and vec.get_attr("horizon") == [40, 40]
    assert vec.env_is_wrapped(VecMonitor) == [False, False]
    assert vec.env_method("render", indices=[1]) == [None]  # no render_mode
    with pytest.raises(ValueError, match="Discrete"):
        vec.step(np.array([0, 11]))
