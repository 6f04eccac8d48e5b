"""PDDL problem generation: checked by an independent parser (the `pddl`
package), and solved by Fast Downward (the `up-fast-downward` package's
build) on the print-fetching domain, whose plan then reaches the goal in the
most-likely determinisation of the RDDL model."""

from __future__ import annotations

import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from ippc.kb import KBError, KnowledgeBase, Update
from ippc.planners.determinise import determinise
from ippc.rddl import load
from ippc.rddl.simulator import Simulator
from pddl.parser.domain import DomainParser
from pddl.parser.problem import ProblemParser

from .conftest import KB_DATA


def parsed(kb: KnowledgeBase, mode: str) -> tuple[object, object, str, str]:
    domain, problem = kb.to_pddl(mode)
    return DomainParser()(domain), ProblemParser()(problem), domain, problem


@pytest.mark.parametrize("mode", ["most-likely", "all-outcomes"])
def test_the_pddl_parses_with_an_independent_parser(
    turtlebot: KnowledgeBase, warehouse: KnowledgeBase, mode: str
) -> None:
    for kb in (turtlebot, warehouse):
        d, p, _, _ = parsed(kb, mode)
        assert d.name == kb.domain_name()  # type: ignore[attr-defined]
        assert p.domain_name == kb.domain_name()  # type: ignore[attr-defined]


def parsed_with(kb: KnowledgeBase, mode: str, exogenous: str) -> tuple[str, str]:
    domain, problem = kb.to_pddl(mode, exogenous)
    DomainParser()(domain)
    ProblemParser()(problem)
    return domain, problem


def test_most_likely_pddl_of_the_print_domain(turtlebot: KnowledgeBase) -> None:
    d, p, domain, problem = parsed(turtlebot, "most-likely")
    # by default the world's fluents keep their current values: nobody is seen
    assert "(somebody_at" not in problem
    domain, problem = parsed_with(turtlebot, "most-likely", "most-likely")
    assert sorted(a.name for a in d.actions) == sorted(  # type: ignore[attr-defined]
        o.name for o in turtlebot.operators() if o.name != "exogenous"
    )
    assert "(:goal (and (papers_delivered kenny phdarea)))" in problem
    # the world's most likely next state: somebody at printer-corridor (0.94)
    # and printer-phdarea (0.5, a tie counts as true), nobody at printer-ent (0)
    init = re.search(r"\(:init (.*)\)\n  \(:goal", problem).group(1)  # type: ignore[union-attr]
    assert "(somebody_at printer-corridor)" in init and "(somebody_at printer-phdarea)" in init
    assert "(somebody_at printer-ent)" not in init
    # costs from R(s, a): a move of 10 earns 0.5 less than localise; a dock 150 less
    assert "(increase (total-cost) 50)" in domain and "(increase (total-cost) 15000)" in domain
    assert "(:metric minimize (total-cost))" in problem


def test_all_outcomes_splits_each_draw(warehouse: KnowledgeBase) -> None:
    domain, _ = parsed_with(warehouse, "all-outcomes", "outcomes")
    names = set(re.findall(r"\(:action (\S+)", domain))
    assert {"pick__o1_1", "pick__o1_2", "pick__o2_1", "pick__o2_2"} <= names
    assert {"charge__o1", "charge__o2", "exogenous__dirty__o1", "exogenous__dirty__o2"} <= names
    assert "; not written: move: the condition battery > 0 cannot be written: dropped" in domain


def test_costs_follow_the_non_fluents(turtlebot: KnowledgeBase) -> None:
    turtlebot.apply([Update.set("distance", ("dan-office", "phdarea"), 30.0)], source="setup")
    d, _, domain, problem = parsed(turtlebot, "most-likely")
    # a move of 30 costs 30/20 more than the best action (localise), one of 10 costs 0.5
    names = {a.name for a in d.actions}  # type: ignore[attr-defined]
    assert {"goto_waypoint__c50", "goto_waypoint__c150"} <= names
    assert "(ippc-cost-goto_waypoint-150 kenny dan-office phdarea)" in problem
    assert "(ippc-cost-goto_waypoint-50 kenny dan-office coffee)" in problem


def test_costs_are_each_actions_own_reward_terms(warehouse: KnowledgeBase) -> None:
    # reward = -MOVE-COST * moves + 10 * boxes at their targets: a move costs
    # MOVE-COST (1.0: 100 hundredths), the rest nothing (a reward is no cost)
    domain, _ = parsed_with(warehouse, "most-likely", "current")
    costs = dict(
        re.findall(
            r"\(:action (\S+)[^:]*:parameters[^\n]*\n[^\n]*\n.*?"
            r"\(increase \(total-cost\) (\d+)\)",
            domain,
            flags=re.S,
        )
    )
    assert costs == {"move": "100", "pick": "0", "drop": "0", "charge": "0"}


def test_without_a_goal_there_is_no_pddl() -> None:
    model = next(iter(load(KB_DATA.parents[2] / "domains" / "corridor_enum").values()))
    with pytest.raises(KBError, match="has no goal") as err:
        KnowledgeBase.from_model(model).to_pddl()
    assert err.value.code == "no-goal"
    with pytest.raises(KBError, match="unknown determinisation"):
        KnowledgeBase.from_model(model).to_pddl("best-case")
    with pytest.raises(KBError, match="unknown exogenous"):
        KnowledgeBase.from_model(model).to_pddl("most-likely", "frozen")


def fast_downward() -> Path:
    spec = importlib.util.find_spec("up_fast_downward")
    assert spec is not None and spec.submodule_search_locations, "pip install up-fast-downward"
    return Path(next(iter(spec.submodule_search_locations))) / "downward" / "fast-downward.py"


@pytest.mark.parametrize(
    ("mode", "exogenous"),
    [("most-likely", "most-likely"), ("all-outcomes", "outcomes"), ("most-likely", "current")],
)
def test_fast_downward_solves_the_print_domain(
    turtlebot: KnowledgeBase, tmp_path: Path, mode: str, exogenous: str
) -> None:
    if exogenous == "current":  # somebody is seen at the far printer, as sensing says
        turtlebot.apply([Update.add("somebody_at", "printer-corridor")], source="sensing")
    domain, problem = turtlebot.to_pddl(mode, exogenous)
    (tmp_path / "domain.pddl").write_text(domain)
    (tmp_path / "problem.pddl").write_text(problem)
    plan_file = tmp_path / "plan.txt"
    run = subprocess.run(
        [
            sys.executable,
            str(fast_downward()),
            "--plan-file",
            str(plan_file),
            str(tmp_path / "domain.pddl"),
            str(tmp_path / "problem.pddl"),
            "--search",
            "astar(blind())",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    steps = [
        line.strip("()").split()
        for line in plan_file.read_text().splitlines()
        if not line.startswith(";")
    ]
    actions = [s for s in steps if not s[0].startswith("exogenous__")]
    assert actions[-1] == ["wait_unload", "kenny", "phdarea"]
    # The plan works in the most-likely determinisation of the RDDL model.
    model = determinise(turtlebot.model)
    sim = Simulator(model)
    state = sim.initial_state()
    rng = np.random.default_rng(0)
    for name, *args in actions:
        act = sim.actions_from_names({(name, tuple(args)): True})
        state = sim.step(state, act, rng).next_state  # raises on an illegal action
    kb = KnowledgeBase.from_model(model)
    kb.load_state(state, source="plan")
    assert kb.goal_holds() is True
