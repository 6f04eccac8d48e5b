"""The one-state step compiled to C (ippc.rddl.sim.cstep) against the Python
step it is translated from (ippc.rddl.sim.scalar): the same draws fed to
both give the same successor, reward and end, on the first instance of
every IPPC 2011/2014/2018 MDP domain (instances 1-5 in the slow sweep) and
on hand-made domains that pin the translation's semantics (Python's
`and`/`or`, short-circuit draw recording, Discrete and Normal records, the
arithmetic helpers, enum tables, if and switch). Then what makes the C step
unavailable (`CUnavailable`: a failing or missing compiler, a construct the
translator does not know), the private cache of compiled libraries, and the
C files of the package compiled with -Wall -Wextra -Werror (mcts's search
kernels are tested in tests/planners/test_mcts_kernels.py). The libraries go to the run's
temporary folder (tests/conftest.py sets IPPC_CACHE)."""

from __future__ import annotations

import ast
import copy
import hashlib
import itertools
import math
import os
import stat
import subprocess
import tempfile
from pathlib import Path
from typing import Any

import ippc.planners.mcts.ckernels as ckernels
import numpy as np
import pytest
from ippc.planners.mcts.ckernels import kernel_source
from ippc.rddl import load, load_pair
from ippc.rddl.sim import cbuild
from ippc.rddl.sim.cstep import CStep, CUnavailable, c_source, find_compiler
from ippc.rddl.sim.scalar import _HELPERS, ScalarStep
from ippc.rddl.simulator import Simulator

from ..conftest import IPPC_MDP_DOMAINS, ippc_files

HAVE_CC = find_compiler() is not None
needs_cc = pytest.mark.skipif(not HAVE_CC, reason="no C compiler (cc, gcc, clang or $CC)")


class Draws:
    """Given draws, in the shape `ScalarStep.step` asks a generator for."""

    def __init__(self, uniforms: list[float], normals: list[float]):
        self.u = uniforms
        self.z = normals

    def random(self, n: int) -> np.ndarray:
        assert n <= len(self.u)
        return np.array(self.u[:n], dtype=np.float64)

    def standard_normal(self, n: int) -> np.ndarray:
        assert n <= len(self.z)
        return np.array(self.z[:n], dtype=np.float64)


def both(sim: Simulator) -> tuple[ScalarStep, CStep]:
    fast = ScalarStep(sim)
    return fast, CStep(fast)


def model_of(tmp_path: Path, text: str, name: str) -> Simulator:
    f = tmp_path / f"{name}.rddl"
    f.write_text(text)
    return Simulator(load(f)[name])


def assert_same(c_out: tuple[Any, ...], py_out: tuple[Any, ...], what: str = "") -> None:
    """The C step's (next, reward, done, ...) equals the Python step's
    (next, reward, done): every grounding, the reward to 1e-9 relative."""
    cn, cr, cd = c_out[:3]
    pn, pr, pd = py_out
    assert len(cn) == len(pn)
    np.testing.assert_allclose(
        np.array(cn, dtype=np.float64),
        np.array(pn, dtype=np.float64),
        rtol=1e-9,
        atol=1e-12,
        err_msg=what,
    )
    if math.isnan(pr):
        assert math.isnan(cr), what
    else:
        assert cr == pytest.approx(pr, rel=1e-9, abs=1e-12), what
    assert cd == pd, what


def compare_steps(sim: Simulator, steps: int = 300, seed: int = 0) -> int:
    """Random legal actions along a trajectory of the Python step; at each
    state both steps with the same uniforms and normals. The number of
    round ends met."""
    fast, c = both(sim)
    rng = np.random.default_rng(seed)
    start = fast.encode_state(sim.initial_state(1))
    state = start
    ends = 0
    for t in range(steps):
        act = fast.encode_actions(sim.random_actions(fast.decode_state(state), rng))
        u = rng.random(fast.n_uniforms).tolist()
        z = rng.standard_normal(fast.n_normals).tolist()
        py = fast.step(state, act, Draws(u, z))
        assert_same(c.step(state, act, u, z), py, f"{sim.model.name} step {t}")
        state = py[0]
        if py[2]:
            ends += 1
            state = start
    return ends


IPPC = [(year, d) for year, domains in IPPC_MDP_DOMAINS.items() for d in domains]


