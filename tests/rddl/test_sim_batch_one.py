"""The single-state step: the code written for a batch of exactly one
(constants broadcast to their operands' shapes) agrees with the code for
small batches; constants cast once to their operation's dtype give the
values the per-call cast gives; the floating-point error state a step runs
in is `np.errstate(divide="ignore", invalid="ignore", over="ignore")` over
the caller's, and the caller's is back afterwards."""

from __future__ import annotations

import dataclasses
import logging
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from ippc.rddl import load, load_model, load_pair
from ippc.rddl.simulator import SimulationError, Simulator, State, Step, _Compiler

from ..conftest import corpus_root
from .test_sim_compiler import DOMAINS, RDDLSIM

# a few instances of the corpus (the benchmark's), where it is installed
CORPUS = [
    "competitions/IPPC2011/SysAdmin/MDP/instance10.rddl",
    "competitions/IPPC2011/Elevators/MDP/instance10.rddl",
    "competitions/IPPC2014/AcademicAdvising/MDP/instance10.rddl",
    "competitions/IPPC2023/Reservoir/instance5.rddl",
    "competitions/IPPC2023/HVAC/instance5.rddl",
]


def _identical(a: object, b: object) -> bool:
    """Same dtype, shape and values (NaN where NaN)."""
    x, y = np.asarray(a), np.asarray(b)
    if x.dtype != y.dtype or x.shape != y.shape:
        return False
    return bool(np.array_equal(x, y, equal_nan=x.dtype.kind in "fc"))


def _same_outcome(out1: tuple, out2: tuple) -> None:
    nxt1, rew1, obs1, done1 = out1
    nxt2, rew2, obs2, done2 = out2
    assert nxt1.keys() == nxt2.keys()
    for k in nxt1:
        assert _identical(nxt1[k], nxt2[k]), k
    assert _identical(rew1, rew2)
    assert _identical(done1, done2)
    assert (obs1 is None) == (obs2 is None)
    if obs1 is not None:
        assert obs1.keys() == obs2.keys()
        for k in obs1:
            assert _identical(obs1[k], obs2[k]), k


def _actions_seq(
    sim: Simulator, state: State, pick: np.random.Generator, t: int
) -> dict[str, np.ndarray] | None:
    """Noop, no actions at all, or random legal ones (noop where none is)."""
    if t % 3 == 0:
        return None
    if t % 3 == 1:
        return sim.noop(1)
    try:
        return sim.random_actions(state, pick)
    except SimulationError:
        return sim.noop(1)


def compare_one_and_small(sim: Simulator, steps: int, seed: int) -> None:
    """Step one state with the code for a batch of one and with the code
    for small batches: the same values, the same exceptions, the same
    draws (the generators stay in step)."""
    one, small = sim._step_fn(1), sim._step_small
    assert one is not small
    state = sim.initial_state(1)
    pick = np.random.default_rng(seed + 1)
    r1, r2 = np.random.default_rng(seed), np.random.default_rng(seed)
    for t in range(steps):
        acts = sim._actions(_actions_seq(sim, state, pick, t), 1)
        outs: list[tuple | None] = []
        errs: list[str | None] = []
        for fn, rng in ((one, r1), (small, r2)):
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                try:
                    outs.append(fn(state.values, acts, 1, rng, True))
                    errs.append(None)
                except SimulationError as e:
                    outs.append(None)
                    errs.append(str(e))
        assert errs[0] == errs[1]
        assert r1.bit_generator.state == r2.bit_generator.state
        if errs[0] is not None:
            return
        assert outs[0] is not None and outs[1] is not None
        _same_outcome(outs[0], outs[1])
        state = State(outs[0][0])


def _corpus_pairs() -> Iterator[tuple[Path, Path]]:
    root = corpus_root()
    if root is None:
        return
    for rel in CORPUS:
        inst = root / "archive" / rel
        if inst.is_file():
            yield inst.parent / "domain.rddl", inst


@pytest.fixture(autouse=True)
def _quiet_logs() -> Iterator[None]:
    logging.disable(logging.WARNING)
    yield
    logging.disable(logging.NOTSET)


@pytest.mark.parametrize("name", RDDLSIM)
def test_batch_of_one_code_agrees_with_small_batch_code(rddlsim_rddl: Path, name: str) -> None:
    sim = Simulator(load(rddlsim_rddl)[name])
    for seed in (0, 5, 11):
        compare_one_and_small(sim, steps=8, seed=seed)


def test_batch_of_one_code_agrees_on_the_corpus_and_examples() -> None:
    sims = [Simulator(load_pair(*pair)) for pair in _corpus_pairs()]
    for folder in ("corridor_enum", "print_jobs", "print_jobs_pomdp"):
        sims += [Simulator(m) for m in load(DOMAINS / folder).values()]
    assert sims
    for sim in sims:
        for seed in (0, 3):
            compare_one_and_small(sim, steps=6, seed=seed)


