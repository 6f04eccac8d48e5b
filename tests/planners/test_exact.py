"""Exact values by value iteration (ippc.planners.exact): hand-computed
values on tiny domains, IPPC instances against the simulator's own draws,
and the models it refuses."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ippc.planners.exact import ExactUnsupported, Solution, probability_model, solve
from ippc.rddl import load, load_pair
from ippc.rddl.model import Model
from ippc.rddl.simulator import Simulator

from ..conftest import corpus_root

TINY = Path(__file__).resolve().parent / "tiny_domains"

COIN = """
domain coin {
    requirements = { concurrent };
    pvariables {
        on : { state-fluent, bool, default = false };
        flip : { action-fluent, bool, default = false };
    };
    cpfs {
        on' = if (flip) then Bernoulli(0.8) else KronDelta(on);
    };
    reward = on;
}
instance coin_inst {
    domain = coin;
    max-nondef-actions = 1;
    horizon = 3;
    discount = 1.0;
}
"""


def model_of(tmp_path: Path, text: str, name: str) -> Model:
    f = tmp_path / "m.rddl"
    f.write_text(text)
    return load(f)[name]


def test_coin_values_by_hand(tmp_path: Path) -> None:
    # reward is read in the current state. With k steps left, V_k(on) = k
    # (never flip); V_1(off) = 0, V_2(off) = 0.8 (flip), V_3(off) = max(0.8,
    # 0.8 * 2 + 0.2 * 0.8) = 1.76 (flip at once).
    sol = solve(model_of(tmp_path, COIN, "coin_inst"))
    assert len(sol.bits) == 2 and sol.actions["flip"].tolist() == [False, True]
    assert sol.initial_value == pytest.approx(1.76, abs=1e-12)
    off = sol.simulator.initial_state(1)
    assert sol.q[3][sol.index(off)].tolist() == pytest.approx([0.8, 1.76])
    assert sol.regret(3, off, {"flip": np.array([False])}) == pytest.approx(0.96)
    assert sol.regret(3, off, {"flip": np.array([True])}) == 0.0
    # noop forever from off: nothing
    assert sol.policy_value(np.zeros(len(sol.bits), dtype=np.int64)) == 0.0


def test_trap_composes_a_draw_inside_a_conjunction() -> None:
    # dead' = dead | (risky ^ Bernoulli(0.1)): safe (5) every step but the
    # last, risky (6) then: 9 * 5 + 6 = 51. Risky first: 6 + 0.9 * 46 + 0.1 *
    # (-20 * 9) = 29.4; noop first: 0 + 46.
    model = load(TINY / "trap.rddl")["tiny_trap_inst"]
    sol = solve(model)
    assert sol.initial_value == pytest.approx(51.0)
    noop, risky, safe = sol.q[10][0]
    assert (noop, risky, safe) == pytest.approx((46.0, 29.4, 51.0))
    assert sol.q[1][0].tolist() == pytest.approx([0.0, 6.0, 5.0])


def test_probability_model_states_the_probability_of_each_fluent() -> None:
    model = load(TINY / "trap.rddl")["tiny_trap_inst"]
    pm = probability_model(model)
    sim = Simulator(pm)
    state = sim.initial_state(3)
    acts = {"risky": np.array([False, True, False]), "safe": np.array([False, False, True])}
    out = sim.step(state, acts, np.random.default_rng(0), check=False)
    assert out.next_state.values["dead__prob-true"].tolist() == pytest.approx([0.0, 0.1, 0.0])


def optimal_returns(sol: Solution, episodes: int, seed: int) -> np.ndarray:
    """Round rewards of the exact policy played on the real simulator."""
    sim = sol.simulator
    rng = np.random.default_rng(seed)
    state = sim.initial_state(episodes)
    total = np.zeros(episodes)
    horizon = sol.model.horizon
    assert horizon is not None
    for t in range(horizon):
        out = sim.step(state, sol.best(horizon - t, state), rng)
        total += out.reward
        state = out.next_state
    return total


def check_against_sampling(sol: Solution, episodes: int) -> None:
    returns = optimal_returns(sol, episodes, seed=1)
    se = returns.std(ddof=1) / np.sqrt(episodes)
    # 4 standard errors: a wrong probability model is off by far more
    assert abs(returns.mean() - sol.initial_value) < 4 * se, (returns.mean(), sol.initial_value, se)


@pytest.fixture(scope="module")
def corpus_dir() -> Path:
    root = corpus_root()
    return root


def competition(corpus_dir: Path, folder: str) -> Model:
    f = corpus_dir / "archive" / "competitions" / folder
    return load_pair(f / "domain.rddl", f / "instance1.rddl")


def test_elevators_one(corpus_dir: Path) -> None:
    """Elevators #1 (IPPC 2011): 144 reachable states. The optimum and
    noop's value agree to 1e-12 with a dynamic program written by hand for
    this instance (the only arrivals are at f1), outside the repository."""
    sol = solve(competition(corpus_dir, "IPPC2011/Elevators/MDP"))
    assert len(sol.bits) == 144
    assert sol.initial_value == pytest.approx(-44.05413676573477, abs=1e-9)
    noop = sol.policy_value(np.zeros(len(sol.bits), dtype=np.int64))
    assert noop == pytest.approx(-66.35899445292712, abs=1e-9)
    check_against_sampling(sol, 2000)


@pytest.mark.slow
@pytest.mark.parametrize(
    "folder,states,optimum",
    [
        ("IPPC2011/SysAdmin/MDP", 1024, 342.68046367996834),
        ("IPPC2011/GameOfLife/MDP", 512, 209.43490392000336),
        ("IPPC2011/CrossingTraffic/MDP", 80, -4.428571428571428),
        ("IPPC2011/Navigation/MDP", 13, -9.566934764385223),
    ],
)
def test_ippc_instance_one_against_sampling(
    corpus_dir: Path, folder: str, states: int, optimum: float
) -> None:
    sol = solve(competition(corpus_dir, folder))
    assert len(sol.bits) == states
    assert sol.initial_value == pytest.approx(optimum, rel=1e-9)
    check_against_sampling(sol, 1000)


@pytest.mark.parametrize(
    "cpf,why",
    [
        ("on' = Bernoulli(if (Bernoulli(0.5)) then 0.2 else 0.4);", "probability draws"),
        ("on' = Bernoulli(0.5) == on;", "a draw inside binary '=='"),
        # the next state of another fluent: the fluents are not independent
        ("on' = Bernoulli(0.5);\n        off' = ~on';", "off' reads the next state \\(on'\\)"),
    ],
)
def test_refuses_what_it_cannot_enumerate(tmp_path: Path, cpf: str, why: str) -> None:
    text = COIN.replace("on' = if (flip) then Bernoulli(0.8) else KronDelta(on);", cpf)
    if "off'" in cpf:
        text = text.replace(
            "on : { state-fluent, bool, default = false };",
            "on : { state-fluent, bool, default = false };\n"
            "        off : { state-fluent, bool, default = true };",
        )
    with pytest.raises(ExactUnsupported, match=why):
        solve(model_of(tmp_path, text, "coin_inst"))


def test_refuses_an_int_state_fluent(tmp_path: Path) -> None:
    text = (
        COIN.replace(
            "on : { state-fluent, bool, default = false };",
            "on : { state-fluent, bool, default = false };\n"
            "        n : { state-fluent, int, default = 0 };",
        )
        .replace("reward = on;", "n' = n + 1;\n    };\n    reward = on;")
        .replace("KronDelta(on);\n    };", "KronDelta(on);")
    )
    with pytest.raises(ExactUnsupported, match="state fluent n is int"):
        solve(model_of(tmp_path, text, "coin_inst"))


def test_refuses_too_many_states(corpus_dir: Path) -> None:
    with pytest.raises(ExactUnsupported, match="more than 100 reachable states"):
        solve(competition(corpus_dir, "IPPC2011/SysAdmin/MDP"), max_states=100)


RANDOM_CONDITION = """
domain rc {
    requirements = { concurrent };
    types { idx : object; };
    pvariables {
        a : { state-fluent, bool, default = false };
        b : { state-fluent, bool, default = false };
        c : { state-fluent, bool, default = false };
    };
    cpfs {
        a' = if (Bernoulli(0.5)) then Bernoulli(0.3) else KronDelta(b);
        b' = Bernoulli(0.5) ^ ~Bernoulli(0.2);
        c' = (exists_{?i : idx} [Bernoulli(0.1)]) => Bernoulli(0.6);
    };
    reward = 0;
}
instance rc_inst {
    domain = rc;
    objects { idx : {i1, i2, i3}; };
    horizon = 2;
    discount = 1.0;
}
"""


def test_composed_probabilities_match_the_simulator_draws(tmp_path: Path) -> None:
    """A draw in an if's condition, in a conjunction with a negated draw, and
    in an exists under an implication: the rewritten model's probabilities
    equal the frequencies of the simulator's own draws."""
    model = model_of(tmp_path, RANDOM_CONDITION, "rc_inst")
    sim = Simulator(probability_model(model))
    n = 200_000
    state = sim.initial_state(n)
    state.values["b"][: n // 2] = True  # half the states have b
    out = sim.step(state, None, np.random.default_rng(5), check=False)
    nxt = out.next_state.values
    exists = 1 - 0.9**3
    expected = {
        # b false: 0.5 * 0.3; b true: 0.5 * 0.3 + 0.5
        "a": (np.r_[[0.65] * (n // 2), [0.15] * (n - n // 2)]),
        "b": np.full(n, 0.5 * 0.8),
        "c": np.full(n, 1 - exists * (1 - 0.6)),
    }
    for name, p in expected.items():
        assert nxt[name + "__prob-true"] == pytest.approx(p), name
        sampled = nxt[name]
        for half in (slice(0, n // 2), slice(n // 2, n)):
            assert abs(sampled[half].mean() - p[half].mean()) < 0.01, name


LAMPS = """
domain lamps {
    requirements = { concurrent, constrained-state };
    types { lamp : object; };
    pvariables {
        lit(lamp) : { state-fluent, bool, default = false };
        press(lamp) : { action-fluent, bool, default = false };
    };
    cpfs {
        lit'(?l) = if (press(?l)) then Bernoulli(0.5) else KronDelta(lit(?l));
    };
    reward = sum_{?l : lamp} lit(?l);
    action-preconditions {
        (sum_{?l : lamp} press(?l)) <= 1;
        forall_{?l : lamp} [press(?l) => ~lit(?l)];
    };
}
non-fluents lamps_nf { domain = lamps; objects { lamp : {a, b, c}; }; }
instance lamps_inst {
    domain = lamps;
    non-fluents = lamps_nf;
    max-nondef-actions = pos-inf;
    horizon = 4;
    discount = 1.0;
}
"""


def test_legal_actions_when_the_joint_actions_are_too_many_to_list(tmp_path: Path) -> None:
    """Three lamps, max-nondef-actions pos-inf: 8 joint actions, of which
    noop and the three single presses can be legal. With max_actions 6
    they cannot be listed blindly; the table then holds the legal ones of
    the reachable states (ippc.rddl.legal), and the values are the same."""
    model = model_of(tmp_path, LAMPS, "lamps_inst")
    full = solve(model)
    legal_only = solve(model, max_actions=6)
    assert next(iter(full.actions.values())).shape[0] == 8
    assert next(iter(legal_only.actions.values())).shape[0] == 4
    assert legal_only.initial_value == pytest.approx(full.initial_value)
    for k in range(1, 5):
        assert sorted(legal_only.v[k].tolist()) == pytest.approx(sorted(full.v[k].tolist()))
    with pytest.raises(ExactUnsupported, match="more than the limit of 3"):
        solve(model, max_actions=3)