@needs_cc
@pytest.mark.parametrize("year,domain", IPPC, ids=[f"{y}-{d}" for y, d in IPPC])
def test_ippc_instance_1_same_as_the_python_step(year: str, domain: str) -> None:
    compare_steps(Simulator(load_pair(*ippc_files(year, domain, 1))))


@needs_cc
@pytest.mark.slow
@pytest.mark.parametrize("number", [1, 2, 3, 4, 5])
@pytest.mark.parametrize("year,domain", IPPC, ids=[f"{y}-{d}" for y, d in IPPC])
def test_ippc_instances_1_to_5_same_as_the_python_step(year: str, domain: str, number: int) -> None:
    compare_steps(Simulator(load_pair(*ippc_files(year, domain, number))), seed=number)


# -- hand-made domains: the translation's semantics ---------------------------

SEMANTICS = """
domain sem {
    requirements = { concurrent };
    types { level : { @low, @mid, @high }; };
    pvariables {
        flag : { state-fluent, bool, default = false };
        k : { state-fluent, int, default = 3 };
        j : { state-fluent, int, default = 0 };
        x : { state-fluent, real, default = 2.5 };
        lvl : { state-fluent, level, default = @mid };
        andk : { state-fluent, int, default = 0 };
        ork : { state-fluent, int, default = 0 };
        hit : { state-fluent, bool, default = false };
        hit2 : { state-fluent, bool, default = false };
        y : { state-fluent, real, default = 0.0 };
        sw : { state-fluent, int, default = 0 };
        go : { action-fluent, bool, default = false };
    };
    cpfs {
        andk' = k ^ j;
        ork' = k | j;
        hit' = if (flag) then Bernoulli(0.3) else false;
        hit2' = go ^ Bernoulli(0.6);
        lvl' = Discrete(level, @low : 0.2, @mid : 0.5, @high : 0.3);
        y' = Normal(x, 4.0);
        sw' = switch (lvl) { case @low : k, case @high : j, default : 7 };
        flag' = flag;
        k' = k;
        j' = j;
        x' = x;
    };
    reward = if (lvl == @high) then k else x;
}
instance sem_inst {
    domain = sem;
    init-state { flag = false; };
    max-nondef-actions = 1;
    horizon = 5;
    discount = 1.0;
}
"""

# the recorded slots of SEMANTICS, in the order the sites are written
SLOT_LVL = [0, 1, 2]  # the Discrete: each case's probability
SLOT_HIT, SLOT_HIT2, SLOT_Y = 3, 4, 5


def _sem_state(fast: ScalarStep, **values: Any) -> tuple[Any, ...]:
    keys = [name for name, _ in fast.state_keys]
    s = list(fast.encode_state(fast.sim.initial_state(1)))
    for name, v in values.items():
        s[keys.index(name)] = v
    return tuple(s)


@needs_cc
def test_and_or_over_ints_are_booleans_in_both_steps(tmp_path: Path) -> None:
    """`k ^ j` and `k | j` over ints are written as `bool(k) and bool(j)`
    (the batched step's 0/1, not Python's operand); the C step gives the
    same (its `and`/`or` of non-boolean operands return an operand as
    Python's do: the hand-written sources below)."""
    sim = model_of(tmp_path, SEMANTICS, "sem_inst")
    fast, c = both(sim)
    assert "(bool(s1) and bool(s2))" in fast.source and "(bool(s1) or bool(s2))" in fast.source
    keys = [name for name, _ in fast.state_keys]
    u, z = [0.9, 0.9, 0.9], [0.0]
    for k, j in itertools.product([0, 3, -2], [0, 5]):
        s = _sem_state(fast, k=k, j=j)
        py = fast.step(s, fast.noop, Draws(u, z))
        out = c.step(s, fast.noop, u, z)
        assert_same(out, py, f"k={k} j={j}")
        assert out[0][keys.index("andk")] == int(bool(k) and bool(j))
        assert out[0][keys.index("ork")] == int(bool(k) or bool(j))


