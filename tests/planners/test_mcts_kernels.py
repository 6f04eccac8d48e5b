"""mcts's search kernels (planners/mcts/csrc/kernels.c, driven through
`ippc.planners.mcts.ckernels.Kernels`) against Python: `probe`
(deterministic actions, equivalent ones dropped, the same-reward flag),
`ids_values` against a brute-force IDS in Python, `walk` and `sample`
against the Python step fed the C generator's draws (splitmix64 written
again here). The libraries go to the run's temporary folder
(tests/conftest.py sets IPPC_CACHE)."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ippc.planners.mcts.ckernels import Kernels
from ippc.rddl import load_pair
from ippc.rddl.sim.scalar import ScalarStep
from ippc.rddl.simulator import Simulator

from ..conftest import ippc_files
from ..rddl.test_cstep import Draws, assert_same, model_of, needs_cc


def both(sim: Simulator) -> tuple[ScalarStep, Kernels]:
    fast = ScalarStep(sim)
    return fast, Kernels(fast)


# -- probe ---------------------------------------------------------------------

PROBE = """
domain probe_d {
    requirements = { concurrent };
    pvariables {
        p : { state-fluent, real, default = 1.0 };
        v : { state-fluent, real, default = 0.0 };
        lit : { state-fluent, bool, default = false };
        y : { state-fluent, real, default = 0.0 };
        coin : { interm-fluent, bool };
        press-a : { action-fluent, bool, default = false };
        press-b : { action-fluent, bool, default = false };
        press-c : { action-fluent, bool, default = false };
        press-d : { action-fluent, bool, default = false };
        sure : { action-fluent, bool, default = false };
        twin : { action-fluent, bool, default = false };
        nudge : { action-fluent, bool, default = false };
        flip : { action-fluent, bool, default = false };
    };
    cpfs {
        coin = flip ^ Bernoulli(0.5);
        // a and b: the same probability; c another one; d the same as a
        // but with a cost; sure and twin: the probability p (a state fluent)
        lit' = if (press-a | press-b | press-d) then Bernoulli(0.7)
               else if (press-c) then Bernoulli(0.6)
               else if (sure | twin) then Bernoulli(p)
               else lit;
        // nudge: a normal of variance v (a state fluent)
        y' = if (nudge) then Normal(y + 1.0, v) else y;
        p' = p;
        v' = v;
    };
    reward = lit - 0.5 * press-d + coin;
}
instance probe_inst {
    domain = probe_d;
    init-state { p = 1.0; };
    max-nondef-actions = 1;
    horizon = 5;
    discount = 1.0;
}
"""

PROBE_ACTIONS = [
    "noop",
    "press-a",
    "press-b",
    "press-c",
    "press-d",
    "sure",
    "twin",
    "nudge",
    "flip",
]


def probe_setup(tmp_path: Path) -> tuple[Simulator, ScalarStep, Kernels, list[tuple[Any, ...]]]:
    sim = model_of(tmp_path, PROBE, "probe_inst")
    fast, c = both(sim)
    acts = []
    for name in PROBE_ACTIONS:
        a = sim.noop(1)
        if name != "noop":
            a[name][0] = True
        acts.append(fast.encode_actions(a))
    return sim, fast, c, acts


@needs_cc
@pytest.mark.parametrize("p,v", [(1.0, 0.0), (0.5, 1.0)])
def test_probe_deterministic_equivalent_and_same_reward(tmp_path: Path, p: float, v: float) -> None:
    """noop is deterministic (no site reached); press-a is not; press-b is
    press-a again (the same probability, successors and rewards) but
    stochastic: kept, as only deterministic actions merge; press-c (another
    probability) and press-d (another reward) are kept; sure (Bernoulli(p))
    and nudge (Normal(., v)) are deterministic exactly when p is 1 and v is
    0; twin is sure again, dropped when deterministic (p = 1), else kept;
    flip's reward is drawn (an interm Bernoulli): its two probes' rewards
    differ."""
    sim, fast, c, acts = probe_setup(tmp_path)
    state = fast.encode_state(sim.initial_state(1))
    keys = [name for name, _ in fast.state_keys]
    state = tuple(p if k == "p" else v if k == "v" else x for k, x in zip(keys, state, strict=True))
    # every uniform 0.1 in the first probe (each Bernoulli true), 0.9 in
    # the second (each false)
    draws = (
        *c.draw_block([0.1] * c.nu, [0.3] * c.nz),
        *c.draw_block([0.9] * c.nu, [-0.3] * c.nz),
    )
    out = c.probe(state, c.block(acts), len(acts), draws)
    kept = {PROBE_ACTIONS[row]: rest for row, *rest in out}
    certain = p == 1.0 and v == 0.0
    dropped = {"twin"} if p == 1.0 else set()
    assert [PROBE_ACTIONS[row] for row, *_ in out] == [a for a in PROBE_ACTIONS if a not in dropped]
    det = {name: k[0] for name, k in kept.items()}
    assert det == {
        "noop": True,
        "press-a": False,
        "press-b": False,
        "press-c": False,
        "press-d": False,
        "sure": certain,
        **({} if p == 1.0 else {"twin": False}),
        "nudge": certain,
        "flip": False,
    }
    same_r = {name: k[4] for name, k in kept.items()}
    assert same_r == {name: name != "flip" for name in kept}
    # the first probe's successor, reward and done are the Python step's
    # with its draws
    for name, (_, s1, r1, d1, _) in kept.items():
        act = acts[PROBE_ACTIONS.index(name)]
        py = fast.step(state, act, Draws([0.1] * c.nu, [0.3] * c.nz))
        assert_same((s1, r1, d1), py, name)
    assert kept["flip"][2] == 1.0  # the coin came up in the first probe


@needs_cc
def test_probe_of_no_action_and_one(tmp_path: Path) -> None:
    sim, fast, c, acts = probe_setup(tmp_path)
    state = fast.encode_state(sim.initial_state(1))
    draws = (*c.draw_block([0.1], [0.0]), *c.draw_block([0.9], [0.0]))
    assert c.probe(state, c.block([]), 0, draws) == []
    (only,) = c.probe(state, c.block(acts[1:2]), 1, draws)
    assert only[0] == 0 and only[1] is False


# -- ids_values ------------------------------------------------------------------

_TOKENS = itertools.count(10**12)  # (apart from the planner's tokens)


def sysadmin_actions(sim: Simulator, fast: ScalarStep) -> list[tuple[Any, ...]]:
    """noop and every single reboot (SysAdmin #1: max-nondef-actions 1)."""
    acts = [fast.noop]
    for i in range(len(fast.noop)):
        a = sim.noop(1)
        a["reboot"][0, i] = True
        acts.append(fast.encode_actions(a))
    return acts


def brute_ids(
    fast: ScalarStep, acts: list[tuple[Any, ...]], gamma: float
) -> Callable[[tuple[Any, ...], tuple[Any, ...], int], float]:
    """An action's IDS value on the most-likely determinisation (every
    uniform 0.5, every normal 0), by plain recursion over `acts`."""
    likely = Draws([0.5] * fast.n_uniforms, [0.0] * fast.n_normals)
    memo: dict[tuple[Any, ...], float] = {}

    def best(state: tuple[Any, ...], depth: int) -> float:
        key = (state, depth)
        if key not in memo:
            memo[key] = max(value(state, a, depth) for a in acts)
        return memo[key]

    def value(state: tuple[Any, ...], act: tuple[Any, ...], depth: int) -> float:
        nxt, r, done = fast.step(state, act, likely)
        if done or depth <= 1:
            return r
        return r + gamma * best(nxt, depth - 1)

    return value


@needs_cc
def test_ids_values_equal_a_brute_force_ids() -> None:
    """SysAdmin #1 (11 candidates), depths 1-3, discount 1 and 0.9, from
    the initial state and from one with computers down: each action's
    value is the brute-force recursion's; another token clears the cache
    (the values of another discount are not reused), the same token reuses
    it (only the kept actions are stepped again)."""
    sim = Simulator(load_pair(*ippc_files("IPPC2011", "SysAdmin", 1)))
    fast, c = both(sim)
    acts = sysadmin_actions(sim, fast)
    cands = c.block(acts)
    kept = acts[:4]
    start = fast.encode_state(sim.initial_state(1))
    down = tuple(bool(i % 3) for i in range(len(start)))
    for gamma, state, depth in itertools.product((1.0, 0.9), (start, down), (1, 2, 3)):
        value = brute_ids(fast, acts, gamma)
        want = [value(state, a, depth) for a in kept]
        token = next(_TOKENS)
        got, made = c.ids_values(
            state, c.block(kept), len(kept), cands, len(acts), depth, gamma, token
        )
        assert got == pytest.approx(want, rel=1e-9), (gamma, depth)
        assert made >= len(kept) + (0 if depth == 1 else len(acts))
        again, made2 = c.ids_values(
            state, c.block(kept), len(kept), cands, len(acts), depth, gamma, token
        )
        assert again == got and made2 == len(kept)  # every successor's value cached
    # the same token with another discount: the cache (discount 0.5) is kept,
    # so the values are not discount 1's; another token clears it
    value = brute_ids(fast, acts, 1.0)
    want = [value(down, a, 3) for a in kept]
    token = next(_TOKENS)
    c.ids_values(down, c.block(kept), len(kept), cands, len(acts), 3, 0.5, token)
    stale, _ = c.ids_values(down, c.block(kept), len(kept), cands, len(acts), 3, 1.0, token)
    assert stale != pytest.approx(want, rel=1e-9)
    fresh, _ = c.ids_values(down, c.block(kept), len(kept), cands, len(acts), 3, 1.0, next(_TOKENS))
    assert fresh == pytest.approx(want, rel=1e-9)
    # ids_clear empties it too
    c.ids_values(down, c.block(kept), len(kept), cands, len(acts), 3, 0.5, token)
    c.ids_clear()
    cleared, _ = c.ids_values(down, c.block(kept), len(kept), cands, len(acts), 3, 1.0, token)
    assert cleared == pytest.approx(want, rel=1e-9)


# -- walk and sample: the C generator's draws, fed to the Python step -----------

MASK = 2**64 - 1


class SplitMix:
    """cstep's generator (splitmix64), its uniforms and its Box-Muller
    normals, written again: the draws the C kernels make."""

    def __init__(self, seed: int):
        self.state = seed & MASK

    def next64(self) -> int:
        self.state = (self.state + 0x9E3779B97F4A7C15) & MASK
        z = self.state
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK
        return z ^ (z >> 31)

    def unif(self) -> float:
        return (self.next64() >> 11) * 2.0**-53

    def draws(self, nu: int, nz: int) -> tuple[list[float], list[float]]:
        u = [self.unif() for _ in range(nu)]
        z = [0.0] * nz
        for i in range(0, nz, 2):
            u1, u2 = self.unif(), self.unif()
            r = math.sqrt(-2.0 * math.log(1.0 - u1))
            z[i] = r * math.cos(2 * math.pi * u2)
            if i + 1 < nz:
                z[i + 1] = r * math.sin(2 * math.pi * u2)
        return u, z


def walk_by_hand(
    fast: ScalarStep,
    c: Kernels,
    state: tuple[Any, ...],
    n: int,
    pool: list[tuple[Any, ...]] | None,
    gamma: float,
    seed: int,
) -> tuple[float, int, bool, int]:
    """`Kernels.walk` with the Python step: (return, steps, ended, the
    generator's state after)."""
    g = SplitMix(seed)
    total, disc, taken = 0.0, 1.0, 0
    for _ in range(n):
        act = pool[g.next64() % len(pool)] if pool else fast.noop
        u, z = g.draws(c.nu, c.nz)
        state, r, done = fast.step(state, act, Draws(u, z))
        total += disc * r
        disc *= gamma
        taken += 1
        if done:
            return total, taken, True, g.state
    return total, taken, False, g.state


NORMALS = """
domain drift {
    requirements = { concurrent };
    pvariables {
        x : { state-fluent, real, default = 0.0 };
        w : { state-fluent, real, default = 0.0 };
        on : { state-fluent, bool, default = false };
        push : { action-fluent, bool, default = false };
    };
    cpfs {
        x' = Normal(x + push, 1.0);
        w' = Normal(w, 0.25 + on);
        on' = Bernoulli(0.3 + 0.4 * push);
    };
    reward = -abs[x] + on;
    termination { x > 2.5; };
}
instance drift_inst {
    domain = drift;
    init-state { x = 0.0; };
    max-nondef-actions = 1;
    horizon = 30;
    discount = 0.95;
}
"""


@needs_cc
@pytest.mark.parametrize("seed", [1, 12345, 2**63 + 7])
def test_walk_and_sample_are_the_python_step_with_the_c_draws(tmp_path: Path, seed: int) -> None:
    """A noop walk and a walk over a pool of actions, on SysAdmin #1
    (uniforms only) and on a domain with normals and termination: the
    return, the steps taken, whether the run ended and the generator's
    state after are those of the Python step fed the same draws; so is a
    sampled transition."""
    sysadmin = Simulator(load_pair(*ippc_files("IPPC2011", "SysAdmin", 1)))
    drift = model_of(tmp_path, NORMALS, "drift_inst")
    ended_any = False
    for sim in (sysadmin, drift):
        fast, c = both(sim)
        acts = (
            sysadmin_actions(sim, fast)
            if sim is sysadmin
            else [fast.noop, fast.encode_actions({"push": np.array([True])})]
        )
        state = fast.encode_state(sim.initial_state(1))
        for pool, n in ((None, 25), (acts, 25), (acts, 1), (None, 0)):
            c.rng.value = seed & MASK
            block = c.block(pool) if pool else None
            got = c.walk(state, n, block, len(pool) if pool else 0, 0.95)
            total, taken, ended, after = walk_by_hand(fast, c, state, n, pool, 0.95, seed)
            assert got[1:] == (taken, ended)
            assert got[0] == pytest.approx(total, rel=1e-9, abs=1e-12)
            assert c.rng.value == after
            ended_any |= ended
        c.rng.value = seed & MASK
        g = SplitMix(seed)
        for act in acts:
            u, z = g.draws(c.nu, c.nz)
            assert_same(c.sample(state, act), fast.step(state, act, Draws(u, z)))
        assert c.rng.value == g.state
    assert ended_any or seed != 1  # (seed 1: the drift passes 2.5 within 25 steps)


COUNTDOWN = """
domain countdown {
    requirements = { concurrent };
    pvariables {
        k : { state-fluent, int, default = 0 };
        skip : { action-fluent, bool, default = false };
    };
    cpfs {
        k' = k + 1 + skip;
    };
    reward = k;
    termination { k >= 3; };
}
instance countdown_inst {
    domain = countdown;
    init-state { k = 0; };
    max-nondef-actions = 1;
    horizon = 10;
    discount = 1.0;
}
"""


@needs_cc
def test_walk_stops_at_termination_with_the_exact_return(tmp_path: Path) -> None:
    """Deterministic: from k = 0 the noop walk ends after 3 steps (k' = 3)
    with rewards 0, 1, 2; a walk of 2 steps does not end; a pool of `skip`
    alone ends after 2 steps (0 + 2)."""
    sim = model_of(tmp_path, COUNTDOWN, "countdown_inst")
    fast, c = both(sim)
    s0 = fast.encode_state(sim.initial_state(1))
    assert c.walk(s0, 10, None, 0, 1.0) == (3.0, 3, True)
    assert c.walk(s0, 10, None, 0, 0.5) == (0 + 0.5 * 1 + 0.25 * 2, 3, True)
    assert c.walk(s0, 2, None, 0, 1.0) == (1.0, 2, False)
    skip = [fast.encode_actions({"skip": np.array([True])})]
    assert c.walk(s0, 10, c.block(skip), 1, 1.0) == (2.0, 2, True)
    assert c.walk((5,), 4, None, 0, 1.0) == (5.0, 1, True)
