"""The simulator's random draws: Bernoulli from 32-bit uniforms, and
branches that draw only for the branch an element takes.

A Bernoulli(p) fires when a uniform 32-bit integer u (half of one raw
64-bit output of the caller's bit generator) is below p * 2**32: within
2**-32 of p, never for p = 0, always for p = 1. The branches of an `if` or
a `switch` draw the same uniforms (each element reads them through the one
branch it takes), so a step draws one uniform per grounding where rddlsim
draws one; a draw outside the branches never reuses theirs.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from ippc.rddl import load_model
from ippc.rddl.simulator import _LARGE_BATCH, Simulator, State

DRAWS = """\
domain draws {
  types { obj : object; level : {@lo, @mid, @hi}; };
  pvariables {
    PA(obj) : { non-fluent, real, default = 0.3 };
    PB(obj) : { non-fluent, real, default = 1.0 };
    PC(obj) : { non-fluent, real, default = 0.0 };
    c(obj) : { state-fluent, bool, default = false };
    k(obj) : { state-fluent, level, default = @lo };
    r(obj) : { state-fluent, real, default = 0.0 };
    a(obj) : { state-fluent, bool, default = false };
    b(obj) : { state-fluent, bool, default = false };
    bc(obj) : { state-fluent, bool, default = false };
    d(obj) : { state-fluent, bool, default = false };
    e(obj) : { state-fluent, bool, default = false };
    f(obj) : { state-fluent, bool, default = false };
    g(obj) : { state-fluent, bool, default = false };
    h(obj) : { state-fluent, bool, default = false };
    z(obj) : { state-fluent, bool, default = false };
    act(obj) : { action-fluent, bool, default = false };
  };
  cpfs {
    c'(?x) = c(?x);
    k'(?x) = k(?x);
    r'(?x) = r(?x);
    a'(?x) = Bernoulli(PA(?x));
    b'(?x) = Bernoulli(PB(?x));
    bc'(?x) = Bernoulli(PC(?x));
    d'(?x) = Bernoulli(r(?x));
    e'(?x) = if (c(?x)) then Bernoulli(0.2) else Bernoulli(0.7);
    f'(?x) = if (c(?x)) then Bernoulli(0.5) else Bernoulli(0.5);
    g'(?x) = [if (c(?x)) then Bernoulli(0.5) else false] ^ Bernoulli(0.5);
    h'(?x) = switch (k(?x)) { case @lo : Bernoulli(0.1),
                              case @mid : [if (c(?x)) then Bernoulli(0.4) else Bernoulli(0.6)],
                              default : Bernoulli(0.9) };
    z'(?x) = Bernoulli(0.0) | [Bernoulli(1.0) ^ act(?x)];
  };
  reward = 0;
}
non-fluents draws_nf { domain = draws; objects { obj : {o1, o2, o3, o4}; };
  non-fluents { PA(o1) = 0.0; PA(o3) = 0.000000001; PA(o4) = 0.999999;
                PB(o2) = 0.3; PB(o3) = 0.75;
                PC(o2) = 1.0; PC(o3) = 0.3; PC(o4) = 0.7; }; }
instance draws_1 { domain = draws; non-fluents = draws_nf;
  max-nondef-actions = pos-inf; horizon = 5; discount = 1.0; }
