"""The code for large batches: constants repeated along the batch or
taken as scalars (`_spread_constant`), counts kept as uint8 through integer
arithmetic, row gathers summed in place, unary functions written in place.
Each gives exactly the values (bit for bit) and the draws of the code for
small batches."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ippc.rddl import load
from ippc.rddl.simulator import (
    _SPREAD_BYTES,
    SimulationError,
    Simulator,
    State,
    _gather_sum,
    _quietly,
    _spread_factory,
)

# per-node constants (CAP, P: a column each), one the same everywhere (SD),
# min/max against constants, a Normal with a constant mean, abs and exp, a
# Bernoulli whose probability is arithmetic on a count over a relation, and
# one with a per-node constant probability (0 and 1 included)
DOMAIN = """
domain spread_test {
    types { node: object; };
    pvariables {
        CAP(node): { non-fluent, real, default = 10.0 };
        LINK(node, node): { non-fluent, bool, default = false };
        SD(node): { non-fluent, real, default = 4.0 };
        P(node): { non-fluent, real, default = 0.5 };
        level(node): { state-fluent, real, default = 1.0 };
        up(node): { state-fluent, bool, default = true };
        pour(node): { action-fluent, real, default = 0.0 };
    };
    cpfs {
        level'(?n) = min[CAP(?n), max[0, level(?n) + abs[Normal(0, SD(?n))] - pour(?n)
                     + exp[-1 * level(?n) / CAP(?n)]]];
        up'(?n) = if (up(?n))
                  then Bernoulli(0.25 + 0.5 * (1 + sum_{?m: node} [LINK(?m, ?n) ^ up(?m)])
                                 / (1 + sum_{?m: node} [LINK(?m, ?n)]))
                  else Bernoulli(P(?n));
    };
    reward = sum_{?n: node} [if (level'(?n) > CAP(?n) - 1) then -1 * level'(?n) else level'(?n) * P(?n)];
    action-preconditions { forall_{?n: node} [pour(?n) >= 0]; };
}
non-fluents spread_nf {
    domain = spread_test;
    objects { node: {a, b, c, d, e, f}; };
    non-fluents {
        CAP(a) = 5.0; CAP(b) = 8.0; CAP(c) = 13.0; CAP(d) = 3.5; CAP(e) = 20.0;
        P(a) = 0.1; P(b) = 0.9; P(c) = 1.0; P(d) = 0.0; P(e) = 0.3;
        LINK(a, b); LINK(c, b); LINK(b, c); LINK(d, e); LINK(e, a); LINK(f, a);
    };
}
instance spread_inst {
    domain = spread_test;
    non-fluents = spread_nf;
    init-state { level(a) = 4.0; level(c) = 12.5; up(d) = false; };
    max-nondef-actions = pos-inf;
    horizon = 20;
    discount = 1.0;
}
"""


@pytest.fixture
def sim(tmp_path: Path) -> Simulator:
    path = tmp_path / "spread.rddl"
    path.write_text(DOMAIN)
    return Simulator(load(path)["spread_inst"])


def _bitwise(a: np.ndarray, b: np.ndarray) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def test_large_code_uses_the_new_forms(sim: Simulator) -> None:
    sim.step(sim.initial_state(32), sim.noop(32), np.random.default_rng(0))
    src = sim._compiler.sources["_step_large"]
    assert "_spread(" in src  # CAP, P against batched values
    assert "_gather_sum(" in src  # the count over LINK
    assert "_abs(" in src and "out=" in src.split("_abs(")[1].split("\n")[0]  # abs in place
    assert "np.exp(" in src and "out=" in src.split("np.exp(")[1].split("\n")[0]
    assert ".astype(_i64)" not in src  # the count stays uint8 into the float arithmetic
    # the small-batch code has none of it
    small = sim._compiler.sources["_step"]
    assert "_spread(" not in small and "_gather_sum(" not in small


@pytest.mark.parametrize("batch", [16, 33, 1024])
def test_large_and_small_code_agree_bit_for_bit(sim: Simulator, batch: int) -> None:
    small, large = sim._step_small, sim._step_fn(batch)
    assert small is not large
    state = sim.initial_state(batch)
    pick = np.random.default_rng(7)
    for t in range(8):
        actions = sim.noop(batch)
        if t % 2:
            actions["pour"] = pick.random((batch, 6)) * 3  # some states pour more than they hold
        acts = sim._actions(actions, batch)
        r1, r2 = np.random.default_rng(t), np.random.default_rng(t)
        out1 = _quietly(small, state.values, acts, batch, r1, True)
        out2 = _quietly(large, state.values, acts, batch, r2, True)
        for k in out1[0]:
            assert _bitwise(out1[0][k], out2[0][k]), k
        assert _bitwise(out1[1], out2[1]) and _bitwise(out1[3], out2[3])
        assert r1.random() == r2.random()  # the same draws
        state = State(out1[0])


def test_probability_zero_and_one_per_node(sim: Simulator) -> None:
    # every node down: up' is Bernoulli(P(?n)); P(c) = 1, P(d) = 0
    batch = 512
    state = sim.initial_state(batch)
    state.values["up"][...] = False
    out = sim.step(state, sim.noop(batch), np.random.default_rng(1))
    up = out.next_state.values["up"]
    assert up[:, 2].all() and not up[:, 3].any()
    assert 0.8 < up[:, 1].mean() < 0.97 and 0.03 < up[:, 0].mean() < 0.2  # P(b) = 0.9, P(a) = 0.1


def test_precondition_still_raises_in_large_code(sim: Simulator) -> None:
    actions = sim.noop(64)
    actions["pour"][5, 2] = -1.0
    with pytest.raises(SimulationError, match="state 5 of the batch"):
        sim.step(sim.initial_state(64), actions, np.random.default_rng(0))


def test_spread_repeats_a_constant_once_per_shape() -> None:
    spread = _spread_factory()
    k = np.arange(3.0).reshape(3, 1)
    k.flags.writeable = False
    w = spread(k, (3, 5))
    assert w.shape == (3, 5) and w.flags.c_contiguous and not w.flags.writeable
    assert (w == np.broadcast_to(k, (3, 5))).all()
    assert spread(k, (3, 5)) is w  # made once
    assert spread(k, (3, 7)).shape == (3, 7)
    # too large: the constant itself, to be broadcast where it is used
    cols = _SPREAD_BYTES // (3 * k.itemsize) + 1
    assert spread(k, (3, cols)) is k


def test_gather_sum_adds_rows_in_order() -> None:
    rng = np.random.default_rng(0)
    x = rng.random((7, 50)) * 10.0 ** rng.integers(-8, 8, (7, 50))
    rows = (np.array([0, 3, 6, 2]), np.array([1, 1, 5, 2]), np.array([6, 0, 0, 4]))
    expected = x[rows[0]] + x[rows[1]] + x[rows[2]]
    got = _gather_sum(x, rows)
    assert _bitwise(got, expected)
    one = _gather_sum(x, rows[:1])
    assert _bitwise(one, x[rows[0]]) and not np.shares_memory(one, x)  # a new array
    # counts of bools, as bytes
    counts = (rng.random((7, 9)) < 0.5).view(np.uint8)
    got8 = _gather_sum(counts, rows)
    assert got8.dtype == np.uint8
    assert (got8 == counts[rows[0]].astype(int) + counts[rows[1]] + counts[rows[2]]).all()
