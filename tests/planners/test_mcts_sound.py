"""mcts never loses a legal, better joint action to its shortcuts (issue 35):
a differential harness against the `exact` planner.

Small RDDL domains are generated from a seed (`generate`): two to four bool
state fluents, two to four bool actions with costs, deterministic and
Bernoulli effects, rewards over states and actions, action preconditions
that tie actions to each other (`a => b`, mutual exclusion), to the state
(`a => s`, `s => a`: noop illegal there) and `a | b` (noop never legal),
and max-nondef-actions limits. `exact` solves each one (a domain where some
reachable state has no legal action is skipped: a simulator stops there).
mcts with its defaults (a fixed number of trials, so that a seed gives the
same search anywhere) then plays rounds on the simulator; every action it
sends must be legal, and its gap to the optimum is measured exactly, with no
sampling noise from the rewards: the exact regret of each action it takes
(the optimal value of the state less the optimal value of the action taken
there, `Solution.regret`), discounted and summed over the round, is what
the round lost against an optimal policy (the performance difference
lemma), and its mean over the rounds estimates the expected loss.

The two domains of the issue (`move => permit`, and the chain `ship =>
label`, `label => weigh`) are fixed files in tests/data/mcts_sound/.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from ippc.planners.base import Observation, SessionInfo
from ippc.planners.exact import ExactUnsupported, Solution, solve
from ippc.planners.mcts import MCTSPlanner
from ippc.planners.mcts.relevance import downward_closed, removable_inert, useless_actions
from ippc.rddl import load
from ippc.rddl.model import Model
from ippc.rddl.sim.scalar import ScalarStep
from ippc.rddl.simulator import Simulator
from ippc.rddl.wire import WireCodec

DATA = Path(__file__).resolve().parents[1] / "data" / "mcts_sound"

TRIALS = "200"
"""mcts's trials a step: the defaults otherwise."""

TOLERANCE = 0.15
"""The largest mean loss a round allowed, as a fraction of `scale`: the
optimum less the worst legal policy's value."""


# ---------------------------------------------------------------- the domains


def generate(seed: int) -> str:
    """A small random domain and its instance `gen_<seed>_inst` (see the
    module docstring)."""
    rng = np.random.default_rng(seed)
    n_s = int(rng.integers(2, 5))
    n_a = int(rng.integers(2, 5))
    states = [f"s{i}" for i in range(n_s)]
    acts = [f"a{j}" for j in range(n_a)]

    def pick(xs: list[str]) -> str:
        return xs[int(rng.integers(len(xs)))]

    def lit(xs: list[str]) -> str:
        x = pick(xs)
        return f"~{x}" if rng.random() < 0.3 else x

    cpfs = []
    for s in states:
        a = pick(acts)
        cond = a if rng.random() < 0.5 else f"({a} ^ {lit(states)})"
        effect = pick(["true", "false", f"Bernoulli({rng.choice([0.3, 0.6, 0.9])})"])
        if rng.random() < 0.4:
            other = f"({lit(states)} ^ Bernoulli({rng.choice([0.2, 0.5])}))"
        else:
            other = pick([s, s, f"({s} ^ Bernoulli(0.8))", "false"])
        cpfs.append(f"{s}' = if ({cond}) then {effect} else {other};")
    reward = []
    for s in rng.choice(states, size=int(rng.integers(1, 3)), replace=False):
        reward.append(f"{int(rng.integers(1, 11))} * {s}")
    for a in acts:
        cost = float(rng.choice([0.0, 0.1, 0.5, 1.0, 2.0]))
        if cost:
            reward.append(f"-{cost} * {a}")
    if rng.random() < 0.4:
        reward.append(f"{int(rng.integers(1, 6))} * ({pick(acts)} ^ {lit(states)})")
    pre = []
    for _ in range(int(rng.integers(1, 4))):
        kind = int(rng.integers(6))
        x, y = rng.choice(acts, size=2, replace=False)
        if kind in (0, 1):
            pre.append(f"{x} => {y};")  # an action needs another
        elif kind == 2:
            pre.append(f"{x} => {lit(states)};")
        elif kind == 3:
            pre.append(f"{pick(states)} => {x};")  # noop illegal there
        elif kind == 4:
            pre.append(f"{x} + {y} <= 1;")
        else:
            pre.append(f"{x} | {y};")  # noop never legal
    limit = rng.choice([0, 1, 2])
    init = [s for s in states if rng.random() < 0.3]
    horizon = int(rng.integers(4, 8))
    discount = float(rng.choice([1.0, 0.9]))
    name = f"gen_{seed}"
    lines = [f"domain {name} {{", "    requirements = { concurrent, preconditions };"]
    lines.append("    pvariables {")
    lines += [f"        {s} : {{ state-fluent, bool, default = false }};" for s in states]
    lines += [f"        {a} : {{ action-fluent, bool, default = false }};" for a in acts]
    lines += ["    };", "    cpfs {"]
    lines += [f"        {c}" for c in cpfs]
    lines += ["    };", f"    reward = {' + '.join(reward)};", "    action-preconditions {"]
    lines += [f"        {p}" for p in pre]
    lines += ["    };", "}", f"instance {name}_inst {{", f"    domain = {name};"]
    if init:
        lines.append(f"    init-state {{ {'; '.join(init)}; }};")
    if limit:
        lines.append(f"    max-nondef-actions = {limit};")
    lines += [f"    horizon = {horizon};", f"    discount = {discount};", "}"]
    return "\n".join(lines) + "\n"