def test_batch_of_one_code_widens_constants_and_raises_the_same(rddlsim_rddl: Path) -> None:
    sim = Simulator(load(rddlsim_rddl)["sysadmin_inst_mdp__1"])
    sim.step(sim.initial_state(1), None, np.random.default_rng(0))
    # (the constants of the batch-of-one code are other, widened, ones)
    assert (
        sim._compiler.sources["_step_one"].replace("_step_one", "_step")
        != sim._compiler.sources["_step"]
    )
    # too many actions: the same message from both
    acts = sim.noop(1)
    acts["reboot"][0, :3] = True
    msgs = []
    for batch_fn in (sim._step_fn(1), sim._step_small):
        with pytest.raises(SimulationError) as info:
            batch_fn(
                sim.initial_state(1).values,
                sim._actions(acts, 1),
                1,
                np.random.default_rng(0),
                True,
            )
        msgs.append(str(info.value))
    assert msgs[0] == msgs[1]
    with pytest.raises(SimulationError, match="max-nondef-actions|nondef"):
        sim.step(sim.initial_state(1), acts, np.random.default_rng(0))


def _trajectory(sim: Simulator, batch: int, seed: int, steps: int) -> list[tuple]:
    state = sim.initial_state(batch)
    rng, pick = np.random.default_rng(seed), np.random.default_rng(seed + 1)
    out: list[tuple] = []
    for _ in range(steps):
        try:
            acts = sim.random_actions(state, pick)
        except SimulationError:
            acts = sim.noop(batch)
        try:
            st = sim.step(state, acts, rng)
        except SimulationError as e:
            out.append(("error", str(e)))
            break
        out.append((st.next_state.values, st.reward, st.observation, st.done))
        state = st.next_state
    out.append(("rng", rng.bit_generator.state["state"]))
    return out


def test_constants_cast_once_give_the_per_call_values(
    rddlsim_rddl: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    models = [load(rddlsim_rddl)[name] for name in RDDLSIM]
    models += [load_pair(*pair) for pair in _corpus_pairs()]
    cast = [Simulator(m) for m in models]
    with monkeypatch.context() as mp:
        mp.setattr(_Compiler, "_cast_constant", lambda self, template, args: None)
        uncast = [Simulator(m) for m in models]
    differs = 0
    for a, b in zip(cast, uncast, strict=True):
        differs += a.source() != b.source()
        for batch in (1, 3, 20):  # the code for one, for small and for large batches
            ta, tb = _trajectory(a, batch, 4, 5), _trajectory(b, batch, 4, 5)
            assert len(ta) == len(tb)
            for x, y in zip(ta, tb, strict=True):
                if x[0] in ("error", "rng"):
                    assert x == y
                else:
                    _same_outcome(x, y)
    assert differs  # (the cast is made somewhere)


DIVIDE = """\
domain dz {
  pvariables {
    x : { state-fluent, real, default = 0.0 };
    y : { state-fluent, real, default = 0.0 };
    z : { state-fluent, real, default = 1.0 };
    a : { action-fluent, bool, default = false }; };
  cpfs { x' = 1.0 / x; y' = x / x; z' = z * 1e-200; };
  reward = 1.0 / x; }
instance dz_1 { domain = dz; init-state { z = 1e-200; }; max-nondef-actions = 1; horizon = 5; discount = 1.0; }
"""


def test_step_ignores_divide_invalid_and_overflow_and_keeps_the_callers_state(
    tmp_path: Path,
) -> None:
    (tmp_path / "dz.rddl").write_text(DIVIDE)
    sim = Simulator(load_model(tmp_path))
    rng = np.random.default_rng(0)
    for batch in (1, 3, 20):
        state = sim.initial_state(batch)
        before = np.geterr()
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # a warning that leaks out fails
            for _ in range(2):  # (the second time in the kept state)
                out = sim.step(state, None, rng)
                assert np.isinf(out.next_state.values["x"]).all()
                assert np.isnan(out.next_state.values["y"]).all()
                assert np.isinf(out.reward).all()
                assert np.geterr() == before
            # the caller's settings for the other errors stand: underflow raises
            with np.errstate(all="raise"):
                with pytest.raises(FloatingPointError, match="underflow"):
                    sim.step(state, None, rng)
                assert np.geterr() == {
                    "divide": "raise",
                    "over": "raise",
                    "under": "raise",
                    "invalid": "raise",
                }
                # ... and a step already in the step's own state changes nothing
                with np.errstate(divide="ignore", invalid="ignore", over="ignore", under="ignore"):
                    sim.step(state, None, rng)
            assert np.geterr() == before


def test_step_returns_a_frozen_step(rddlsim_rddl: Path) -> None:
    sim = Simulator(load(rddlsim_rddl)["sysadmin_inst_mdp__1"])
    out = sim.step(sim.initial_state(1), None, np.random.default_rng(0))
    assert type(out) is Step
    assert [f.name for f in dataclasses.fields(out)] == [
        "next_state",
        "reward",
        "observation",
        "done",
    ]
    assert isinstance(out.next_state, State) and out.next_state.batch == 1
    assert out.reward.shape == (1,) and out.done.shape == (1,) and out.observation is None
    with pytest.raises(dataclasses.FrozenInstanceError):
        out.reward = np.zeros(1)  # type: ignore[misc]
    again = dataclasses.replace(out, observation=None)
    assert again.next_state is out.next_state and again.reward is out.reward
    assert "Step(next_state=State(batch=1" in repr(out)
