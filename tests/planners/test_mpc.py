"""The model-predictive planner (ippc.planners.mpc): its action space read
from the preconditions, the plan's sampling and refits, and whole rounds
against analytic optima on two small domains written for the test (a
linear-quadratic one and a reservoir-like one whose release is bounded by
the level, a precondition it can only check)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from ippc.planners import Observation, PlannerError, SessionInfo, find_planner, make_planner
from ippc.planners.mpc import MPCPlanner
from ippc.planners.mpc.search import Plan, weights
from ippc.planners.mpc.space import ActionSpace
from ippc.rddl import load
from ippc.rddl.model import Model
from ippc.rddl.simulator import Simulator
from ippc.rddl.wire import WireCodec

# x' = x + u, reward -(x^2) - R u^2: a scalar linear-quadratic regulator.
# The bounds on u are far wider than any optimal control (|u| < x0).
LQ = """
domain lq {
    requirements = { continuous };
    pvariables {
        R : { non-fluent, real, default = 0.5 };
        UMAX : { non-fluent, real, default = 10.0 };
        x : { state-fluent, real, default = 3.0 };
        u : { action-fluent, real, default = 0.0 };
    };
    cpfs { x' = x + u; };
    reward = -(x * x) - R * u * u;
    action-preconditions { u <= UMAX; u >= -UMAX; };
}
instance lq_inst {
    domain = lq;
    max-nondef-actions = pos-inf;
    horizon = 8;
    discount = 1.0;
}
"""

# A reservoir: the level rises by INFLOW a step, the release may not exceed
# MAXREL (read as a bound) nor the level (a precondition on a state fluent:
# checked, not built in). Every step costs |level - TARGET|.
RESERVOIR = """
domain tank {
    requirements = { continuous };
    types { res : object; };
    pvariables {
        INFLOW(res) : { non-fluent, real, default = 6.0 };
        TARGET(res) : { non-fluent, real, default = 5.0 };
        MAXREL(res) : { non-fluent, real, default = 8.0 };
        level(res) : { state-fluent, real, default = 4.0 };
        release(res) : { action-fluent, real, default = 0.0 };
    };
    cpfs { level'(?r) = level(?r) + INFLOW(?r) - release(?r); };
    reward = -sum_{?r : res} [abs[level(?r) - TARGET(?r)]];
    action-preconditions {
        forall_{?r : res} [release(?r) >= 0];
        forall_{?r : res} [release(?r) <= MAXREL(?r)];
        forall_{?r : res} [release(?r) <= level(?r)];
    };
}
non-fluents tank_nf { domain = tank; objects { res : {r1, r2}; }; }
instance tank_inst {
    domain = tank;
    non-fluents = tank_nf;
    max-nondef-actions = pos-inf;
    horizon = 6;
    discount = 1.0;
}
"""

# One item per user (an "at most one" precondition sampled as a choice) and
# an enum action: the reward pays item i2 for u1, i3 for u2, and mode @hi.
CHOICE = """
domain pick {
    requirements = { concurrent };
    types { user : object; item : object; mode : {@lo, @hi}; };
    pvariables {
        LIKES(user, item) : { non-fluent, bool, default = false };
        score : { state-fluent, real, default = 0.0 };
        show(user, item) : { action-fluent, bool, default = false };
        setting : { action-fluent, mode, default = @lo };
    };
    cpfs { score' = score; };
    reward = (sum_{?u : user, ?i : item} [LIKES(?u, ?i) * show(?u, ?i)]) + (setting == @hi);
    action-preconditions { forall_{?u : user} [(sum_{?i : item} show(?u, ?i)) <= 1]; };
}
non-fluents pick_nf {
    domain = pick;
    objects { user : {u1, u2}; item : {i1, i2, i3}; };
    non-fluents { LIKES(u1, i2); LIKES(u2, i3); };
}
instance pick_inst {
    domain = pick;
    non-fluents = pick_nf;
    max-nondef-actions = pos-inf;
    horizon = 3;
    discount = 1.0;
}
"""


def model_of(tmp_path: Path, text: str, name: str) -> Model:
    f = tmp_path / f"{name}.rddl"
    f.write_text(text)
    return load(f)[name]


def lq_optimum(x0: float, r: float, horizon: int) -> float:
    """The optimal total of the LQ domain: V_t(x) = -P_t x^2 with P_H = 0 and
    P_t = 1 + r P_{t+1} / (r + P_{t+1}) (maximise -x^2 - r u^2 - P (x + u)^2)."""
    p = 0.0
    for _ in range(horizon):
        p = 1.0 + r * p / (r + p)
    return -p * x0 * x0


def play(
    model: Model, options: dict[str, str], rounds: int = 1, seed: int = 0
) -> tuple[list[float], MPCPlanner, list[dict[str, np.ndarray]]]:
    """Rounds of the planner against the simulator, every action checked as
    the server checks it (a step with `check`); the totals and the actions."""
    sim = Simulator(model)
    planner = make_planner("mpc", {"seed": str(seed), **options})
    assert isinstance(planner, MPCPlanner)
    planner.start_session(SessionInfo(model.name, model, sim, rounds, 1e6, seed))
    codec = WireCodec(sim)
    rng = np.random.default_rng(seed + 1)
    totals, sent = [], []
    assert model.horizon is not None
    for r in range(rounds):
        planner.start_round(r + 1)
        state, total = sim.initial_state(1), 0.0
        for t in range(model.horizon):
            obs = Observation(None, state, t + 1, model.horizon - t, 1e6, 0.0, math.inf)
            decoded = codec.actions_from(planner.act(obs))
            assert not decoded.illegal
            assert bool(sim.check_actions(state, decoded.arrays)[0])
            sent.append(decoded.arrays)
            step = sim.step(state, decoded.arrays, rng, check=True)
            total += float(step.reward[0])
            state = step.next_state
        totals.append(total)
    return totals, planner, sent


# -- the action space ---------------------------------------------------


def test_space_reads_bounds_and_lists_what_it_only_checks(tmp_path: Path) -> None:
    space = ActionSpace(Simulator(model_of(tmp_path, RESERVOIR, "tank_inst")))
    assert space.lower.tolist() == [0.0, 0.0]
    assert space.upper.tolist() == [8.0, 8.0]
    assert space.limit is None  # pos-inf
    # the level bound is the only one left to the check, named by its place
    assert len(space.unhandled) == 1
    line = RESERVOIR.splitlines().index("        forall_{?r : res} [release(?r) <= level(?r)];") + 1
    assert f"tank_inst.rddl:{line}:" in space.unhandled[0]


def test_space_samples_at_most_one_item_per_user_and_enum_values(tmp_path: Path) -> None:
    sim = Simulator(model_of(tmp_path, CHOICE, "pick_inst"))
    space = ActionSpace(sim)
    assert space.unhandled == []  # "at most one" holds by construction
    show, setting = space.choices
    assert (show.groups, show.options, show.onehot) == (2, 4, True)
    assert (setting.groups, setting.options, setting.onehot) == (1, 2, False)
    plan = Plan(space, 2)
    samples = plan.sample(500, np.random.default_rng(0))
    acts = space.actions(samples, 0)
    assert acts["show"].shape == (500, 2, 3)
    assert acts["show"].sum(axis=2).max() == 1  # never two items for a user
    assert set(np.unique(acts["setting"])) == {0, 1}
    assert sim.check_actions(sim.initial_state(500), acts).all()
    # every option of a group is drawn (none, i1, i2, i3)
    assert set(np.unique(samples.choices[0])) == {0, 1, 2, 3}


ONE_AT_A_TIME = RESERVOIR.replace("max-nondef-actions = pos-inf", "max-nondef-actions = 1")


def test_limit_nondefault_keeps_the_largest_departures(tmp_path: Path) -> None:
    sim = Simulator(model_of(tmp_path, ONE_AT_A_TIME, "tank_inst"))
    space = ActionSpace(sim)
    assert space.limit == 1
    plan = Plan(space, 3)
    samples = plan.sample(200, np.random.default_rng(1))
    nondefault = (samples.numbers != 0).sum(axis=-1)
    assert nondefault.max() == 1
    raw = np.array([[[1.0, 3.0]]])
    one = type(samples)(raw.copy(), np.zeros((1, 1, 0), bool), [])
    space.limit_nondefault(one)
    assert one.numbers.tolist() == [[[0.0, 3.0]]]


def test_weights_cem_takes_the_best_tenth_mppi_all() -> None:
    r = np.arange(20, dtype=float)
    cem = weights(r, "cem")
    assert cem is not None and cem[18] == cem[19] == 0.5 and cem[:18].sum() == 0
    mppi = weights(r, "mppi")
    assert mppi is not None and math.isclose(mppi.sum(), 1.0)
    assert np.all(np.diff(mppi) > 0)  # higher return, more weight
    assert weights(np.full(3, -np.inf), "cem") is None  # nothing legal: no refit


def test_refit_moves_flags_and_choices_to_the_winners(tmp_path: Path) -> None:
    space = ActionSpace(Simulator(model_of(tmp_path, CHOICE, "pick_inst")))
    plan = Plan(space, 1)
    samples = plan.sample(400, np.random.default_rng(2))
    acts = space.actions(samples, 0)
    returns = acts["show"][:, 0, 1] * 1.0 + acts["show"][:, 1, 2] + (acts["setting"] == 1)
    for _ in range(3):
        plan.refit(samples, returns.astype(float), "cem")
    first = space.actions(plan.first(np.random.default_rng(0)), 0)
    assert first["show"][0].tolist() == [[False, True, False], [False, False, True]]
    assert first["setting"].tolist() == [1]


# -- whole rounds against analytic optima -------------------------------


@pytest.mark.parametrize("method", ["cem", "mppi"])
def test_lq_reaches_the_riccati_optimum(tmp_path: Path, method: str) -> None:
    model = model_of(tmp_path, LQ, "lq_inst")
    best = lq_optimum(3.0, 0.5, 8)
    (total,), _, sent = play(
        model, {"method": method, "iterations": "12", "samples": "200", "horizon": "8"}
    )
    noop = -9.0 * 8
    assert total <= best + 1e-9  # nothing beats the optimum
    assert total >= best * 1.02, (total, best)  # within 2% of it
    assert total > 0.5 * noop  # and far from noop's
    # the first control is the LQR gain's: u0 = -P1 / (R + P1) x0
    p1 = -lq_optimum(1.0, 0.5, 7)
    assert sent[0]["u"][0] == pytest.approx(-p1 / (0.5 + p1) * 3.0, abs=0.15)


def test_reservoir_like_domain_stays_legal_and_optimal(tmp_path: Path) -> None:
    # Each reservoir starts at 4 with inflow 6: a release may not exceed the
    # level, so the level can never come down to 5; a lower level is always
    # better, and the best is to release all of it every step (the level
    # stays at 6 from step 2 on). Every step costs 1 per reservoir whatever
    # is done best: the optimum over 6 steps and two reservoirs is -12.
    model = model_of(tmp_path, RESERVOIR, "tank_inst")
    (total,), planner, sent = play(model, {"iterations": "30", "samples": "300", "horizon": "6"})
    assert -12.0 * 1.05 <= total <= -12.0 + 1e-9, total
    for a in sent:
        assert (a["release"] >= 0).all() and (a["release"] <= 8).all()
    assert planner.stats["repaired"] > 0  # the level bound was met by repairs


def test_one_release_at_a_time_is_never_broken(tmp_path: Path) -> None:
    model = model_of(tmp_path, ONE_AT_A_TIME, "tank_inst")
    _, _, sent = play(model, {"iterations": "3", "samples": "100"}, rounds=2)
    assert len(sent) == 12
    assert max(np.count_nonzero(a["release"]) for a in sent) == 1


def test_choice_domain_picks_the_liked_items(tmp_path: Path) -> None:
    model = model_of(tmp_path, CHOICE, "pick_inst")
    (total,), _, _ = play(model, {"iterations": "4", "samples": "200"})
    assert total == 9.0  # 3 steps x (two liked items + @hi)


# -- options and registry ----------------------------------------------


def test_registered_and_options_checked() -> None:
    assert find_planner("mpc") is MPCPlanner
    with pytest.raises(PlannerError, match="option 'method' must be one of cem, mppi"):
        MPCPlanner(method="sgd")
    with pytest.raises(PlannerError, match="'horizon' must be an integer >= 1"):
        MPCPlanner(horizon="0")
    with pytest.raises(PlannerError, match="has no option 'budget'"):
        MPCPlanner(budget="3")


def test_memory_budget_bounds_the_batch(tmp_path: Path) -> None:
    model = model_of(tmp_path, CHOICE, "pick_inst")
    sim = Simulator(model)
    small = MPCPlanner(memory_mb="1", samples="100000", horizon="50")
    small.start_session(SessionInfo("pick", model, sim, 1, 10.0, 0))
    assert small.cap * small.per_sample <= 2**20
    assert small.cap < 100000
    big = MPCPlanner(samples="64")
    big.start_session(SessionInfo("pick", model, sim, 1, 10.0, 0))
    assert big.cap == 64


def test_out_of_time_it_draws_choices_instead_of_sending_noop(tmp_path: Path) -> None:
    # no time for one round of sampling (RecSim #4 on a loaded machine): the
    # plan was never refitted, so its flags and choices are drawn, not left
    # at their defaults (a random baseline rather than noop)
    model = model_of(tmp_path, CHOICE, "pick_inst")
    sim = Simulator(model)
    planner = MPCPlanner(seed="4", time_per_step="0")
    planner.start_session(SessionInfo("pick", model, sim, 1, 1e6, 4))
    planner.start_round(1)
    state = sim.initial_state(1)
    shown = 0
    for turn in range(1, 4):
        acts = planner.act(Observation(None, state, turn, 4 - turn, 1e6, 0.0, math.inf))
        decoded = WireCodec(sim).actions_from(acts)
        assert bool(sim.check_actions(state, decoded.arrays)[0])
        shown += int(decoded.arrays.get("show", np.zeros(1))[0].sum())
    assert planner.stats["refits"] == 0
    assert shown > 0


class _SlowClock:
    """A clock on which every reading is `step` seconds after the last (a
    machine starved of CPU)."""

    def __init__(self, step: float) -> None:
        self.now, self.step = 1000.0, step

    def monotonic(self) -> float:
        self.now += self.step
        return self.now

    perf_counter = monotonic


def test_iterations_mode_depends_on_the_seed_alone(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a fixed number of rounds: the same seed sends the same actions whether
    # the machine is fast or starved (every clock reading 5 s after the last),
    # and the batch and horizon are the options', not sized by timing
    import ippc.planners.mpc.planner as planner_module
    import ippc.planners.mpc.search as search_module

    model = model_of(tmp_path, RESERVOIR, "tank_inst")
    options = {"iterations": "2", "samples": "40", "horizon": "4"}
    _, fast, sent_fast = play(model, options, rounds=2, seed=9)
    slow_clock = _SlowClock(5.0)
    monkeypatch.setattr(planner_module, "time", slow_clock)
    monkeypatch.setattr(search_module, "time", slow_clock)
    _, slow, sent_slow = play(model, options, rounds=2, seed=9)
    assert (fast.n, fast.h_limit) == (slow.n, slow.h_limit) == (40, 4)
    assert len(sent_fast) == len(sent_slow) == 12
    for a, b in zip(sent_fast, sent_slow, strict=True):
        assert a.keys() == b.keys()
        for name in a:
            assert np.array_equal(a[name], b[name])
    assert fast.stats["refits"] == slow.stats["refits"] == 2 * 12
    # another seed plays otherwise (the seed is what decides)
    _, _, sent_other = play(model, options, rounds=2, seed=10)
    pairs = zip(sent_fast, sent_other, strict=True)
    assert any(not np.array_equal(a["release"], b["release"]) for a, b in pairs)
