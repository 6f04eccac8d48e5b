"""ippc.rddl.legal: the legal joint actions of a state, found by propagation
and search, compared with brute force (every joint action checked by the
simulator) and with the forms IPPC 2018 uses."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from ippc.rddl import load, load_pair
from ippc.rddl.legal import LegalActions, NoLegalAction, TooManyActions, solver_for
from ippc.rddl.simulator import Simulator, State

from ..conftest import IPPC_MDP_DOMAINS, ippc_files

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]


def ippc(year: str, domain: str, n: int = 1) -> Simulator:
    return Simulator(load_pair(*ippc_files(year, domain, n)))


def tiny(name: str) -> Simulator:
    return Simulator(load(HERE / "legal_domains")[name])


def names(sim: Simulator, arrays: dict[str, np.ndarray]) -> set[tuple[str, ...]]:
    n = next(iter(arrays.values())).shape[0]
    return {tuple(sorted(sim.actions_to_names(arrays, i))) for i in range(n)}


def brute_force(
    sim: Simulator, state: State, values: dict[str, list[object]]
) -> set[tuple[str, ...]]:
    """Every joint action over the given values of each action fluent (one
    list per fluent, the default first), filtered by check_actions."""
    grounds = []
    for p in sim.action_fluents:
        shape = sim.noop(1)[p.name].shape[1:]
        grounds.extend((p.name, idx, values[p.name]) for idx in np.ndindex(*shape))
    combos = list(itertools.product(*(v for _, _, v in grounds)))
    acts = sim.noop(len(combos))
    for row, combo in enumerate(combos):
        for (name, idx, _), value in zip(grounds, combo, strict=True):
            acts[name][(row, *idx)] = value
    ok = sim.check_actions(state[[0] * len(combos)], acts)
    return names(sim, {k: v[ok] for k, v in acts.items()})


def test_chromatic_dice_rolls_five_dice_at_once() -> None:
    """Phase roll1: `current-phase == @roll1 => forall_{?d} roll(?d)` and
    nothing else allowed: exactly one legal joint action, found at once."""
    sim = ippc("IPPC2018", "ChromaticDice")
    legal = LegalActions(sim)
    state = sim.initial_state(1)
    space = legal.space(state)
    assert space.count == 1 and space.exact and space.nodes == 0
    got = legal.enumerate(state)
    assert names(sim, got) == {tuple(f"roll(d{i}) = true" for i in range(1, 6))}
    assert not sim.check_actions(state, sim.noop(1))[0]
    # the simulator's random actions fall back on it where coin flips cannot find it
    drawn = sim.random_actions(state[[0, 0, 0]], np.random.default_rng(0))
    assert sim.check_actions(state[[0, 0, 0]], drawn).all()
    assert drawn["roll"].all()


@pytest.mark.parametrize("domain", ["EarthObservation", "WildlifePreserve", "PushYourLuck"])
def test_exactly_one_forms_match_brute_force(domain: str) -> None:
    """`slew(@north-east) + slew(@south-east) + (take-image | slew(@east)) == 1`,
    `forall_{?r} (sum_{?a} defend(?a, ?r)) == 1`, `cash-out | exists roll`:
    along a few steps, the legal set is exactly what brute force finds."""
    sim = ippc("IPPC2018", domain)
    legal = LegalActions(sim)
    rng = np.random.default_rng(4)
    state = sim.initial_state(1)
    for _ in range(4):
        found = legal.enumerate(state)
        want = brute_force(sim, state, {p.name: [False, True] for p in sim.action_fluents})
        assert names(sim, found) == want
        assert legal.count(state) == len(want)
        state = sim.step(state, legal.sample(state, rng, 1), rng).next_state


def test_wildlife_preserve_has_no_noop_and_a_product_count() -> None:
    sim = ippc("IPPC2018", "WildlifePreserve")
    rangers = len(sim.model.types["ranger"].members)
    areas = len(sim.model.types["area"].members)
    state = sim.initial_state(1)
    space = solver_for(sim).space(state)
    assert space.count == areas**rangers and space.nodes == 0  # counted, not searched
    assert () not in names(sim, solver_for(sim).enumerate(state))


def test_uniform_samples() -> None:
    """WildlifePreserve #1: every one of the legal joint actions equally
    often (chi-square, p < 0.001)."""
    sim = ippc("IPPC2018", "WildlifePreserve")
    legal = LegalActions(sim)
    state = sim.initial_state(1)
    n = 2000
    drawn = legal.sample(state, np.random.default_rng(1), n)
    rows = [tuple(sorted(sim.actions_to_names(drawn, i))) for i in range(n)]
    counts = {k: rows.count(k) for k in set(rows)}
    k = legal.count(state)
    assert len(counts) == k
    chi2 = sum((c - n / k) ** 2 / (n / k) for c in counts.values())
    assert chi2 < {4: 16.3, 9: 26.1, 16: 37.7}.get(k, 3.0 * k), (k, counts)


def test_bool_enum_and_int_actions() -> None:
    """legal_domains/mixed.rddl: an enum level per item, an int amount
    bounded to 0..3 by its constraints, max-nondef-actions 3; brute force
    over amounts -4..8 finds nothing the solver misses."""
    sim = tiny("legal_mixed_inst")
    state = sim.initial_state(1)
    rng = np.random.default_rng(0)
    for _ in range(2):
        found = solver_for(sim).enumerate(state)
        want = brute_force(
            sim, state, {"go": [False, True], "set-level": [0, 1, 2], "amount": list(range(-4, 9))}
        )
        assert names(sim, found) == want and len(want) > 10
        assert () in want and names(sim, {k: v[:1] for k, v in found.items()}) == {()}  # noop first
        assert any("amount = 3" in row for row in want)
        assert any("set-level(a) = @high" in row for row in want)
        state = sim.step(state, solver_for(sim).sample(state, rng, 1), rng).next_state
    # the Simulator's method is the same enumeration
    assert names(sim, sim.legal_actions(state)) == names(sim, solver_for(sim).enumerate(state))
    with pytest.raises(TooManyActions, match="more than the limit of 5"):
        solver_for(sim).enumerate(state, limit=5)


def test_a_state_without_legal_actions_says_why() -> None:
    sim = tiny("legal_stuck_inst")
    legal = LegalActions(sim)
    first = sim.initial_state(1)
    assert legal.count(first) == 3
    stuck = sim.step(first, sim.noop(1), np.random.default_rng(0)).next_state
    space = legal.space(stuck)
    assert space.empty and space.count == 0
    message = r"no legal joint action in this state: .*stuck\.rddl:23:\d+: constraint cannot hold"
    with pytest.raises(NoLegalAction, match=message):
        legal.enumerate(stuck)
    with pytest.raises(NoLegalAction, match=message):
        legal.sample(stuck, np.random.default_rng(0))
    both = State({k: np.concatenate([first.values[k], stuck.values[k]]) for k in first.values})
    with pytest.raises(NoLegalAction, match="state 1 of the batch"):
        legal.sample_batch(both, np.random.default_rng(0))


@pytest.mark.parametrize("domain", IPPC_MDP_DOMAINS["IPPC2018"])
def test_ippc2018_nothing_legal_is_missed(domain: str) -> None:
    """Too many joint actions for brute force: random probes with few
    non-default groundings; every probe the simulator finds legal is among
    the enumerated actions, and every enumerated one is legal."""
    sim = ippc("IPPC2018", domain)
    legal = LegalActions(sim)
    size = legal.layout.size
    rng = np.random.default_rng(7)
    state = sim.initial_state(1)
    probed = 0
    for _ in range(3):
        found = legal.enumerate(state)
        have = names(sim, found)
        assert len(have) == legal.count(state) == next(iter(found.values())).shape[0]
        assert sim.check_actions(state[[0] * len(have)], found).all()
        for p in (1 / size, 2 / size, 4 / size):
            rows = (rng.random((1500, size)) < p).tolist()
            probes = legal.arrays(rows)
            ok = sim.check_actions(state[[0] * 1500], probes)
            probed += int(ok.sum())
            assert names(sim, {k: v[ok] for k, v in probes.items()}) <= have
        state = sim.step(state, legal.sample(state, rng, 1), rng).next_state
    assert probed > 0