@needs_cc
def test_a_draw_behind_a_false_condition_is_not_recorded(tmp_path: Path) -> None:
    """The slots `CStep.step` returns hold the probability each Bernoulli
    site compared its uniform with, and -1.0 where the site was not
    reached: `if (flag) then Bernoulli(..)` with flag false, and
    `go ^ Bernoulli(..)` (Python's `and`) with go false."""
    sim = model_of(tmp_path, SEMANTICS, "sem_inst")
    fast, c = both(sim)
    assert c.nl == 6 and c.nu == 3 and c.nz == 1
    u, z = [0.1, 0.1, 0.1], [0.5]
    go = tuple(True for _ in fast.noop)
    for flag, act in itertools.product([False, True], [fast.noop, go]):
        s = _sem_state(fast, flag=flag)
        nxt, r, done, slots = c.step(s, act, u, z)
        assert_same((nxt, r, done), fast.step(s, act, Draws(u, z)))
        assert slots[SLOT_HIT] == (0.3 if flag else -1.0)
        assert slots[SLOT_HIT2] == (0.6 if act == go else -1.0)
        # reached: the draw decided (u 0.1 is below both)
        keys = [name for name, _ in fast.state_keys]
        assert nxt[keys.index("hit")] == float(flag)
        assert nxt[keys.index("hit2")] == float(act == go)


@needs_cc
def test_discrete_records_every_case_and_normal_its_deviation_plus_2(tmp_path: Path) -> None:
    """A Discrete records each case's probability (not the cumulative
    ones, and all of them whichever case is drawn); a Normal(m, v) records
    sqrt(v) + 2 (kept apart from probabilities) and is m + sqrt(v) z."""
    sim = model_of(tmp_path, SEMANTICS, "sem_inst")
    fast, c = both(sim)
    keys = [name for name, _ in fast.state_keys]
    s = _sem_state(fast)
    for u0, want in ((0.1, 0), (0.2, 1), (0.69, 1), (0.7, 2), (0.999, 2)):
        u, z = [u0, 0.5, 0.5], [-1.5]
        nxt, r, done, slots = c.step(s, fast.noop, u, z)
        assert_same((nxt, r, done), fast.step(s, fast.noop, Draws(u, z)))
        assert [slots[i] for i in SLOT_LVL] == [0.2, 0.5, 0.3]
        assert nxt[keys.index("lvl")] == want
        assert slots[SLOT_Y] == 4.0  # sqrt(4) + 2
        assert nxt[keys.index("y")] == 2.5 + 2.0 * -1.5


@needs_cc
def test_enum_tables_if_and_switch(tmp_path: Path) -> None:
    """The Discrete's value is read from a table of enum codes; the reward's
    `if` and the `switch` over an enum state take the right branch."""
    sim = model_of(tmp_path, SEMANTICS, "sem_inst")
    fast, c = both(sim)
    assert "[_discrete(" in fast.source
    keys = [name for name, _ in fast.state_keys]
    codes = {"@low": 0, "@mid": 1, "@high": 2}
    for lvl, want_sw, want_r in (("@low", 4, 2.5), ("@mid", 7, 2.5), ("@high", 9, 4.0)):
        s = _sem_state(fast, lvl=codes[lvl], k=4, j=9, x=2.5)
        u, z = [0.5, 0.5, 0.5], [0.0]
        nxt, r, done, _ = c.step(s, fast.noop, u, z)
        assert_same((nxt, r, done), fast.step(s, fast.noop, Draws(u, z)))
        assert nxt[keys.index("sw")] == want_sw
        assert r == want_r