def model_of(text: str, instance: str, tmp_path: Path) -> Model:
    f = tmp_path / f"{instance}.rddl"
    f.write_text(text)
    return load(f)[instance]


def solvable(model: Model) -> Solution | None:
    """The exact solution, or None where a reachable state has no legal action."""
    try:
        sol = solve(model)
    except ExactUnsupported:
        return None  # (a reachable state with no legal action)
    if not sol.legal.any(axis=1).all():
        return None
    return sol


# ---------------------------------------------------------------- the player


@dataclass
class Played:
    """Rounds of mcts against the exact solution."""

    optimum: float  # the optimal expected round reward
    loss: list[float]  # per round: discounted sum of the exact regrets of its actions
    rewards: list[float]  # per round: what it got
    illegal: list[str]  # what the server would have refused, with the turn

    @property
    def gap(self) -> float:
        return float(np.mean(self.loss))


def play(model: Model, sol: Solution, rounds: int, seed: int, **options: str) -> Played:
    """`rounds` rounds of mcts (`options` over its defaults, TRIALS trials a
    step) on the simulator, each action checked as the server checks it."""
    sim = Simulator(model)
    codec = WireCodec(sim)
    planner = MCTSPlanner(**{"iterations": TRIALS, "seed": str(seed), **options})
    planner.start_session(
        SessionInfo(model.name, model, sim, rounds=rounds, time_allowed=600.0, seed=seed)
    )
    rng = np.random.default_rng(seed)
    horizon = model.horizon or 1
    gamma = model.discount
    out = Played(sol.initial_value, [], [], [])
    for r in range(1, rounds + 1):
        planner.start_round(r)
        state = sim.initial_state(1)
        total = lost = 0.0
        weight = 1.0
        previous = 0.0
        for turn in range(1, horizon + 1):
            left = horizon - turn + 1
            obs = Observation(
                {(n, a): v for n, a, v in codec.state(state)},
                state,
                turn,
                left,
                600.0,
                previous,
                time.monotonic() + 60.0,
            )
            decoded = codec.actions_from(planner.act(obs))
            why = codec.check(state, decoded)
            if why is not None:
                out.illegal.append(f"round {r} turn {turn}: {why}")
                break
            lost += weight * sol.regret(left, state, decoded.arrays)
            step = sim.step(state, decoded.arrays, rng)
            previous = float(step.reward[0])
            total += weight * previous
            weight *= gamma
            state = step.next_state
            if step.done[0]:
                break
        planner.end_round(total)
        out.loss.append(lost)
        out.rewards.append(total)
    planner.end_session(float(sum(out.rewards)))
    return out