"""

PA = np.array([0.0, 0.3, 1e-9, 0.999999])
PB = np.array([1.0, 0.3, 0.75, 1.0])
PC = np.array([0.0, 1.0, 0.3, 0.7])
R = np.array([0.0, 1.0, 0.3, 0.7])  # the state-dependent probabilities of d
# slots of 4 uniforms per state: a, b, bc, d, e (both branches), f (both),
# g (the branch, then the draw outside it), h (every case and the if inside)
SLOTS = 9
N = 200_000  # states in the batch of the frequency tests


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> Simulator:
    folder = tmp_path_factory.mktemp("draws")
    (folder / "draws.rddl").write_text(DRAWS)
    return Simulator(load_model(folder))


def _state(sim: Simulator, batch: int, seed: int) -> State:
    """States with c and k drawn at random (by numpy, not the simulator)
    and r set to R."""
    rng = np.random.default_rng(seed)
    state = sim.initial_state(batch)
    state.values["c"][...] = rng.random((batch, 4)) < 0.5
    state.values["k"][...] = rng.integers(0, 3, (batch, 4))
    state.values["r"][...] = R
    return state


def _within(hits: np.ndarray, p: float) -> None:
    """The frequency of `hits` is within 5 standard deviations of p."""
    n = hits.size
    assert n > 1000
    freq = float(np.count_nonzero(hits)) / n
    assert abs(freq - p) <= 5 * np.sqrt(p * (1 - p) / n) + 1e-12, (freq, p)


@pytest.fixture(scope="module")
def outcome(sim: Simulator) -> tuple[State, dict[str, np.ndarray]]:
    state = _state(sim, N, 3)
    out = sim.step(state, None, np.random.default_rng(11))
    return state, out.next_state.values


def test_one_uniform_per_grounding_of_each_branch_group(sim: Simulator) -> None:
    sim.step(sim.initial_state(_LARGE_BATCH), None, np.random.default_rng(0))
    src = sim.source()
    # both variants draw the same block: one slot per draw outside the
    # branches, one per group of branches; Bernoulli(0) and Bernoulli(1)
    # draw nothing
    assert src.count(f"_uniforms(rng, {SLOTS * 4} * B)") == 2
    assert "rng.random" not in src


def test_bernoulli_frequencies_with_constant_probabilities(
    outcome: tuple[State, dict[str, np.ndarray]],
) -> None:
    _, nxt = outcome
    for name, probs in (("a", PA), ("b", PB), ("bc", PC), ("d", R)):
        values = nxt[name]
        for i, p in enumerate(probs):
            if p == 0:
                assert not values[:, i].any(), (name, i)
            elif p == 1:
                assert values[:, i].all(), (name, i)
            elif p < 1e-6:
                assert np.count_nonzero(values[:, i]) <= 2, (name, i)
            else:
                _within(values[:, i], p)
    assert not nxt["z"].any()  # Bernoulli(0) | (Bernoulli(1) ^ act), act false


def test_branches_give_the_marginal_of_the_branch_taken(
    outcome: tuple[State, dict[str, np.ndarray]],
) -> None:
    state, nxt = outcome
    c, k = state.values["c"], state.values["k"]
    _within(nxt["e"][c], 0.2)
    _within(nxt["e"][~c], 0.7)
    _within(nxt["f"], 0.5)
    # two `if`s draw apart: e and f are independent where both branches draw
    _within(nxt["e"][c] & nxt["f"][c], 0.1)
    _within(nxt["e"][~c] & nxt["f"][~c], 0.35)
    # a draw outside the branches is independent of the one inside them
    _within(nxt["g"][c], 0.25)
    assert not nxt["g"][~c].any()
    _within(nxt["h"][k == 0], 0.1)
    _within(nxt["h"][(k == 1) & c], 0.4)
    _within(nxt["h"][(k == 1) & ~c], 0.6)
    _within(nxt["h"][k == 2], 0.9)
    # and the groundings of one fluent are independent of each other
    _within(nxt["a"][:, 1] & nxt["a"][:, 3], 0.3 * 0.999999)
    _within(
        nxt["e"][:, 0] & nxt["e"][:, 1],
        float(np.mean(np.where(c[:, 0], 0.2, 0.7) * np.where(c[:, 1], 0.2, 0.7))),
    )


@pytest.mark.parametrize("batch", [1, 3, _LARGE_BATCH, 100])
def test_same_seed_same_trajectory(sim: Simulator, batch: int) -> None:
    def run(seed: int) -> list[np.ndarray]:
        rng = np.random.default_rng(seed)
        s = _state(sim, batch, 5)
        out = []
        for _ in range(4):
            s = sim.step(s, None, rng).next_state
            out.append(np.concatenate([s.values[n].reshape(batch, -1) for n in "abdefgh"], axis=1))
        return out

    first, again, other = run(21), run(21), run(22)
    assert all((x == y).all() for x, y in zip(first, again, strict=True))
    assert any((x != y).any() for x, y in zip(first, other, strict=True))


class _Bits:
    """A stand-in for a Generator whose bit generator returns given raw
    64-bit outputs (to test the thresholds exactly)."""

    def __init__(self, raw: np.ndarray):
        self.bit_generator = self
        self.raw = raw

    def random_raw(self, n: int) -> np.ndarray:
        assert n == self.raw.size
        return self.raw


def test_thresholds_are_exact_at_the_edges(sim: Simulator) -> None:
    # every slot's uniforms set to one value u: the low half of each raw
    # output is one uniform, the high half the next
    top = 2**32 - 1

    def step_with(u: int, batch: int = 1) -> dict[str, np.ndarray]:
        half = np.full(SLOTS * 4 * batch, u, dtype=np.uint32)
        raw = half.view(np.uint64).copy()
        fake: Any = _Bits(raw)
        state = _state(sim, batch, 0)
        state.values["c"][...] = True
        return sim.step(state, None, fake).next_state.values

    lowest, highest = step_with(0), step_with(top)
    # u = 0 fires for every p > 0, even 1e-9; u = 2**32 - 1 only for p = 1
    assert (lowest["a"][0] == (PA > 0)).all()
    assert (lowest["bc"][0] == (PC > 0)).all()
    assert (lowest["d"][0] == (R > 0)).all()
    assert (highest["a"][0] == (PA == 1)).all()
    assert (highest["b"][0] == (PB == 1)).all()
    assert (highest["bc"][0] == (PC == 1)).all()
    assert (highest["d"][0] == (R == 1)).all()
    # p = 0.3 fires for u < ceil(0.3 * 2**32), and for no u above
    edge = int(np.ceil(0.3 * 2**32))
    assert step_with(edge - 1)["a"][0, 1] and not step_with(edge)["a"][0, 1]
    assert step_with(edge - 1)["b"][0, 1] and not step_with(edge)["b"][0, 1]
    assert step_with(edge - 1)["bc"][0, 2] and not step_with(edge)["bc"][0, 2]
    assert step_with(edge - 1)["d"][0, 2] and not step_with(edge)["d"][0, 2]
    # the same in the variant for large batches
    large = step_with(edge - 1, _LARGE_BATCH)
    assert large["a"][:, 1].all() and large["d"][:, 2].all()
    assert not step_with(edge, _LARGE_BATCH)["a"][:, 1].any()


def test_uniforms_are_read_batch_last_in_slot_order(sim: Simulator) -> None:
    # the first slot (a's Bernoulli) reads the first 4 * B uniforms, the
    # grounding axis outermost: grounding i of state b reads uniform i * B + b
    batch = 3
    half = np.full(SLOTS * 4 * batch, 2**32 - 1, dtype=np.uint32)
    half[1 * batch + 2] = 0  # a(o2) of state 2
    fake: Any = _Bits(half.view(np.uint64).copy())
    nxt = sim.step(_state(sim, batch, 0), None, fake).next_state.values
    want = np.zeros((batch, 4), dtype=bool)
    want[2, 1] = True
    assert (nxt["a"] == want).all()