ARITH = """
domain arith {
    requirements = { concurrent };
    pvariables {
        a : { state-fluent, real, default = 0.0 };
        b : { state-fluent, real, default = 0.0 };
        k : { state-fluent, int, default = 0 };
        m : { state-fluent, int, default = 0 };
        dv : { state-fluent, real, default = 0.0 };
        kd : { state-fluent, real, default = 0.0 };
        pw : { state-fluent, real, default = 0.0 };
        kp : { state-fluent, real, default = 0.0 };
        mn : { state-fluent, real, default = 0.0 };
        mx : { state-fluent, int, default = 0 };
        rd : { state-fluent, int, default = 0 };
        fl : { state-fluent, int, default = 0 };
        ce : { state-fluent, int, default = 0 };
        ab : { state-fluent, real, default = 0.0 };
        sg : { state-fluent, real, default = 0.0 };
        ln : { state-fluent, real, default = 0.0 };
        sq : { state-fluent, real, default = 0.0 };
        ex : { state-fluent, real, default = 0.0 };
        ik : { state-fluent, int, default = 0 };
        cmp : { state-fluent, bool, default = false };
        eq : { state-fluent, bool, default = false };
        imp : { state-fluent, bool, default = false };
        avg : { state-fluent, real, default = 0.0 };
    };
    cpfs {
        a' = a; b' = b; k' = k; m' = m;
        dv' = a / b;
        kd' = k / m;
        pw' = pow[a, b];
        kp' = pow[k, m];
        mn' = min[a, k];
        mx' = max[k, m];
        rd' = round[a];
        fl' = floor[a];
        ce' = ceil[a];
        ab' = abs[a];
        sg' = sgn[a];
        ln' = ln[a];
        sq' = sqrt[a];
        ex' = exp[b];
        ik' = a * k;
        cmp' = (a < b) ^ (k >= m);
        eq' = (a == b) <=> (k ~= m);
        imp' = (k > 0) => (a <= b);
        avg' = (a + b + k + m) / 4;
    };
    reward = -a * k + b / 3;
}
instance arith_inst {
    domain = arith;
    init-state { a = 0.0; };
    max-nondef-actions = 0;
    horizon = 5;
    discount = 1.0;
}
"""

# (a, b, k, m): zero divisors (inf, nan), halves (round half to even),
# negatives (floor, ceil, Python's sgn, ln and sqrt of negatives), integer
# powers with negative bases, 0 ** -1, overflow, nan
ARITH_STATES = [
    (a, b, k, m)
    for a, b in [
        (2.5, 0.0), (-2.5, 0.0), (0.0, 0.0), (3.5, 2.0), (-3.5, 3.0), (0.5, -1.0),
        (-0.5, 0.5), (1e3, 800.0), (7.25, 7.25), (float("nan"), 1.0), (4.0, float("inf")),
    ]
    for k, m in [(0, 0), (7, 2), (-7, 2), (0, -1), (-3, 3), (2, 2000)]
]  # fmt: skip


@needs_cc
def test_arithmetic_as_the_python_step(tmp_path: Path) -> None:
    """Division (by zero too), pow, min, max, round, floor, ceil, abs, sgn,
    ln, sqrt, exp, int casts, comparisons and the connectives: the C step's
    values are the Python step's, nan where it gives nan."""
    sim = model_of(tmp_path, ARITH, "arith_inst")
    fast, c = both(sim)
    assert "_div(" in fast.source and "_pow(" in fast.source
    compared = 0
    for a, b, k, m in ARITH_STATES:
        s = (a, b, k, m) + fast.encode_state(sim.initial_state(1))[4:]
        try:
            py = fast.step(s, fast.noop, Draws([], []))
        except ValueError:
            assert math.isnan(a)  # (Python's floor of nan raises; C gives nan)
            continue
        if any(isinstance(v, complex) for v in py[0]):
            continue  # (a negative base to a fractional power: see below)
        assert_same(c.step(s, fast.noop, [], []), py, f"a={a} b={b} k={k} m={m}")
        compared += 1
    assert compared >= 50


@needs_cc
def test_pow_of_a_negative_base_as_the_batched_step(tmp_path: Path) -> None:
    sim = model_of(tmp_path, ARITH, "arith_inst")
    fast, c = both(sim)
    keys = [name for name, _ in fast.state_keys]
    for a, b in ((-8.0, 1 / 3), (-10.0, 401.0)):
        state = sim.initial_state(1)
        state.values["a"][0], state.values["b"][0] = a, b
        out = sim.step(state, sim.noop(1), np.random.default_rng(0), check=False)
        want = float(out.next_state.values["pw"][0])
        s = fast.encode_state(state)
        got_c = c.step(s, fast.noop, [], [])[0][keys.index("pw")]
        np.testing.assert_equal(got_c, want)
        got_py = fast.step(s, fast.noop, Draws([], []))[0][keys.index("pw")]
        np.testing.assert_equal(got_py, want)


@needs_cc
def test_and_or_over_ints_as_the_batched_step(tmp_path: Path) -> None:
    sim = model_of(tmp_path, SEMANTICS, "sem_inst")
    fast = ScalarStep(sim)
    keys = [name for name, _ in fast.state_keys]
    state = sim.initial_state(1)
    state.values["j"][0] = 5
    out = sim.step(state, sim.noop(1), np.random.default_rng(0), check=False)
    assert int(out.next_state.values["andk"][0]) == 1
    nxt, _, _ = fast.step(fast.encode_state(state), fast.noop, np.random.default_rng(0))
    assert nxt[keys.index("andk")] == 1


