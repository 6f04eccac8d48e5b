"""The simulator's compiler: what its optimisations must not change.

The step is compiled twice (for small and for large batches, with different
strategies: matrix products or row gathers, logical operations or
np.where, copies to a contiguous layout); both must make the same draws
and compute the same values. Folded constants, parameter checks proved
unnecessary by bounds, contractions of relations, the random policy's
batched search: each against a plain computation of the same thing.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ippc.rddl import load, load_model
from ippc.rddl.sim.actions import _random_value
from ippc.rddl.simulator import (
    _LARGE_BATCH,
    RANDOM_MAX_CONCURRENT,
    SimulationError,
    Simulator,
    State,
)

REPO = Path(__file__).resolve().parents[2]
DOMAINS = REPO / "domains"

RDDLSIM = [
    "sysadmin_inst_mdp__1",
    "game_of_life_inst_mdp__1",
    "elevators_inst_mdp__1",
    "crossing_traffic_inst_mdp__1",
    "inst_traffic_binary_ctm",
]


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    if a.dtype.kind == "f":
        return bool(np.allclose(a, b, rtol=1e-12, atol=1e-12, equal_nan=True))
    return bool((a == b).all())


def compare_variants(sim: Simulator, batch: int, steps: int, seed: int = 0) -> None:
    """Step the same states with the code for small and for large batches:
    the same values, the same draws (the generators stay in step)."""
    assert batch >= _LARGE_BATCH
    small, large = sim._step_small, sim._step_fn(batch)
    assert small is not large
    state = sim.initial_state(batch)
    pick = np.random.default_rng(seed + 1)
    for _ in range(steps):
        try:
            actions = sim.random_actions(state, pick)
        except SimulationError:
            actions = sim.noop(batch)
        acts = sim._actions(actions, batch)
        r1, r2 = np.random.default_rng(seed), np.random.default_rng(seed)
        out1 = out2 = None
        err1 = err2 = None
        with np.errstate(all="ignore"):
            try:
                out1 = small(state.values, acts, batch, r1, True)
            except SimulationError as e:
                err1 = str(e)
            try:
                out2 = large(state.values, acts, batch, r2, True)
            except SimulationError as e:
                err2 = str(e)
        assert err1 == err2
        if err1 is not None:
            return
        assert out1 is not None and out2 is not None
        nxt1, rew1, obs1, done1 = out1
        nxt2, rew2, obs2, done2 = out2
        for k in nxt1:
            assert nxt1[k].shape == (batch, *sim._compiler.shape_of(sim.model.pvariables[k]))
            assert _same(nxt1[k], nxt2[k]), k
        assert _same(rew1, rew2) and _same(done1, done2)
        assert (obs1 is None) == (obs2 is None)
        if obs1 is not None:
            assert obs1.keys() == obs2.keys()
            assert all(_same(obs1[k], obs2[k]) for k in obs1)
        assert r1.random() == r2.random()  # as many draws, in the same order
        state = State(nxt1)


@pytest.mark.parametrize("name", RDDLSIM)
def test_small_and_large_batch_code_agree(rddlsim_rddl: Path, name: str) -> None:
    sim = Simulator(load(rddlsim_rddl)[name])
    compare_variants(sim, batch=40, steps=6)


def test_small_and_large_batch_code_agree_on_the_examples() -> None:
    for folder, name in [("corridor_enum", "corridor_enum_inst_1"), ("print_jobs", "print_jobs_inst_2"),
                         ("print_jobs_pomdp", None)]:  # fmt: skip
        models = load(DOMAINS / folder)
        for key, model in models.items():
            if name is None or key == name:
                compare_variants(Simulator(model), batch=24, steps=5)


def test_checks_agree_in_both_variants(rddlsim_rddl: Path) -> None:
    sim = Simulator(load(rddlsim_rddl)["elevators_inst_mdp__1"])
    state = sim.initial_state(64)
    rng = np.random.default_rng(3)
    actions = sim.noop(64)
    for p in sim.action_fluents:  # many actions at once: some states illegal
        actions[p.name][...] = rng.random(actions[p.name].shape) < 0.3
    small = sim.check_actions(
        state[: _LARGE_BATCH - 1], {k: v[: _LARGE_BATCH - 1] for k, v in actions.items()}
    )
    large = sim.check_actions(state, actions)
    assert large.shape == (64,) and large.dtype == bool
    assert 0 < large.sum() < 64
    assert (large[: _LARGE_BATCH - 1] == small).all()
    by_one = [
        bool(sim.check_actions(state[i], {k: v[i : i + 1] for k, v in actions.items()})[0])
        for i in range(64)
    ]
    assert large.tolist() == by_one


def test_next_state_is_owned_and_batch_first(rddlsim_rddl: Path) -> None:
    sim = Simulator(load(rddlsim_rddl)["elevators_inst_mdp__1"])
    for batch in (3, 40):
        s = sim.initial_state(batch)
        before = {k: v.copy() for k, v in s.values.items()}
        out = sim.step(s, None, np.random.default_rng(0))
        for k, v in out.next_state.values.items():
            shape = sim._compiler.shape_of(sim.model.pvariables[k])
            assert v.shape == (batch, *shape)
            assert not np.shares_memory(v, s.values[k])
            for k2, v2 in out.next_state.values.items():
                assert k2 == k or not np.shares_memory(v, v2)
            v[...] = np.zeros_like(v)  # the caller's to change
        assert all((s.values[k] == before[k]).all() for k in before)
        # indexing and copying a state made by a step
        one = out.next_state[1]
        assert one.batch == 1 and out.next_state.copy().batch == batch


FOLD = """\
domain fold { types { obj : object; };
  pvariables {
    W(obj) : { non-fluent, real, default = 0.5 };
    REL(obj, obj) : { non-fluent, bool, default = false };
    p(obj) : { state-fluent, bool, default = false };
    q(obj) : { state-fluent, real, default = 0.0 };
    c(obj) : { interm-fluent, int, level = 1 };
    a(obj) : { action-fluent, bool, default = false }; };
  cpfs {
    c(?x) = sum_{?y : obj} [REL(?y, ?x) ^ p(?y)];
    p'(?x) = Bernoulli(0.25 + 0.5 * c(?x) / [1 + sum_{?y : obj} REL(?y, ?x)]) | a(?x);
    q'(?x) = q(?x) + (sum_{?y : obj} [W(?y) * REL(?x, ?y) * (q(?y) - q(?x))]) + exp[W(?x)]; };
  reward = sum_{?x : obj} [p(?x) - W(?x) * a(?x)]; }
non-fluents fold_nf { domain = fold; objects { obj : {o1, o2, o3, o4, o5, o6, o7, o8, o9}; };
  non-fluents { W(o2) = 2.0; REL(o1, o2); REL(o2, o3); REL(o3, o1); REL(o4, o1); REL(o5, o6);
                REL(o6, o5); REL(o7, o8); REL(o8, o9); REL(o9, o7); REL(o2, o1); }; }
instance fold_1 { domain = fold; non-fluents = fold_nf;
  init-state { p(o1); p(o5); q(o1) = 1.0; q(o2) = -2.0; q(o7) = 3.5; };
  max-nondef-actions = 2; horizon = 10; discount = 1.0; }
"""


def _fold_sim(tmp_path: Path, text: str = FOLD) -> Simulator:
    (tmp_path / "fold.rddl").write_text(text)
    return Simulator(load_model(tmp_path))


def test_contractions_and_folds_compute_the_definitions(tmp_path: Path) -> None:
    sim = _fold_sim(tmp_path)
    m = sim.model
    objs = m.objects("obj")
    n = len(objs)
    rel = np.zeros((n, n), dtype=bool)
    for (name, args), v in m.non_fluent_values.items():
        if name == "REL" and v:
            rel[objs.index(args[0]), objs.index(args[1])] = True
    w = np.full(n, 0.5)
    w[1] = 2.0
    for batch in (5, 40):
        rng = np.random.default_rng(9)
        state = sim.initial_state(batch)
        state.values["p"][...] = rng.random((batch, n)) < 0.5
        state.values["q"][...] = rng.normal(size=(batch, n))
        acts = sim.noop(batch)
        acts["a"][:, 3] = True
        out = sim.step(state, acts, np.random.default_rng(1))
        p, q = state.values["p"], state.values["q"]
        # q'(x) = q(x) + sum_y W(y) REL(x, y) (q(y) - q(x)) + exp(W(x))
        want_q = q + ((w * rel)[None] * (q[:, None, :] - q[:, :, None])).sum(axis=2) + np.exp(w)
        assert np.allclose(out.next_state.values["q"], want_q, rtol=1e-12, atol=1e-12)
        # reward: running count minus the penalty of the actions taken
        want_r = p.sum(axis=1) - w[3]
        assert np.allclose(out.reward, want_r)
        # p'(x) = Bernoulli(...) | a(x): the drawn values are those of the
        # step's uniform 32-bit integers (the raw 64-bit outputs cut in two,
        # laid out batch last) against the probability scaled by 2**32
        counts = (rel[None] & p[:, :, None]).sum(axis=1)
        prob = 0.25 + 0.5 * counts / (1 + rel.sum(axis=0))
        raw = np.random.default_rng(1).bit_generator.random_raw((n * batch + 1) // 2)
        u = raw.view(np.uint32)[: n * batch].reshape(n, batch).T
        assert (out.next_state.values["p"] == ((u < prob * 2.0**32) | acts["a"])).all()


def test_parameter_checks_stay_where_bounds_do_not_prove_them(tmp_path: Path) -> None:
    # 0.25 + 0.5 * c / (1 + in-degree) is within [0, 1]: no check at run time
    sim = _fold_sim(tmp_path)
    assert "_cnz(_lt(" not in sim.source()
    # with 0.75 + ... it is not (above 1 where enough neighbours are on):
    # checked, and raised when it happens
    sim2 = _fold_sim(tmp_path, FOLD.replace("Bernoulli(0.25 +", "Bernoulli(0.75 +"))
    assert "_cnz(_lt(" in sim2.source()
    s = sim2.initial_state(2)
    s.values["p"][1] = True
    with pytest.raises(SimulationError, match=r"Bernoulli probability outside \[0, 1\]: 1\.\d+"):
        sim2.step(s, None, np.random.default_rng(0))
    s.values["p"][1] = False
    sim2.step(s, None, np.random.default_rng(0))  # every probability within [0, 1]: no error
    # a real-valued state fluent has no bounds: checked
    sim3 = _fold_sim(
        tmp_path,
        FOLD.replace(
            "Bernoulli(0.25 + 0.5 * c(?x) / [1 + sum_{?y : obj} REL(?y, ?x)])", "Bernoulli(q(?x))"
        ),
    )
    s3 = sim3.initial_state(40)
    with pytest.raises(SimulationError, match=r"probability outside \[0, 1\]: -2\.0"):
        sim3.step(s3, None, np.random.default_rng(0))


def test_constant_conditions_and_folded_constraints(tmp_path: Path) -> None:
    text = FOLD.replace(
        "q'(?x) = q(?x) + (sum_{?y : obj} [W(?y) * REL(?x, ?y) * (q(?y) - q(?x))]) + exp[W(?x)];",
        "q'(?x) = if (W(o2) > 1) then q(?x) + 1 else Bernoulli(0.5) + q(?x);",
    ).replace(
        "reward =",
        "state-action-constraints { forall_{?x : obj} W(?x) >= 0; exists_{?x : obj} W(?x) > 1; }; reward =",
    )
    sim = _fold_sim(tmp_path, text)
    src = sim.source()
    # the uniform condition picks its branch; the other one (which would
    # draw) is not taken, so it draws nothing (as rddlsim): the step's
    # uniforms are p's Bernoulli's alone, one per object
    n = len(sim.model.objects("obj"))
    assert src.count("_uniforms(") == 1
    assert f"_uniforms(rng, {n} * B)" in src
    out = sim.step(sim.initial_state(2), None, np.random.default_rng(0))
    assert np.allclose(out.next_state.values["q"], sim.initial_state(2).values["q"] + 1)
    # constraints that hold for every state and action fold away; one that
    # fails for every state raises at run time, not when building
    assert sim.check_actions(sim.initial_state(3), sim.noop(3)).all()
    failing = _fold_sim(
        tmp_path, text.replace("exists_{?x : obj} W(?x) > 1", "exists_{?x : obj} W(?x) > 5")
    )
    with pytest.raises(SimulationError, match="constraint violated"):
        failing.step(failing.initial_state(), None, np.random.default_rng(0))
    assert not failing.check_actions(failing.initial_state(2), failing.noop(2)).any()


def test_same_seed_same_trajectory_in_both_variants(rddlsim_rddl: Path) -> None:
    sim = Simulator(load(rddlsim_rddl)["game_of_life_inst_mdp__1"])

    def run(batch: int, seed: int) -> list[np.ndarray]:
        rng = np.random.default_rng(seed)
        s = sim.initial_state(batch)
        out = []
        for _ in range(4):
            step = sim.step(s, None, rng)
            s = step.next_state
            out.append(s.values["alive"].copy())
        return out

    for batch in (2, 40):
        a, b, c = run(batch, 3), run(batch, 3), run(batch, 4)
        assert all((x == y).all() for x, y in zip(a, b, strict=True))
        assert any((x != z).any() for x, z in zip(a, c, strict=True))


# ----------------------------------------------------------- random policy


def reference_random_actions(
    sim: Simulator, state: State, rng: np.random.Generator
) -> dict[str, np.ndarray]:
    """The random policy one candidate at a time, as rddlsim's loop goes
    (the same draws as `Simulator.random_actions`, in the same order)."""
    batch = state.batch
    actions = sim.noop(batch)
    limit = RANDOM_MAX_CONCURRENT
    if sim.model.max_nondef_actions is not None:
        limit = min(limit, sim.model.max_nondef_actions)
    taken = np.zeros(batch, dtype=int)
    for p in sim.action_fluents:
        flat = actions[p.name].reshape(batch, -1)
        n = flat.shape[1]
        if n == 0:
            continue
        order = np.argsort(rng.random((batch, n)), axis=1, kind="stable")
        heads = rng.random((batch, n)) < 0.5
        if not sim._preconditions:
            rank = taken[:, None] + np.cumsum(heads, axis=1)
            heads &= rank <= limit
            rows = np.nonzero(heads)
            flat[rows[0], order[rows]] = _random_value(sim, p, rng, len(rows[0]))
            taken += heads.sum(axis=1)
            continue
        values = _random_value(sim, p, rng, batch * n).reshape(batch, n)
        for b in range(batch):
            for j in np.nonzero(heads[b])[0]:
                if taken[b] >= limit:
                    break
                trial = {k: v[b : b + 1].copy() for k, v in actions.items()}
                trial[p.name].reshape(1, -1)[0, order[b, j]] = values[b, j]
                if sim.check_actions(state[b], trial)[0]:
                    flat[b, order[b, j]] = values[b, j]
                    taken[b] += 1
    return actions


@pytest.mark.parametrize(
    "folder, name",
    [("print_jobs", "print_jobs_inst_2"), ("corridor_enum", "corridor_enum_inst_1")],
)
def test_random_policy_matches_the_sequential_rule(folder: str, name: str) -> None:
    sim = Simulator(load(DOMAINS / folder)[name])
    state = sim.initial_state(6)
    for seed in range(8):
        got = sim.random_actions(state, np.random.default_rng(seed))
        want = reference_random_actions(sim, state, np.random.default_rng(seed))
        assert got.keys() == want.keys()
        assert all((got[k] == want[k]).all() for k in got), seed
        state = sim.step(state, got, np.random.default_rng(seed)).next_state


CAP = """\
domain cap { types { obj : object; };
  pvariables {
    p(obj) : { state-fluent, bool, default = false };
    a(obj) : { action-fluent, bool, default = false };
    b(obj) : { action-fluent, bool, default = false }; };
  cpfs { p'(?x) = a(?x) | b(?x); };
  reward = sum_{?x : obj} p(?x);
  action-preconditions { forall_{?x : obj} ~(a(?x) ^ b(?x)); (sum_{?x : obj} a(?x)) <= 7; }; }
instance cap_1 { domain = cap; objects { obj : {%s}; };
  max-nondef-actions = pos-inf; horizon = 4; discount = 1.0; }
"""


def test_random_policy_takes_at_most_rddlsims_cap_and_follows_the_rule(tmp_path: Path) -> None:
    objs = ", ".join(f"o{i}" for i in range(60))
    (tmp_path / "cap.rddl").write_text(CAP % objs)
    sim = Simulator(load_model(tmp_path))
    state = sim.initial_state(5)
    for seed in range(4):
        got = sim.random_actions(state, np.random.default_rng(seed))
        counts = sim.count_nondefault(got, 5)
        assert (counts == RANDOM_MAX_CONCURRENT).all()  # 60 + 60 coin flips: the cap binds
        assert (got["a"].sum(axis=1) <= 7).all() and not (got["a"] & got["b"]).any()
        assert sim.check_actions(state, got).all()
        want = reference_random_actions(sim, state, np.random.default_rng(seed))
        assert all((got[k] == want[k]).all() for k in got), seed
    # without constraints the cap binds too (the all-at-once path)
    (tmp_path / "cap.rddl").write_text(
        (CAP % objs).replace(
            "action-preconditions { forall_{?x : obj} ~(a(?x) ^ b(?x)); (sum_{?x : obj} a(?x)) <= 7; };",
            "",
        )
    )
    free = Simulator(load_model(tmp_path))
    got = free.random_actions(free.initial_state(5), np.random.default_rng(0))
    assert (free.count_nondefault(got, 5) == RANDOM_MAX_CONCURRENT).all()
    want = reference_random_actions(free, free.initial_state(5), np.random.default_rng(0))
    assert all((got[k] == want[k]).all() for k in got)
