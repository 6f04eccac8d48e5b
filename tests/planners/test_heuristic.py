"""The IDS heuristic on the most-likely determinisation and reward-lock
detection (ippc.planners.mcts.heuristic): depth-d values against the exact
values of the determinised model (value iteration, `planners.exact`), the
scaling to the steps left, PROST's stopping rules and learning phase with a
made-up clock, and dead ends, goals and non-locks on hand-made domains and
on IPPC instances."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ippc.planners.determinise import determinise
from ippc.planners.exact import solve
from ippc.planners.mcts.heuristic import IDS, RewardLocks, training_states
from ippc.rddl import load, load_pair
from ippc.rddl.model import Model
from ippc.rddl.simulator import Simulator, State

from ..conftest import ippc_files
from .test_exact import model_of

TINY = Path(__file__).resolve().parent / "tiny_domains"

# A chain: `go` moves one cell right with probability 0.7 (most likely: it
# moves), `jump` two cells with probability 0.4 (most likely: it stays);
# the last cell pays 10 a step, every other cell -1; `go` costs 0.5.
CHAIN = """
domain chain {
    requirements = { concurrent };
    types { cell : object; };
    pvariables {
        NEXT(cell, cell) : { non-fluent, bool, default = false };
        NEXT2(cell, cell) : { non-fluent, bool, default = false };
        LAST(cell) : { non-fluent, bool, default = false };
        at(cell) : { state-fluent, bool, default = false };
        go : { action-fluent, bool, default = false };
        jump : { action-fluent, bool, default = false };
    };
    cpfs {
        at'(?c) = if (go ^ exists_{?d : cell} [at(?d) ^ NEXT(?d, ?c)]) then Bernoulli(0.7)
                  else if (go ^ at(?c) ^ ~LAST(?c)) then Bernoulli(0.3)
                  else if (jump ^ exists_{?d : cell} [at(?d) ^ NEXT2(?d, ?c)]) then Bernoulli(0.4)
                  else if (jump ^ at(?c) ^ ~LAST(?c)) then Bernoulli(0.6)
                  else at(?c);
    };
    reward = (sum_{?c : cell} [at(?c) ^ LAST(?c)]) * 10.0
             - (sum_{?c : cell} [at(?c) ^ ~LAST(?c)]) - 0.5 * go;
}
non-fluents chain_nf {
    domain = chain;
    objects { cell : {c1, c2, c3, c4, c5}; };
    non-fluents {
        NEXT(c1, c2); NEXT(c2, c3); NEXT(c3, c4); NEXT(c4, c5);
        NEXT2(c1, c3); NEXT2(c2, c4); NEXT2(c3, c5);
        LAST(c5);
    };
}
instance chain_inst {
    domain = chain;
    non-fluents = chain_nf;
    init-state { at(c1); };
    max-nondef-actions = 1;
    horizon = 8;
    discount = 1.0;
}
"""

# A goal: once `done` holds it pays 1 forever and nothing undoes it (the
# `noise` fluent keeps changing); `finish` makes `done` with probability 0.5
GOAL = """
domain goal {
    requirements = { concurrent };
    pvariables {
        done : { state-fluent, bool, default = false };
        noise : { state-fluent, bool, default = false };
        spoil : { state-fluent, bool, default = false };
        finish : { action-fluent, bool, default = false };
    };
    cpfs {
        done' = done | (finish ^ Bernoulli(0.5));
        noise' = Bernoulli(0.5);
        spoil' = spoil;
    };
    reward = if (done ^ ~spoil) then 1 else 0;
}
instance goal_inst {
    domain = goal;
    max-nondef-actions = 1;
    horizon = 5;
    discount = 1.0;
}
"""


def det_states(model: Model, count: int, seed: int = 0) -> State:
    """The initial state and states the determinised model reaches from it
    under random actions (so that the exact solution of that model has them)."""
    det = Simulator(determinise(model))
    rng = np.random.default_rng(seed)
    s = det.initial_state(1)
    out = [s]
    for _ in range(count - 1):
        s = det.step(s, det.random_actions(s, rng), None, check=False).next_state  # type: ignore[arg-type]
        out.append(s)
    return State({k: np.concatenate([x.values[k] for x in out]) for k in out[0].values})


def exact_check(model: Model, depths: range, count: int = 6) -> None:
    """IDS's depth-d values equal the determinised model's exact d-step Q-values."""
    sol = solve(determinise(model))
    ids = IDS.for_model(model, reasonable_action=False, max_depth=max(depths))
    assert ids.table is not None
    states = det_states(model, count)
    for d in depths:
        got = ids.estimate(states, [d] * states.batch, [ids.table] * states.batch)
        for i in range(states.batch):
            want = sol.q[d][sol.index(states, i)]
            # the table is enumerated in the solution's order (noop first)
            np.testing.assert_allclose(got[i], want, rtol=0, atol=1e-9)


def test_chain_values_equal_exact_determinised_values(tmp_path: Path) -> None:
    exact_check(model_of(tmp_path, CHAIN, "chain_inst"), range(1, 9))


def test_chain_by_hand(tmp_path: Path) -> None:
    # determinised: go moves one cell on, jump stays; the reward reads the
    # current cell. From c1 with 4 steps: noop -1 x 4 = -4; go -1.5, then
    # from c2 with 3 steps nothing beats noop (-3; going on pays -1.5 x 3 - 1
    # = -5.5): -4.5; jump -1, then from c1 with 3 steps -3: -4
    ids = IDS.for_model(model_of(tmp_path, CHAIN, "chain_inst"), reasonable_action=False)
    s = ids.det.initial_state(1)
    q = ids.estimate(s, [4], [ids.table])[0]  # type: ignore[list-item]
    assert q.tolist() == pytest.approx([-4.0, -4.5, -4.0])
    # with 5 steps go reaches c5 after 4 moves: -1.5*4 + 10 = 4
    q5 = ids.estimate(s, [5], [ids.table])[0]  # type: ignore[list-item]
    assert q5.tolist() == pytest.approx([-5.0, 4.0, -5.0])


def test_trap_values_equal_exact(tmp_path: Path) -> None:
    exact_check(load(TINY / "trap.rddl")["tiny_trap_inst"], range(1, 6), count=3)


def test_sysadmin_values_equal_exact() -> None:
    model = load_pair(*ippc_files("IPPC2011", "SysAdmin/MDP", 1))
    exact_check(model, range(1, 4), count=4)


def test_scaled_to_the_steps_left(tmp_path: Path) -> None:
    model = model_of(tmp_path, CHAIN, "chain_inst")
    ids = IDS.for_model(model, reasonable_action=False, max_depth=4)
    s = ids.det.initial_state(1)
    q4 = ids.estimate(s, [4], [ids.table])[0]  # type: ignore[list-item]
    q8 = ids.estimate(s, [8], [ids.table])[0]  # type: ignore[list-item]
    np.testing.assert_allclose(q8, 2 * q4)  # depth 4, scaled by 8 / 4
    assert ids.stats.depth_sum == 8


def test_discounted_scaling(tmp_path: Path) -> None:
    text = CHAIN.replace("discount = 1.0", "discount = 0.9")
    ids = IDS.for_model(
        model_of(tmp_path, text, "chain_inst"), reasonable_action=False, max_depth=2
    )
    s = ids.det.initial_state(1)
    q = ids.estimate(s, [6], [ids.table])[0]  # type: ignore[list-item]
    # noop: -1 - 0.9 over 2 steps, scaled by (1 - 0.9**6) / (1 - 0.9**2)
    factor = (1 - 0.9**6) / (1 - 0.9**2)
    assert q[0] == pytest.approx((-1 - 0.9) * factor)


def test_reasonable_action_stops_the_deepening(tmp_path: Path) -> None:
    # at depth 2 from c4, go (reaching c5) beats noop: PROST stops there
    model = model_of(tmp_path, CHAIN, "chain_inst")
    ids = IDS.for_model(model, max_depth=6)
    det = ids.det
    s = det.initial_state(1)
    s.values["at"][0] = [False, False, False, True, False]
    q = ids.estimate(s, [6], [ids.table])[0]  # type: ignore[list-item]
    assert ids.stats.depth_sum == 2
    assert q[1] > q[0]
    # without the test it goes to the depth limit
    ids2 = IDS.for_model(model, max_depth=6, reasonable_action=False)
    ids2.estimate(s, [6], [ids2.table])  # type: ignore[list-item]
    assert ids2.stats.depth_sum == 6
    # from c1 nothing beats noop at depth 2 (-2 vs -3.5, -2): deeper
    ids3 = IDS.for_model(model, max_depth=6)
    ids3.estimate(det.initial_state(1), [6], [ids3.table])  # type: ignore[list-item]
    assert ids3.stats.depth_sum > 2


def test_many_roots_at_once_equal_one_at_a_time(tmp_path: Path) -> None:
    model = model_of(tmp_path, CHAIN, "chain_inst")
    states = det_states(model, 5)
    steps = [8, 3, 5, 1, 7]
    ids = IDS.for_model(model, max_depth=5)
    assert ids.table is not None
    # each root its own candidates: a subset of the table
    cands = [{k: v[[0, 1]] for k, v in ids.table.items()}, ids.table] * 2 + [ids.table]
    together = ids.estimate(states, steps, cands)
    for i in range(states.batch):
        alone = ids.estimate(states[i], [steps[i]], [cands[i]])[0]
        np.testing.assert_allclose(together[i], alone)


def test_illegal_candidates_are_minus_infinity(tmp_path: Path) -> None:
    text = CHAIN.replace("reward =", "action-preconditions { jump => ~at($c1); };\n    reward =")
    ids = IDS.for_model(model_of(tmp_path, text, "chain_inst"), reasonable_action=False)
    s = ids.det.initial_state(1)
    q = ids.estimate(s, [3], [ids.table])[0]  # type: ignore[list-item]
    assert np.isneginf(q[2]) and np.isfinite(q[:2]).all()
    assert ids.legal_table(s)["jump"].tolist() == [False, False]


class StepClock:
    """A clock that advances `tick` seconds per reading."""

    def __init__(self, tick: float) -> None:
        self.t = 0.0
        self.tick = tick

    def __call__(self) -> float:
        self.t += self.tick
        return self.t


def test_learning_picks_the_depth_that_fits_the_timeout(tmp_path: Path) -> None:
    model = model_of(tmp_path, CHAIN, "chain_inst")
    sim = Simulator(model)
    train = training_states(sim, np.random.default_rng(1), count=6)
    # every clock reading adds 1 ms; while learning, a search reads the
    # clock twice per level from depth 2 on, so depth d takes 2 (d - 1) ms:
    # depth 3 (4 ms) fits in 5 ms, depth 4 (6 ms) does not
    ids = IDS.for_model(model, clock=StepClock(0.001), timeout=0.005)
    learned = ids.learn(train, steps=8)
    assert learned == 3 and not ids.fallback
    ids2 = IDS.for_model(model, clock=StepClock(0.001), timeout=0.1)
    assert ids2.learn(train, steps=8) == 8  # the cap: the steps left
    # three states searched together are charged a third of the time each:
    # depth d costs 2 (d - 1) / 3 ms a state, and depth 5 fits in 3 ms
    ids4 = IDS.for_model(model, clock=StepClock(0.001), timeout=0.003)
    assert ids4.learn(train, steps=8, batch=3) == 5
    ids3 = IDS.for_model(model, clock=StepClock(0.001), timeout=0.001)
    assert ids3.learn(train, steps=8) == 1 and ids3.fallback
    # the fallback looks one step ahead (immediate reward x steps left)
    q = ids3.estimate(ids3.det.initial_state(1), [4], [ids3.table])[0]  # type: ignore[list-item]
    assert q.tolist() == pytest.approx([-4.0, -6.0, -4.0])


def test_a_passed_deadline_stops_at_depth_one(tmp_path: Path) -> None:
    ids = IDS.for_model(model_of(tmp_path, CHAIN, "chain_inst"), clock=StepClock(1.0))
    q = ids.estimate(ids.det.initial_state(1), [4], [ids.table], deadline=0.5)[0]  # type: ignore[list-item]
    assert q.tolist() == pytest.approx([-4.0, -6.0, -4.0])


# -- reward locks ------------------------------------------------------------


def test_trap_dead_end_and_non_lock() -> None:
    model = load(TINY / "trap.rddl")["tiny_trap_inst"]
    ids = IDS.for_model(model)
    locks = RewardLocks(model, ids.table)  # type: ignore[arg-type]
    assert (locks.min_reward, locks.max_reward) == (-20.0, 11.0)
    s = locks.sim.initial_state(1)
    assert locks.check(s) is None  # alive: reward 0 under noop
    s.values["dead"][0] = True
    assert locks.check(s) == "dead end"
    # action by action (PROST's way) finds the same
    precise = RewardLocks(model, ids.table, per_action=True)  # type: ignore[arg-type]
    assert precise.check(s) == "dead end"
    assert precise.check(locks.sim.initial_state(1)) is None


def test_goal_and_spoiled_goal(tmp_path: Path) -> None:
    model = model_of(tmp_path, GOAL, "goal_inst")
    locks = RewardLocks(model, IDS.for_model(model).table)  # type: ignore[arg-type]
    s = locks.sim.initial_state(1)
    assert locks.check(s) is None  # reward 0, but finish can change it
    s.values["done"][0] = True
    assert locks.check(s) == "goal"  # noise keeps changing: not part of the reward
    s.values["spoil"][0] = True
    # reward 0 forever (spoil stays): a dead end
    assert locks.check(s) == "dead end"
    s.values["done"][0] = False
    assert locks.check(s) == "dead end"


def test_a_lock_for_the_steps_left(tmp_path: Path) -> None:
    # not done yet: finish can make it done, but its reward shows a step
    # later, so with one step left the reward is 0 whatever happens
    model = model_of(tmp_path, GOAL, "goal_inst")
    locks = RewardLocks(model, IDS.for_model(model).table)  # type: ignore[arg-type]
    s = locks.sim.initial_state(1)
    assert locks.check(s) is None
    assert locks.check(s, steps_left=1) == "dead end"
    assert locks.check(s, steps_left=2) is None
    # the trap's alive state: its reward changes at once (risky pays 6)
    trap = load(TINY / "trap.rddl")["tiny_trap_inst"]
    trap_locks = RewardLocks(trap, IDS.for_model(trap).table)  # type: ignore[arg-type]
    assert trap_locks.check(trap_locks.sim.initial_state(1), steps_left=1) is None


def test_a_goal_left_by_noop_is_not_one(tmp_path: Path) -> None:
    text = GOAL.replace("done' = done | (finish ^ Bernoulli(0.5));", "done' = finish;")
    model = model_of(tmp_path, text, "goal_inst")
    locks = RewardLocks(model, IDS.for_model(model).table)  # type: ignore[arg-type]
    s = locks.sim.initial_state(1)
    s.values["done"][0] = True
    assert locks.check(s) is None


def test_crossing_traffic_robot_gone_is_a_dead_end() -> None:
    model = load_pair(*ippc_files("IPPC2011", "CrossingTraffic/MDP", 1))
    locks = RewardLocks(model, IDS.for_model(model).table)  # type: ignore[arg-type]
    assert locks.supported
    s = locks.sim.initial_state(1)
    assert locks.check(s) is None
    s.values["robot-at"][0] = False  # hit by an obstacle: the robot is gone
    assert locks.check(s) == "dead end"