# -- the translator on hand-written step sources ------------------------------

# Constructs the RDDL writer does not emit today but the translator claims
# (Python's // and %, chained comparisons, tables read by name, `p > U[k]`,
# min/max of three): a step written by hand over the SEMANTICS instance's
# 11 state groundings
HAND_SOURCE = """def _scalar_step(S, A, rng):
    (s0, s1, s2, s3, s4, s5, s6, s7, s8, s9, s10,) = S
    (a0,) = A
    U = rng.random(2).tolist()
    Z = rng.standard_normal(1).tolist()
    t1 = s1 // s2
    t2 = s1 % s2
    t3 = _N0[s4]
    t4 = (s1 and s2) or s3
    t5 = 0 <= s1 < s2 <= 10
    t6 = min(s1, s9, s3)
    t7 = max(s9, s2, s1)
    n0 = (0.4 > U[1])
    n1 = t1
    n2 = t2
    n3 = t3 * 1.5 + int(s3) + float(bool(s1))
    n4 = t4
    n5 = (U[0] < 0.5) if t5 else (0.25 > U[1])
    n6 = t6
    n7 = t7
    n8 = _sgn(s3) + abs(s3) + _floor(s3) + _ceil(s3) + _round(s3)
    n9 = (s3 + _sqrt(s5) * Z[0])
    n10 = (-_inf if a0 else _nan) if s1 == 99 else -s3
    r = (s1 ** 2) - (not a0)
    done = (s1 > 100) or (not (s2 != 7))
    return (n0, n1, n2, n3, n4, n5, n6, n7, n8, n9, n10), r, done
"""


def hand_step(fast: ScalarStep, source: str, **tables: tuple[int, ...]) -> ScalarStep:
    """A copy of `fast` whose step is `source` (state and action tuples of
    the same length), with `tables` read by name."""
    hand = copy.copy(fast)
    hand.source = source
    hand.tables = dict(tables)
    nodes = list(ast.walk(ast.parse(source)))
    hand.n_uniforms = max([n.slice.value + 1 for n in nodes if _is_draw(n, "U")] or [0])
    hand.n_normals = max([n.slice.value + 1 for n in nodes if _is_draw(n, "Z")] or [0])
    ns: dict[str, Any] = dict(_HELPERS)
    ns.update(tables)
    exec(compile(source, "<hand-written step>", "exec"), ns)  # noqa: S102
    hand.step = ns["_scalar_step"]
    return hand


def _is_draw(n: Any, name: str) -> bool:
    return (
        isinstance(n, ast.Subscript)
        and isinstance(n.value, ast.Name)
        and n.value.id == name
        and isinstance(n.slice, ast.Constant)
    )


# (s1, s2, s3, s4, s5, s9): s3 not nan (int(nan) raises in Python), s9 nan
# too (min and max keep Python's first of the smallest)
HAND_STATES = [
    (s1, s2, s3, s4, s5, s9)
    for s1, s2 in [(7, 2), (-7, 2), (7, -2), (-7, -3), (0, 5), (3, 3), (99, 7), (101, 1), (4, 11)]
    for s3 in (-2.5, -0.5, 0.0, 2.5, 3.5)
    for s4, s5 in ((0, 4.0), (2, 0.0), (1, -1.0))
    for s9 in (float("nan"), 1.0, -9.0)
]


