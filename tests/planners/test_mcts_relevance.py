"""Action groundings that can never pay (planners/mcts/relevance.py): on the
IPPC domains where there are some (AcademicAdvising: the courses that lead to
no program requirement; Wildfire: cut-outs of target cells, which only cost),
against the exact planner's values on a small AcademicAdvising instance (the
best action among those left is as good as the best of all, in every state),
the reward rule (an action that pays is kept), the constraint rule (where noop
may be illegal nothing is left out) and the thts search's candidates."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ippc.planners.exact import solve
from ippc.planners.mcts.relevance import useless_actions
from ippc.rddl import load_pair
from ippc.rddl.model import Model
from ippc.rddl.sim.scalar import ScalarStep
from ippc.rddl.simulator import Simulator

from ..conftest import ippc_files
from .test_exact import model_of
from .test_mcts import observe
from .test_mcts_thts import planner_on


def useless_of(model: Model) -> list[tuple[str, tuple[int, ...]]]:
    return useless_actions(ScalarStep(Simulator(model)))


def requirement_closure(model: Model) -> set[str]:
    """The program requirements and their prerequisites, transitively."""
    nf = model.non_fluent_values
    need = {a[0] for (k, a), v in nf.items() if k.upper() == "PROGRAM_REQUIREMENT" and v}
    edges = [a for (k, a), v in nf.items() if k.upper() == "PREREQ" and v]
    grown = True
    while grown:
        grown = False
        for before, after in edges:
            if after in need and before not in need:
                need.add(before)
                grown = True
    return need


@pytest.mark.parametrize("year", ["IPPC2014", "IPPC2018"])
@pytest.mark.parametrize("n", [1, 2, 3, 4, 5])
def test_the_useful_courses_are_the_requirements_and_their_prerequisites(year: str, n: int) -> None:
    model = load_pair(*ippc_files(year, "AcademicAdvising", n))
    courses = model.types["course"].members
    useless = useless_of(model)
    assert {name for name, _ in useless} <= {"take-course", "takeCourse"}
    left_out = {courses[idx[0]] for _, idx in useless}
    assert set(courses) - left_out == requirement_closure(model)


def test_ippc_2018_academic_advising_4_keeps_the_chain_to_its_requirement() -> None:
    model = load_pair(*ippc_files("IPPC2018", "AcademicAdvising", 4))
    courses = model.types["course"].members
    kept = set(courses) - {courses[idx[0]] for _, idx in useless_of(model)}
    # c0402 (a requirement) needs c0300, which needs c0205, c0104, and c0104
    # needs c0005 and c0004 (the other requirement)
    assert kept == {"c0004", "c0005", "c0104", "c0205", "c0300", "c0402"}


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5])
def test_wildfire_cut_outs_of_target_cells_only_cost(n: int) -> None:
    # out-of-fuel' ignores cut-out on a TARGET cell, and cut-out costs
    model = load_pair(*ippc_files("IPPC2014", "Wildfire", n))
    xs, ys = model.types["x_pos"].members, model.types["y_pos"].members
    targets = {a for (k, a), v in model.non_fluent_values.items() if k == "TARGET" and v}
    useless = useless_of(model)
    assert {name for name, _ in useless} == {"cut-out"}
    assert {(xs[i], ys[j]) for _, (i, j) in useless} == targets


@pytest.mark.parametrize(
    ("year", "domain"),
    [("IPPC2011", "SysAdmin"), ("IPPC2011", "Elevators"), ("IPPC2011", "CooperativeRecon")],
)
def test_domains_where_every_action_may_pay_keep_them_all(year: str, domain: str) -> None:
    assert useless_of(load_pair(*ippc_files(year, domain, 1))) == []


def small_advising(tmp_path: Path) -> Model:
    """IPPC 2018's AcademicAdvising domain with five courses: r (the
    requirement) needs p, which needs q; x and y lead nowhere."""
    domain = Path(ippc_files("IPPC2018", "AcademicAdvising", 1)[0]).read_text()
    instance = """