def worst_value(sol: Solution) -> float:
    """The expected round reward of the worst legal policy from the initial
    state (value iteration with min over the legal actions)."""
    n_states, n_actions = sol.legal.shape
    v = np.zeros(n_states)
    for _ in range(len(sol.v) - 1):
        q = sol.reward + sol.model.discount * sol._expect(v).reshape(n_states, n_actions)
        v = np.where(sol.legal, q, np.inf).min(axis=1)
    return float(v[0])


def scale(sol: Solution) -> float:
    """The spread of round rewards that a policy decides: the optimum less
    the worst legal policy's value (at least 1), as IPPC's scores normalise."""
    return max(1.0, sol.initial_value - worst_value(sol))


# ---------------------------------------------------------------- regressions


@pytest.mark.parametrize(
    ("file", "instance", "optimum"),
    [("permit.rddl", "permit_inst", 89.9), ("chain.rddl", "chain_inst", 77.6)],
)
def test_an_action_another_needs_is_not_pruned(file: str, instance: str, optimum: float) -> None:
    # move => permit, permit costing 0.1 and move reaching a +10 goal: relevance
    # used to leave permit out, move alone is illegal, and mcts played noop (0.0)
    model = load(DATA / file)[instance]
    sol = solve(model)
    assert sol.initial_value == pytest.approx(optimum)
    fast = ScalarStep(Simulator(model))
    assert useless_actions(fast) == []
    assert not downward_closed(fast)  # the C walk of legal actions stays off
    played = play(model, sol, rounds=2, seed=0)
    assert played.illegal == []
    assert played.rewards == pytest.approx([optimum, optimum])
    assert played.loss == pytest.approx([0.0, 0.0])


COSTLESS_PERMIT = """
domain free_permit {
    requirements = { preconditions };
    pvariables {
        goal : { state-fluent, bool, default = false };
        move : { action-fluent, bool, default = false };
        permit : { action-fluent, bool, default = false };
        wave : { action-fluent, bool, default = false };
    };
    cpfs { goal' = goal | move; };
    reward = 10 * goal;
    action-preconditions { move => permit; wave + move <= 1; };
}
instance free_permit_inst { domain = free_permit; horizon = 5; discount = 1.0; }
"""


def test_a_grounding_the_step_never_reads_is_kept_where_a_constraint_needs_it(
    tmp_path: Path,
) -> None:
    # permit and wave change nothing and cost nothing (the step never reads
    # them); wave may be left out (it only appears where unsetting it keeps the
    # constraint true), permit may not
    model = model_of(COSTLESS_PERMIT, "free_permit_inst", tmp_path)
    fast = ScalarStep(Simulator(model))
    assert sorted(fast.inert_actions) == [("permit", ()), ("wave", ())]
    assert removable_inert(fast) == [("wave", ())]
    sol = solve(model)
    played = play(model, sol, rounds=1, seed=0)
    assert played.illegal == [] and played.rewards == pytest.approx([40.0])