@needs_cc
def test_hand_written_source_as_python(tmp_path: Path) -> None:
    """Integer // and % (the sign of the divisor), a table read by name,
    `and`/`or` returning operands, chained comparisons, `p > U[k]`, min and
    max of three (the first of the smallest), the helpers, inf and nan,
    `not`, `**`, a done from `or`: the C step gives the Python step's
    values, and records the draws reached."""
    fast = ScalarStep(model_of(tmp_path, SEMANTICS, "sem_inst"))
    hand = hand_step(fast, HAND_SOURCE, _N0=(1, 2, 5))
    assert (hand.n_uniforms, hand.n_normals) == (2, 1)
    c = CStep(hand)
    base = list(fast.encode_state(fast.sim.initial_state(1)))
    for (s1, s2, s3, s4, s5, s9), go, u in itertools.product(
        HAND_STATES, (False, True), ((0.1, 0.3), (0.9, 0.45))
    ):
        s = list(base)
        s[1:6] = [s1, s2, s3, s4, s5]
        s[9] = s9
        st = tuple(s)
        act = (go,)
        py = hand.step(st, act, Draws(list(u), [0.7]))
        nxt, r, done, slots = c.step(st, act, list(u), [0.7])
        assert_same((nxt, r, done), py, f"{st} {act} {u}")
        # slot 0: `0.4 > U[1]`; then `U[0] < 0.5` or `0.25 > U[1]`, as the
        # chained comparison decides; then the normal's deviation + 2
        t5 = 0 <= s1 < s2 <= 10
        assert slots[0] == 0.4
        assert slots[1:3] == ([0.5, -1.0] if t5 else [-1.0, 0.25])
        if s5 >= 0:
            assert slots[3] == math.sqrt(s5) + 2.0
        else:
            assert math.isnan(slots[3])


@needs_cc
def test_float_floor_division_as_python(tmp_path: Path) -> None:
    fast = ScalarStep(model_of(tmp_path, SEMANTICS, "sem_inst"))
    source = HAND_SOURCE.replace("t1 = s1 // s2", "t1 = s3 // 0.1")
    hand = hand_step(fast, source, _N0=(1, 2, 5))
    c = CStep(hand)
    s = list(fast.encode_state(fast.sim.initial_state(1)))
    s[1:6] = [7, 2, 1.0, 0, 4.0]
    py = hand.step(tuple(s), (False,), Draws([0.5, 0.5], [0.0]))
    assert py[0][1] == 9.0
    assert_same(c.step(tuple(s), (False,), [0.5, 0.5], [0.0]), py)


@needs_cc
@pytest.mark.parametrize(
    "line,why",
    [
        ("t1 = s1 << s2", "s1 << s2"),
        ("t1 = math.floor(s1)", "math.floor"),
        ("t1 = U[0] + s1", "a draw in arithmetic"),
        ("t1 = _unknown(s1)", "_unknown"),
        ("t1 = [s1][0]", "[s1][0]"),
        ("t1 = s1 if U[0] else s2", "a draw read directly"),
    ],
)
def test_an_unknown_construct_is_unavailable(tmp_path: Path, line: str, why: str) -> None:
    """The translator names what it cannot write (`CUnavailable`), and
    nothing is compiled."""
    fast = ScalarStep(model_of(tmp_path, SEMANTICS, "sem_inst"))
    source = HAND_SOURCE.replace("t1 = s1 // s2", line)
    hand = copy.copy(fast)
    hand.source = source
    hand.tables = {"_N0": (1, 2, 5)}
    hand.n_uniforms, hand.n_normals = 2, 1
    with pytest.raises(CUnavailable, match="cannot translate") as err:
        c_source(hand)
    assert why in str(err.value)


# -- CUnavailable -----------------------------------------------------------------


def sysadmin_step() -> ScalarStep:
    return ScalarStep(Simulator(load_pair(*ippc_files("IPPC2011", "SysAdmin", 1))))


