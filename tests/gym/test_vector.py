"""ippc.gym.RDDLVectorEnv: its trajectories are those of n RDDLEnvs with the same
seeds (Gymnasium's SyncVectorEnv over them, in each autoreset mode), stepped in
one batched simulator call; and the per-state streams it needs for that."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from ippc.gym import IllegalActionError, RDDLEnv, RDDLVectorEnv
from ippc.gym.streams import PerStateGenerator
from ippc.rddl.simulator import Simulator

from .conftest import GYMTEST, GYMTEST_POMDP, ippc_mdp_problems


def _actions(space: Any, steps: int, seed: int) -> list[Any]:
    space.seed(seed)
    return [space.sample() for _ in range(steps)]


def compare(
    domain: Any,
    instance: Any,
    n: int,
    steps: int,
    mode: AutoresetMode,
    actions: list[Any] | None = None,
    vector_kwargs: dict[str, Any] | None = None,
    **kwargs: Any,
) -> int:
    """Step an RDDLVectorEnv and a SyncVectorEnv of RDDLEnvs side by side with the
    same actions; assert every output is equal; return how many episodes ended."""
    vec = RDDLVectorEnv(
        domain, instance, num_envs=n, autoreset_mode=mode, **kwargs, **(vector_kwargs or {})
    )
    sync = SyncVectorEnv(
        [lambda: RDDLEnv(domain, instance, **kwargs) for _ in range(n)], autoreset_mode=mode
    )
    got, want = vec.reset(seed=7), sync.reset(seed=7)
    assert data_equivalence(got, want, exact=True)
    ended = 0
    for t, action in enumerate(actions or _actions(vec.action_space, steps, 3)):
        got, want = vec.step(action), sync.step(action)
        for name, a, b in zip(("obs", "reward", "term", "trunc", "info"), got, want, strict=True):
            assert data_equivalence(a, b, exact=True), f"step {t}: {name} differs:\n{a}\n{b}"
        done = got[2] | got[3]
        ended += int(done.sum())
        if mode == AutoresetMode.DISABLED and done.any():
            got, want = (env.reset(options={"reset_mask": done.copy()}) for env in (vec, sync))
            assert data_equivalence(got, want, exact=True)
    return ended


@pytest.mark.parametrize("mode", list(AutoresetMode))
def test_equal_to_single_envs_in_every_autoreset_mode(mode: AutoresetMode) -> None:
    # the horizon (6) and the terminal state end episodes at different steps;
    # Normal and Bernoulli draws; random actions, many of them illegal
    ended = compare(GYMTEST, None, 5, 40, mode)
    assert ended >= 5


@pytest.mark.parametrize("illegal", ["noop", "end"])
def test_equal_to_single_envs_with_illegal_actions(illegal: str) -> None:
    assert compare(GYMTEST, None, 4, 30, AutoresetMode.NEXT_STEP, illegal_actions=illegal) > 0


@pytest.mark.parametrize(
    "problem",
    [
        "SysAdmin_MDP_ippc2011",  # Bernoulli
        "Reservoir_ippc2023",  # real actions, Normal and other draws
        "ChromaticDice_ippc2018",  # Discrete draws, noop illegal: legal actions drawn
    ],
)
def test_equal_to_single_envs_on_ippc_instances(problem: str) -> None:
    compare(problem, "1", 3, 45, AutoresetMode.NEXT_STEP)


@pytest.mark.slow
@pytest.mark.parametrize("problem", ippc_mdp_problems())
def test_equal_to_single_envs_on_every_ippc_instance_1(problem: str) -> None:
    compare(problem, "1", 3, 50, AutoresetMode.NEXT_STEP)


def test_a_pomdp_batches_its_observations() -> None:
    compare(GYMTEST_POMDP, None, 4, 12, AutoresetMode.SAME_STEP)


def test_one_stream_for_the_batch_is_seeded_but_not_single_envs() -> None:
    """The comparison can fail: one generator for the whole batch draws other values."""
    with pytest.raises(AssertionError, match="differs"):
        compare(
            "SysAdmin_MDP_ippc2011",
            "1",
            3,
            10,
            AutoresetMode.NEXT_STEP,
            vector_kwargs={"streams": "batch"},
        )

    def rewards(seed: int) -> np.ndarray:
        envs = RDDLVectorEnv("SysAdmin_MDP_ippc2011", "1", num_envs=8, streams="batch")
        envs.reset(seed=seed)
        return np.array([envs.step({})[1] for _ in range(10)])

    assert np.array_equal(rewards(1), rewards(1))
    assert not np.array_equal(rewards(1), rewards(2))


def test_one_batched_simulator_call_per_step(monkeypatch: pytest.MonkeyPatch) -> None:
    envs = RDDLVectorEnv("SysAdmin_MDP_ippc2011", "1", num_envs=64)
    envs.reset(seed=0)
    calls: list[int] = []
    step = Simulator.step

    def counted(self: Simulator, state: Any, *args: Any, **kwargs: Any) -> Any:
        calls.append(state.batch)
        return step(self, state, *args, **kwargs)

    monkeypatch.setattr(Simulator, "step", counted)
    for _ in range(5):
        envs.step(envs.action_space.sample())
    assert calls == [64] * 5


def test_illegal_actions_per_environment() -> None:
    envs = RDDLVectorEnv(GYMTEST, num_envs=3)
    envs.reset(seed=0)
    light3 = np.array([0, 1, 0])  # forbidden in environment 1 only
    obs, _, _, _, info = envs.step({"light___c3": light3, "light___c1": 1})
    assert info["illegal_action"].tolist() == [False, True, False]
    assert info["_illegal_action"].tolist() == [True, True, True]
    assert obs["lit___c1"].tolist() == [1, 0, 1] and obs["lit___c3"].tolist() == [0, 0, 0]
    strict = RDDLVectorEnv(GYMTEST, num_envs=3, illegal_actions="raise")
    strict.reset(seed=0)
    with pytest.raises(IllegalActionError, match="environment 1: .*GOAL"):
        strict.step({"light___c3": light3})
    with pytest.raises(ValueError, match=r"'move': 2 is not in Discrete\(2\) \(environment 2\)"):
        envs.step({"move": np.array([0, 1, 2])})


def test_render_gives_every_environment() -> None:
    envs = RDDLVectorEnv(GYMTEST, num_envs=2, render_mode="ansi")
    envs.reset(seed=0)
    envs.step({"move": np.array([1, 0])})
    texts = envs.render()
    assert texts is not None and len(texts) == 2
    assert "  at = c2" in texts[0].splitlines() and "  at = c1" in texts[1].splitlines()


def test_per_state_streams_draw_what_each_generator_draws_alone() -> None:
    seeds = [3, 4, 5]
    batched = PerStateGenerator([np.random.default_rng(s) for s in seeds])
    alone = [np.random.default_rng(s) for s in seeds]
    # 5 Bernoulli slots for each of 3 states: ceil(15 / 2) raw outputs
    u = batched.bit_generator.random_raw(8).view(np.uint32)[:15].reshape(5, 3)
    for b, g in enumerate(alone):
        assert np.array_equal(u[:, b], g.bit_generator.random_raw(3).view(np.uint32)[:5])
    z = batched.standard_normal((2, 3))  # batch last
    g = batched.gamma(np.array([[1.0], [2.0], [3.0]]), 1.0, (3, 4))  # batch first
    for b, gen in enumerate(alone):
        assert np.array_equal(z[:, b], gen.standard_normal(2))
        assert np.array_equal(g[b], gen.gamma(b + 1.0, 1.0, 4))
    with pytest.raises(TypeError, match="batch"):
        batched.random((4, 3))
    with pytest.raises(AttributeError, match="no per-state 'integers'"):
        batched.integers  # noqa: B018


def test_streams_drawn_ahead_are_given_back() -> None:
    """Raw outputs drawn for several steps at once: after `sync` every generator is
    where the outputs taken leave it, a buffered 32-bit half included."""
    gens = [np.random.default_rng(s) for s in (1, 2)]
    gens[0].integers(0, 9, dtype=np.int32)  # leaves half an output buffered
    alone = [np.random.default_rng(s) for s in (1, 2)]
    alone[0].integers(0, 9, dtype=np.int32)
    batched = PerStateGenerator(gens, ahead=8)
    for _ in range(3):
        u = batched.bit_generator.random_raw(3).view(np.uint32)[:6].reshape(3, 2)
        for b, g in enumerate(alone):
            assert np.array_equal(u[:, b], g.bit_generator.random_raw(2).view(np.uint32)[:3])
    batched.sync()
    for g, h in zip(gens, alone, strict=True):
        assert g.bit_generator.state == h.bit_generator.state
        assert (
            g.integers(0, 1000, 5, dtype=np.int32).tolist()
            == h.integers(0, 1000, 5, dtype=np.int32).tolist()
        )
