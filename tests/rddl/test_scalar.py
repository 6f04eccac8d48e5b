"""The one-state step over Python scalars (ippc.rddl.sim.scalar) against the
batched step: the same successor distribution. Its draws are its own, so
the two are compared in distribution: from states along a trajectory, with
random legal joint actions, N scalar steps against one batched step of N
copies, every next-state grounding's mean and the reward's mean within
z_max standard errors (a value the batched step always gives must come
every time: its standard error is 0). Seeded, so a run is the same every
time. Exactly, too, where there is nothing to draw: the most-likely
determinisation of each model (`planners.determinise`) and, for boolean
models, exact.py's probability model (each next-state fluent's
probability of being true, a real fluent), step for step. A sample of IPPC
instances and hand-made models in the fast suite, the first instance of
every rddlrepository domain in the slow sweep."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ippc.rddl import load, load_pair
from ippc.rddl.sim.scalar import ScalarStep, ScalarUnsupported
from ippc.rddl.simulator import SimulationError, Simulator

from ..conftest import corpus_pairs, corpus_root, ippc_files

Z_MAX = 5.5  # with some thousand groundings compared, |z| of 4 is seen by chance


def compare(sim: Simulator, steps: int = 4, n: int = 1500, seed: int = 0) -> int:
    """Compare the two steps along a trajectory; the number of steps compared."""
    fast = ScalarStep(sim)
    rng = np.random.default_rng(seed)
    state = sim.initial_state(1)
    compared = 0
    for _ in range(steps):
        actions = sim.random_actions(state, rng)
        rows = np.zeros(n, dtype=np.int64)
        try:
            batched = sim.step(
                state[rows],
                {k: np.repeat(v, n, axis=0) for k, v in actions.items()},
                rng,
                check=False,
            )
        except SimulationError:
            break  # (a distribution's parameters out of range: the batched step raises)
        s, a = fast.encode_state(state), fast.encode_actions(actions)
        outs = [fast.step(s, a, rng) for _ in range(n)]
        mine = np.array([o[0] for o in outs], dtype=np.float64).reshape(n, -1)
        theirs = np.concatenate(
            [batched.next_state.values[name].reshape(n, -1) for name in batched.next_state.values],
            axis=1,
        ).astype(np.float64)
        assert mine.shape == theirs.shape
        rewards = np.array([o[1] for o in outs])
        done = np.array([o[2] for o in outs], dtype=np.float64)
        for label, x, y in (
            ("next state", mine, theirs),
            ("reward", rewards[:, None], batched.reward[:, None]),
            ("done", done[:, None], batched.done[:, None].astype(np.float64)),
        ):
            finite = np.isfinite(y).all(axis=0) & np.isfinite(x).all(axis=0)
            x, y = x[:, finite], y[:, finite]
            se = np.sqrt((x.var(axis=0) + y.var(axis=0)) / n)
            diff = np.abs(x.mean(axis=0) - y.mean(axis=0))
            tol = 1e-9 * np.maximum(1.0, np.abs(y.mean(axis=0)))
            z = np.where(
                se > 0, diff / np.where(se > 0, se, 1.0), np.where(diff > tol, np.inf, 0.0)
            )
            if z.size:
                worst = int(np.argmax(z))
                key = sim.model.name if label != "next state" else fast.state_keys[worst]
                assert z[worst] <= Z_MAX, (
                    f"{label} {key}: scalar mean {x[:, worst].mean()}, batched {y[:, worst].mean()}"
                )
        compared += 1
        state = batched.next_state[int(rng.integers(n))]
        if bool(batched.done[0]):
            state = sim.initial_state(1)
    return compared


def compare_exact(sim: Simulator, steps: int = 6, seed: int = 0, suffix: str = "") -> int:
    """The same successor, reward and done, step for step, for a model
    without draws (up to float rounding: Python sums in another order than
    numpy); with `suffix`, only the state fluents named so are compared
    (those computed without draws, in a model that draws elsewhere), and
    the trajectory goes on from the batched step's successor."""
    fast = ScalarStep(sim)
    keys = [i for i, (name, _) in enumerate(fast.state_keys) if name.endswith(suffix)]
    assert keys
    if not suffix:
        assert fast.draws == 0
    rng = np.random.default_rng(seed)
    state = sim.initial_state(1)
    for _ in range(steps):
        actions = sim.random_actions(state, rng)
        out = sim.step(state, actions, rng, check=False)
        nxt, reward, done = fast.step(fast.encode_state(state), fast.encode_actions(actions), rng)
        want = fast.encode_state(out.next_state)
        np.testing.assert_allclose(
            np.array(nxt, dtype=np.float64)[keys],
            np.array(want, dtype=np.float64)[keys],
            rtol=1e-9,
            atol=1e-12,
        )
        if not suffix:
            assert reward == pytest.approx(float(out.reward[0]), rel=1e-9, abs=1e-12)
            assert done == bool(out.done[0])
        state = out.next_state if not out.done[0] else sim.initial_state(1)
    return steps