def test_a_failing_compiler_is_unavailable(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """CC=false (found, but every build fails) with an empty cache: the
    error names the compiler; nothing is left in the cache."""
    monkeypatch.setenv("IPPC_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("CC", "false")
    assert find_compiler() == "false"
    with pytest.raises(CUnavailable, match="false failed"):
        CStep(sysadmin_step())
    assert list((tmp_path / "cache" / "cstep").iterdir()) == []


@pytest.mark.parametrize("how", ["CC", "which"])
def test_no_compiler_is_unavailable(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, how: str
) -> None:
    """CC naming a program that does not exist, or none of cc, gcc and
    clang on the path: no compiler."""
    monkeypatch.setenv("IPPC_CACHE", str(tmp_path / "cache"))
    if how == "CC":
        monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    else:
        monkeypatch.delenv("CC", raising=False)
        monkeypatch.setattr(cbuild.shutil, "which", lambda _name: None)
    assert find_compiler() is None
    with pytest.raises(CUnavailable, match="no C compiler"):
        CStep(sysadmin_step())


def counting_cc(folder: Path) -> tuple[str, Path]:
    """A compiler that counts its runs in a file, then runs the real one."""
    real = find_compiler()
    assert real is not None
    count = folder / "runs"
    script = folder / "counting-cc"
    script.write_text(f'#!/bin/sh\necho run >> "{count}"\nexec {real} "$@"\n')
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    return str(script), count


def runs(count: Path) -> int:
    return len(count.read_text().splitlines()) if count.exists() else 0


@needs_cc
def test_a_second_cstep_loads_the_cached_library(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The compiler runs once per instance: a second CStep on the same
    instance loads the library the first one built (the same file);
    another instance builds its own; no source or partial file is left."""
    cc, count = counting_cc(tmp_path)
    monkeypatch.setenv("CC", cc)
    monkeypatch.setenv("IPPC_CACHE", str(tmp_path / "cache"))
    first = CStep(sysadmin_step())
    assert runs(count) == 1
    second = CStep(sysadmin_step())
    assert runs(count) == 1
    assert second.path == first.path
    assert first.path.parent == tmp_path / "cache" / "cstep"
    other = CStep(ScalarStep(Simulator(load_pair(*ippc_files("IPPC2011", "SysAdmin", 2)))))
    assert runs(count) == 2 and other.path != first.path
    assert sorted(p.suffix for p in first.path.parent.iterdir()) == [".so", ".so"]
    # and it steps
    s = first.scalar.encode_state(first.scalar.sim.initial_state(1))
    assert_same(
        second.step(s, second.scalar.noop, [0.5] * second.nu, [0.0]),
        first.scalar.step(s, first.scalar.noop, Draws([0.5] * 20, [])),
    )


@needs_cc
def test_an_unwritable_cache_falls_back_to_a_private_temporary_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """cstep/ cannot be made under a file: the build goes to a fresh
    folder of tempfile's (mode 0700, this user's), the same one for the
    rest of the process."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("IPPC_CACHE", str(blocker))
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    monkeypatch.setattr(cbuild, "_TEMP", None)
    (tmp_path / "tmp").mkdir()
    c = CStep(sysadmin_step())
    folder = c.path.parent
    assert folder.parent == tmp_path / "tmp" and folder.name.startswith("ippc-cstep-")
    st = folder.stat()
    assert stat.S_IMODE(st.st_mode) == 0o700 and st.st_uid == os.getuid()
    assert CStep(sysadmin_step()).path == c.path


def test_the_default_cache_is_under_home_and_private(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """~/.cache/ippc/cstep, created mode 0700 (and its new parent too)."""
    monkeypatch.delenv("IPPC_CACHE", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))
    folder = cbuild.cache_dir()
    assert folder == tmp_path / ".cache" / "ippc" / "cstep"
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    assert stat.S_IMODE(folder.parent.stat().st_mode) == 0o700


PLANTED = r"""
#include <stdio.h>
__attribute__((constructor)) static void planted(void) {
    FILE *f = fopen(MARK, "w");
    if (f) { fputs("loaded", f); fclose(f); }
}
"""


def plant(folder: Path, scalar: ScalarStep, mark: Path) -> Path:
    """A library at the very name the step's build would load, which writes
    `mark` when it is loaded."""
    cc = find_compiler()
    assert cc is not None
    digest = hashlib.sha256((cc + "\0" + c_source(scalar)).encode()).hexdigest()[:24]
    lib = folder / f"step-{digest}.so"
    src = folder.parent / "planted.c"
    src.write_text(PLANTED)
    subprocess.run(
        [*cc.split(), "-shared", "-fPIC", f'-DMARK="{mark}"', "-o", str(lib), str(src)],
        check=True,
    )
    return lib


@needs_cc
@pytest.mark.parametrize("wrong", ["mode 0777", "mode 0720", "owner", "symlink"])
def test_a_planted_cache_folder_is_refused_and_its_library_never_loaded(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
    wrong: str,
) -> None:
    """Another user made the cache folder first (writable by others, owned
    by someone else, or a link to a folder elsewhere) and put a library
    there under the name the build would load: the folder is refused with
    a warning naming it, the step is built in a private temporary folder,
    and the planted library is never loaded (it would write a mark)."""
    base = tmp_path / "cache"
    base.mkdir(mode=0o700)
    folder = base / "cstep"
    elsewhere = tmp_path / "elsewhere"
    (elsewhere if wrong == "symlink" else folder).mkdir()
    if wrong == "symlink":
        elsewhere.chmod(0o700)
        folder.symlink_to(elsewhere)
    scalar = sysadmin_step()
    mark = tmp_path / "mark"
    planted = plant(folder, scalar, mark)
    if wrong.startswith("mode"):
        folder.chmod(int(wrong.split()[1], 8))
    elif wrong == "owner":  # (as if another uid owned it)
        folder.chmod(0o700)
        uid = os.getuid()
        monkeypatch.setattr(cbuild, "_uid", lambda: uid + 1)
        if uid == 0:  # root can make it so for real
            monkeypatch.setattr(cbuild, "_uid", lambda: 0)
            os.chown(folder, 12345, -1)
    monkeypatch.setenv("IPPC_CACHE", str(base))
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    monkeypatch.setattr(cbuild, "_TEMP", None)
    monkeypatch.setattr(cbuild, "_REFUSED", set())
    (tmp_path / "tmp").mkdir()
    with caplog.at_level("WARNING", logger="ippc.rddl.sim.cbuild"):
        c = CStep(scalar)
    assert not mark.exists()
    assert c.path != planted and c.path.parent.parent == tmp_path / "tmp"
    assert "cache folder refused" in caplog.text and str(folder) in caplog.text
    # and the step it built works
    s = scalar.encode_state(scalar.sim.initial_state(1))
    assert_same(
        c.step(s, scalar.noop, [0.5] * c.nu, [0.0]),
        scalar.step(s, scalar.noop, Draws([0.5] * 20, [])),
    )


@needs_cc
def test_a_planted_library_in_the_private_folder_is_not_loaded(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A library of the cache that others may write (mode 0666) is not
    loaded: it is built again in its place."""
    base = tmp_path / "cache"
    monkeypatch.setenv("IPPC_CACHE", str(base))
    folder = cbuild.cache_dir()
    scalar = sysadmin_step()
    mark = tmp_path / "mark"
    planted = plant(folder, scalar, mark)
    planted.chmod(0o666)
    c = CStep(scalar)
    assert not mark.exists()
    assert c.path == planted and stat.S_IMODE(planted.stat().st_mode) == 0o700


def c_files() -> list[Path]:
    """The C files of the package (rddl/sim/csrc, planners/mcts/csrc)."""
    ours = Path(cbuild.__file__).with_name("csrc")
    theirs = Path(ckernels.__file__).with_name("csrc")
    return sorted(ours.glob("*.c")) + sorted(theirs.glob("*.c"))


STRICT = ["-Wall", "-Wextra", "-Werror"]


def test_the_c_files_compile_without_a_warning(tmp_path: Path) -> None:
    """Each C file of the package alone (csrc/step.h standing in for the
    generated step), and whole units as a session builds them (the step of
    several instances with mcts's kernels and tree), with -Wall -Wextra
    -Werror: CI fails on a warning."""
    cc = find_compiler()
    if cc is None:
        pytest.skip("no C compiler (cc, gcc, clang or $CC): the C files are not checked")

    files = c_files()
    assert {f.name for f in files} >= {"step_api.c", "kernels.c", "tree.c"}
    units = [(f.parent, f) for f in files]
    for i, (year, domain) in enumerate(
        [("IPPC2011", "SysAdmin"), ("IPPC2018", "AcademicAdvising"), ("IPPC2014", "Wildfire")]
    ):
        scalar = ScalarStep(Simulator(load_pair(*ippc_files(year, domain, 1))))
        unit = tmp_path / f"unit{i}.c"
        unit.write_text(c_source(scalar, kernel_source()))
        units.append((tmp_path, unit))
    for cwd, f in units:
        cmd = [*cc.split(), "-O1", "-fPIC", "-c", *STRICT, "-o", os.devnull, str(f)]
        done = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, check=False)
        assert done.returncode == 0, f"{f.name}: {done.stderr[:2000]}"


def test_which_is_the_compiler(monkeypatch: pytest.MonkeyPatch) -> None:
    """$CC first (with its flags kept), else the first of cc, gcc, clang."""
    monkeypatch.setattr(
        cbuild.shutil, "which", lambda name: f"/bin/{name}" if name != "cc" else None
    )
    monkeypatch.setenv("CC", "gcc -m64")
    assert find_compiler() == "gcc -m64"
    monkeypatch.delenv("CC")
    assert find_compiler() == "gcc"