non-fluents nf_small {
    domain = academic-advising_mdp;
    objects { course : { q, p, r, x, y }; };
    non-fluents {
        PREREQ(q, p); PREREQ(p, r); PREREQ(x, y);
        PRIOR_PROB_PASS_NO_PREREQ(q) = 0.7;
        PRIOR_PROB_PASS_NO_PREREQ(x) = 0.9;
        PRIOR_PROB_PASS(p) = 0.2;
        PRIOR_PROB_PASS(r) = 0.1;
        PRIOR_PROB_PASS(y) = 0.5;
        PROGRAM_REQUIREMENT(r);
        COURSE_COST = -1;
        COURSE_RETAKE_COST = -2;
    };
}
instance small {
    domain = academic-advising_mdp;
    non-fluents = nf_small;
    horizon = 6;
    discount = 1.0;
}
"""
    return model_of(tmp_path, domain + instance, "small")


def test_the_best_action_left_is_as_good_as_the_best_of_all(tmp_path: Path) -> None:
    """In every reachable state and with any steps left, the exact optimum
    over the joint actions that set no useless grounding equals the optimum
    over all of them; and leaving out a useful course would lose value."""
    model = small_advising(tmp_path)
    useless = useless_of(model)
    courses = model.types["course"].members
    assert {courses[idx[0]] for _, idx in useless} == {"x", "y"}
    sol = solve(model)
    take = sol.actions["take-course"]
    kept = ~take[:, [courses.index("x"), courses.index("y")]].any(axis=1)
    without_q = ~take[:, courses.index("q")]
    lost = 0.0
    for k in range(1, len(sol.q)):
        q = sol.q[k]
        np.testing.assert_allclose(q[:, kept].max(axis=1), q.max(axis=1), atol=1e-9)
        lost = max(lost, float((q.max(axis=1) - q[:, kept & without_q].max(axis=1)).max()))
    assert lost > 0.01


PAYS = """
domain pays {
    requirements = { concurrent, reward-deterministic };
    pvariables {
        BONUS : { non-fluent, real, default = 1.0 };
        goal : { state-fluent, bool, default = false };
        trophy : { state-fluent, bool, default = false };
        work : { action-fluent, bool, default = false };
        play : { action-fluent, bool, default = false };
    };
    cpfs {
        goal' = goal | (work & Bernoulli(0.5));
        trophy' = trophy | play;
    };
    reward = goal + BONUS * (play & ~trophy);
}
non-fluents nf_pays { domain = pays; non-fluents { BONUS = 1.0; }; }
non-fluents nf_costs { domain = pays; non-fluents { BONUS = -1.0; }; }
instance pays_inst { domain = pays; non-fluents = nf_pays; horizon = 4; discount = 1.0; }
instance costs_inst { domain = pays; non-fluents = nf_costs; horizon = 4; discount = 1.0; }
"""


@pytest.mark.parametrize(("instance", "useless"), [("pays_inst", []), ("costs_inst", ["play"])])
def test_an_action_that_touches_no_relevant_state_is_kept_when_it_pays(
    tmp_path: Path, instance: str, useless: list[str]
) -> None:
    # `trophy` matters only to play's own reward term: with a bonus, play pays
    # once; with a cost it never does
    model = model_of(tmp_path, PAYS, instance)
    assert [name for name, _ in useless_of(model)] == useless


MUST_ACT = """
domain must_act {
    requirements = { concurrent, reward-deterministic, preconditions };
    pvariables {
        goal : { state-fluent, bool, default = false };
        work : { action-fluent, bool, default = false };
        idle : { action-fluent, bool, default = false };
    };
    cpfs { goal' = goal | (work & Bernoulli(0.5)); };
    reward = goal - 0.5 * idle;
    action-preconditions { work + idle == 1; };
}
instance must_act_inst { domain = must_act; horizon = 4; discount = 1.0; }
"""


def test_nothing_is_left_out_where_noop_may_be_illegal(tmp_path: Path) -> None:
    # idle only costs, but leaving it out of a joint action can make it illegal
    assert useless_of(model_of(tmp_path, MUST_ACT, "must_act_inst")) == []


@pytest.mark.parametrize("prune", ["yes", "no"])
def test_the_thts_candidates_take_no_course_that_leads_nowhere(prune: str) -> None:
    model = load_pair(*ippc_files("IPPC2018", "AcademicAdvising", 4))
    planner, sim = planner_on(model, iterations="20", seed="1", prune_useless=prune)
    search = planner._thts
    assert search is not None
    state = sim.initial_state(1)
    planner.act(observe(sim, state, 1, 20))
    rows = search._candidates(search.fast.encode_state(state))
    acts = search.chooser.lib.take(np.array(rows))
    courses = model.types["course"].members
    taken = {courses[i] for _, i in np.argwhere(acts["take-course"])}
    if prune == "yes":
        assert taken == {"c0004", "c0005", "c0104", "c0205", "c0300", "c0402"}
    else:
        assert taken == set(courses)
    assert rows[0] == 0  # noop first