@pytest.mark.parametrize(
    ("constraint", "kept"),
    [
        ("a0 => a1;", {"a0", "a1"}),  # a1 positive: kept, and what it is read with
        ("a1 => a0;", set()),  # a1 only negative: unsetting it keeps this true
        ("a1 + a2 <= 1;", set()),
        ("a1 == a2;", {"a1", "a2"}),
        ("a0 => (a1 | a2);", {"a0", "a1", "a2"}),
        ("~a1 | s0;", set()),
        ("(a1 + a2) >= 1 => s0;", set()),
        ("(if (s0) then a1 else a2) => a0;", set()),
        ("(if (a1) then s0 else a2) => a0;", {"a0", "a1", "a2"}),
    ],
)
def test_the_constraint_rule_by_polarity(tmp_path: Path, constraint: str, kept: set[str]) -> None:
    # a0 pays; a1 and a2 only cost and touch nothing: useless unless a
    # constraint is not proven to allow them at their default
    text = f"""
domain pol {{
    requirements = {{ preconditions }};
    pvariables {{
        s0 : {{ state-fluent, bool, default = false }};
        a0 : {{ action-fluent, bool, default = false }};
        a1 : {{ action-fluent, bool, default = false }};
        a2 : {{ action-fluent, bool, default = false }};
    }};
    cpfs {{ s0' = s0 | a0; }};
    reward = 5 * s0 - 0.5 * a1 - 0.5 * a2;
    action-preconditions {{ {constraint} }};
}}
instance pol_inst {{ domain = pol; horizon = 3; discount = 1.0; }}
"""
    model = model_of(text, "pol_inst", tmp_path)
    useless = {name for name, _ in useless_actions(ScalarStep(Simulator(model)))}
    assert {"a1", "a2"} - useless == kept - {"a0"}
    assert "a0" not in useless


# ---------------------------------------------------------------- the harness

FAST_SEEDS = range(12)
SLOW_SEEDS = range(12, 212)


def check_seeds(seeds: range, tmp_path: Path, rounds: int, **options: str) -> dict[int, float]:
    """Every generated domain of `seeds` that exact solves: no illegal action,
    a mean loss within TOLERANCE; the losses, as fractions of `scale`."""
    gaps: dict[int, float] = {}
    for seed in seeds:
        model = model_of(generate(seed), f"gen_{seed}_inst", tmp_path)
        sol = solvable(model)
        if sol is None:
            continue
        spread = scale(sol)
        played = play(model, sol, rounds=rounds, seed=seed, **options)
        assert played.illegal == [], (seed, played.illegal, generate(seed))
        if played.gap > TOLERANCE * spread + 1e-9:
            # 200 trials are too few where every action has the same noisy
            # future and they differ only in their costs (seed 41: 21% of its
            # scale lost over 16 rounds at 200 trials, 13% at 800, 7% at 3,200):
            # a seed over the tolerance plays again with 8 times the trials and 4
            # times the rounds. A sound search converges there; one that drops
            # the action it needs loses whatever the trials.
            more = {"iterations": str(8 * int(TRIALS)), **options}
            played = play(model, sol, rounds=4 * rounds, seed=seed + 10_000, **more)
            assert played.illegal == [], (seed, played.illegal, generate(seed))
        gaps[seed] = played.gap / spread
        assert played.gap <= TOLERANCE * spread + 1e-9, (seed, played, generate(seed))
    return gaps


def test_generated_domains_fast_sample(tmp_path: Path) -> None:
    gaps = check_seeds(FAST_SEEDS, tmp_path, rounds=2)
    assert len(gaps) >= len(FAST_SEEDS) // 2  # most generated domains are solvable


@pytest.mark.slow
def test_generated_domains_without_the_c_step(tmp_path: Path) -> None:
    # without the C step (compiled=no) mcts runs its wave engine: the same
    # candidates, legal and within the tolerance too (slow: seconds a round)
    gaps = check_seeds(range(8), tmp_path, rounds=1, compiled="no")
    assert len(gaps) >= 4


@pytest.mark.slow
def test_generated_domains_sweep(tmp_path: Path) -> None:
    gaps = check_seeds(SLOW_SEEDS, tmp_path, rounds=4)
    assert len(gaps) >= len(SLOW_SEEDS) // 2


def test_actions_that_agree_on_both_probes_only_by_chance_are_not_merged() -> None:
    model = load(DATA / "probe.rddl")["probe_inst"]
    sol = solve(model)
    assert sol.initial_value == pytest.approx(20.0)
    losses = [play(model, sol, rounds=1, seed=seed).gap for seed in range(6)]
    assert losses == pytest.approx([0.0] * 6, abs=3.0)  # (2.5 a step lost when merged)