def deterministic_versions(sim: Simulator) -> list[tuple[Simulator, str]]:
    """The most-likely determinisation (every fluent compared) and, for
    boolean models, the probability model (its probability fluents)."""
    from ippc.planners.determinise import determinise
    from ippc.planners.exact import PROB_SUFFIX, ExactUnsupported, probability_model

    out = [(Simulator(determinise(sim.model)), "")]
    try:
        out.append((Simulator(probability_model(sim.model)), PROB_SUFFIX))
    except ExactUnsupported:
        pass
    return out


SAMPLE = [
    ("IPPC2011", "SysAdmin/MDP", 1),
    ("IPPC2011", "Elevators/MDP", 1),
    ("IPPC2011", "CrossingTraffic/MDP", 1),
    ("IPPC2011", "Traffic/MDP", 1),
    ("IPPC2014", "Wildfire/MDP", 1),
    ("IPPC2014", "AcademicAdvising/MDP", 1),
]


@pytest.mark.parametrize("year,domain,number", SAMPLE, ids=[f"{y}-{d}" for y, d, _ in SAMPLE])
def test_ippc_sample_same_distribution(year: str, domain: str, number: int) -> None:
    sim = Simulator(load_pair(*ippc_files(year, domain, number)))
    assert compare(sim) == 4
    versions = deterministic_versions(sim)
    assert len(versions) == 2  # (these are boolean models)
    for det, suffix in versions:
        assert compare_exact(det, suffix=suffix) == 6


# interm fluents, enums with switch and Discrete, Normal and real arithmetic,
# int casts, exists/forall/prod/min/avg, division, termination
MIXED = """
domain mixed {
    requirements = { concurrent };
    types { cell : object; level : { @low, @mid, @high }; };
    pvariables {
        W(cell) : { non-fluent, real, default = 1.0 };
        on(cell) : { state-fluent, bool, default = false };
        lvl : { state-fluent, level, default = @low };
        x : { state-fluent, real, default = 0.0 };
        k : { state-fluent, int, default = 0 };
        heat : { interm-fluent, real };
        push(cell) : { action-fluent, bool, default = false };
        up : { action-fluent, bool, default = false };
    };
    cpfs {
        heat = sum_{?c : cell} [W(?c) * on(?c)] / (1 + k);
        on'(?c) = if (push(?c)) then Bernoulli(0.9)
                  else if (exists_{?d : cell} [on(?d) ^ ?d ~= ?c]) then Bernoulli(0.3)
                  else on(?c);
        lvl' = switch (lvl) {
            case @low : if (up) then Discrete(level, @low : 0.2, @mid : 0.7, @high : 0.1) else @low,
            case @mid : Discrete(level, @low : 0.5, @mid : 0.25, @high : 0.25),
            default : if (forall_{?c : cell} [on(?c)]) then @high else @mid
        };
        x' = x + Normal(heat, 0.5 + min_{?c : cell} [W(?c)]);
        k' = k + floor[abs[x] / 3.0] + (prod_{?c : cell} [1 + on(?c)]);
    };
    reward = avg_{?c : cell} [on(?c)] + (lvl == @high) - 0.1 * x + sqrt[k];
    termination { k > 60; };
}
non-fluents mixed_nf {
    domain = mixed;
    objects { cell : {c1, c2, c3}; };
    non-fluents { W(c1) = 0.5; W(c3) = 2.0; };
}
instance mixed_inst {
    domain = mixed;
    non-fluents = mixed_nf;
    init-state { on(c1); };
    max-nondef-actions = 2;
    horizon = 20;
    discount = 1.0;
}
"""


@pytest.mark.parametrize("domain", ["RedFinnedBlueEye", "PushYourLuck"])
def test_numeric_enums_same_distribution(domain: str) -> None:
    # enums @1..@n that count as numbers in arithmetic (IPPC 2018)
    sim = Simulator(load_pair(*ippc_files("IPPC2018", domain, 1)))
    assert ScalarStep(sim).draws > 0  # (it used to refuse these models)
    assert compare(sim, steps=4, n=1000) == 4


def test_hand_made_constructs_same_distribution(tmp_path: Path) -> None:
    f = tmp_path / "mixed.rddl"
    f.write_text(MIXED)
    sim = Simulator(load(f)["mixed_inst"])
    fast = ScalarStep(sim)
    assert "Z[0]" in fast.source and "_discrete(" in fast.source
    assert compare(sim, steps=8) == 8


