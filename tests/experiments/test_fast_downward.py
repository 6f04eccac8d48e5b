"""The deterministic baseline's Fast Downward runner and planner options (the PyPI
package up-fast-downward is in the test extra)."""

from __future__ import annotations

from pathlib import Path

import pytest
from ippc.experiments.fast_downward import (
    FastDownwardPlanner,
    driver_path,
    parse_plan,
    run_fast_downward,
)
from ippc.planners import PlannerError, make_planner

DATA = Path(__file__).resolve().parents[1] / "data" / "experiments"
DOMAIN = (DATA / "corridor_domain.pddl").read_text()


def test_driver_is_the_packaged_one() -> None:
    path = driver_path()
    assert path.name == "fast-downward.py" and path.is_file()
    assert "up_fast_downward" in path.parts


def test_parse_plan() -> None:
    text = "(go hall kitchen)\n(go kitchen office)\n; cost = 22 (general cost)\n"
    assert parse_plan(text) == [("go", ("hall", "kitchen")), ("go", ("kitchen", "office"))]
    with pytest.raises(PlannerError, match="cannot read line"):
        parse_plan("go hall kitchen\n")


def test_optimal_plan_with_action_costs() -> None:
    plan = run_fast_downward(DOMAIN, (DATA / "corridor_problem.pddl").read_text())
    # 12 + 10 through the kitchen beats the direct 25
    assert plan == [("go", ("hall", "kitchen")), ("go", ("kitchen", "office"))]


def test_unsolvable_task_has_no_plan() -> None:
    assert run_fast_downward(DOMAIN, (DATA / "corridor_unsolvable.pddl").read_text()) is None


def test_broken_pddl_is_an_error_with_fast_downwards_words() -> None:
    with pytest.raises(PlannerError, match=r"Fast Downward failed \(exit"):
        run_fast_downward("(define (domain broken", (DATA / "corridor_problem.pddl").read_text())


def test_planner_is_registered_and_checks_its_options(tmp_path: Path) -> None:
    planner = make_planner("fast-downward", {"search": "astar(lmcut())"})
    assert isinstance(planner, FastDownwardPlanner) and planner.search == "astar(lmcut())"
    with pytest.raises(PlannerError, match="mode must be most-likely or all-outcomes"):
        FastDownwardPlanner(mode="best")
    with pytest.raises(PlannerError, match="has no option 'depth'"):
        FastDownwardPlanner(depth="3")
    with pytest.raises(PlannerError, match="time_limit"):
        FastDownwardPlanner(time_limit="soon")