def test_encode_decode_and_folding() -> None:
    sim = Simulator(load_pair(*ippc_files("IPPC2011", "SysAdmin/MDP", 1)))
    fast = ScalarStep(sim)
    s = sim.initial_state(1)
    t = fast.encode_state(s)
    back = fast.decode_state(t)
    assert all(np.array_equal(back.values[k], s.values[k]) for k in s.values)
    assert len(t) == s.values["running"].size and len(fast.noop) == 10
    # the constant CONNECTED is folded: no non-fluent name in the code
    assert "CONNECTED" not in fast.source and "sum" not in fast.source
    # rebooting a computer: it runs next for sure
    acts = sim.noop(1)
    acts["reboot"][0, 3] = True
    s2 = s.copy()
    s2.values["running"][0, 3] = False
    nxt, _, done = fast.step(
        fast.encode_state(s2), fast.encode_actions(acts), np.random.default_rng(0)
    )
    assert nxt[3] is True and done is False


def test_unsupported_is_named(tmp_path: Path) -> None:
    text = MIXED.replace(
        "x' = x + Normal(heat, 0.5 + min_{?c : cell} [W(?c)]);", "x' = x + Gamma(2, 1);"
    )
    f = tmp_path / "m.rddl"
    f.write_text(text)
    with pytest.raises(ScalarUnsupported, match="Gamma"):
        ScalarStep(Simulator(load(f)["mixed_inst"]))


def _first_per_folder(pairs: list[tuple[Path, Path]]) -> list[tuple[Path, Path]]:
    seen: set[Path] = set()
    out = []
    for dom, inst in pairs:
        if dom.parent not in seen:
            seen.add(dom.parent)
            out.append((dom, inst))
    return out


# the first instance of every domain folder (every instance would take the
# better part of an hour: the writer grounds each one)
PAIRS = _first_per_folder(corpus_pairs())

# What the sweep refuses, asserted (a refusal that goes away, or another one,
# fails): folder -> (who refuses: "build" is the batched simulator, "scalar"
# the scalar step; the error it must give). Every POMDP is refused by the
# scalar step ("observations"), checked apart from this table.
EXPECTED_REFUSALS: dict[str, tuple[str, str]] = {
    # categorical draws over objects
    "archive/arcade/Blackjack": ("scalar", "DiscreteOver"),
    "archive/or/BinPacking": ("scalar", "DiscreteOver"),
    "archive/or/Knapsack": ("scalar", "DiscreteOver"),
    "archive/standalone/Intruders/Discrete": ("scalar", "DiscreteOver"),
    # continuous draws other than Normal
    "archive/arcade/Pong": ("scalar", "distribution Uniform"),
    "archive/competitions/IPPC2023/RecSim": ("scalar", "distribution Uniform"),
    "archive/physics/Bicycle": ("scalar", "distribution Uniform"),
    "archive/standalone/Intruders/Continuous": ("scalar", "distribution Uniform"),
    "archive/competitions/IPPC2023/PowerGen": ("scalar", "distribution Weibull"),
    "archive/standalone/Elevators": ("scalar", "distribution Poisson"),
    # object arguments computed at run time (a fluent of an object type used as an argument)
    "archive/arcade/Tetris": ("scalar", "an argument computed at run time"),
    "archive/standalone/TrafficBLX/SimplePhases": ("scalar", "an argument computed at run time"),
    "archive/gym/Pendulum": ("scalar", "function fmod"),
    # pyRDDLGym's matrix functions (test_corpus_sim asserts the same)
    "archive/or/Option": ("build", "MatrixOp is not supported"),
}


def _refusal(rel: str) -> tuple[str, str] | None:
    for folder, outcome in EXPECTED_REFUSALS.items():
        if rel == folder or rel.startswith(folder + "/"):
            return outcome
    return None


@pytest.mark.slow
@pytest.mark.parametrize(
    "domain,instance",
    PAIRS,
    ids=[p[1].relative_to(corpus_root()).as_posix() for p in PAIRS],
)
def test_corpus_same_distribution(domain: Path, instance: Path) -> None:
    expected = _refusal(instance.relative_to(corpus_root()).as_posix())
    try:
        sim = Simulator(load_pair(domain, instance))
    except SimulationError as err:
        assert expected is not None and expected[0] == "build", f"the simulator refused: {err}"
        assert expected[1] in str(err), err
        return
    assert expected is None or expected[0] != "build", f"expected {expected}, but it built"
    try:
        ScalarStep(sim)
    except ScalarUnsupported as err:
        if sim.observ_fluents:
            assert "observations" in str(err), err
        else:
            assert expected is not None, f"the scalar step refused: {err}"
            assert expected[1] in str(err), err
        return
    assert expected is None, f"expected the refusal {expected}, but the scalar step wrote it"
    assert not sim.observ_fluents, "a POMDP was written by the scalar step"
    compare(sim, steps=2, n=600)
    for det, suffix in deterministic_versions(sim):
        try:
            ScalarStep(det)
        except ScalarUnsupported:
            continue  # (exact's probability model can be far longer)
        compare_exact(det, steps=3, suffix=suffix)


def test_expected_refusal_folders_exist() -> None:
    rels = {p[1].relative_to(corpus_root()).as_posix() for p in PAIRS}
    for folder in EXPECTED_REFUSALS:
        assert any(r == folder or r.startswith(folder + "/") for r in rels), folder
