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


# ------------------------------------------------------------ the baseline's runs


def test_baseline_in_experiment_1_goes_to_the_nearest_printer_and_replans() -> None:
    """The paper's story: the deterministic robot assumes somebody at every printer, drives
    to p2 (the shortest route), waits in vain, plans again without p2 and fetches at p1."""
    from ippc.experiments.print_fetch.office import EXPERIMENTS, distance
    from ippc.experiments.print_fetch.run import APPROACHES, run_one

    row = run_one(EXPERIMENTS[1], APPROACHES["fast-downward"], 0)
    assert row.success and row.error == ""
    assert row.first_printer == "p2"
    assert (row.failed_actions, row.replans, row.steps) == (1, 1, 6)
    metres = distance("prof_office", "p2") + distance("p2", "p1") + distance("p1", "phd_area")
    assert row.distance_m == pytest.approx(metres, abs=1e-3)
    # driving, the vain wait (60 s), the wait at p1 (20 s), the hand-over (5 s), and one
    # sensing cycle (0.1 s at sensing's 10 Hz) per turn for the knowledge base to settle
    assert row.execution_s == pytest.approx(2 * metres + 60 + 20 + 5 + 0.1 * row.steps, abs=1e-3)


def test_baseline_in_experiment_3_waits_once_at_the_busy_printer() -> None:
    from ippc.experiments.print_fetch.office import EXPERIMENTS, distance
    from ippc.experiments.print_fetch.run import APPROACHES, run_one

    row = run_one(EXPERIMENTS[3], APPROACHES["fast-downward"], 0)
    assert row.success and row.first_printer == "p1"
    assert (row.failed_actions, row.replans) == (1, 1)
    metres = distance("dock", "p1") + distance("p1", "prof_office")
    assert row.distance_m == pytest.approx(metres, abs=1e-3)
    assert row.execution_s == pytest.approx(2 * metres + 75 + 20 + 5 + 0.1 * row.steps, abs=1e-3)


def test_baseline_forgets_what_it_saw_elsewhere_when_nothing_is_left() -> None:
    """Experiment 4, seed 4008: every printer the robot tried was unhelpful when it waited,
    so on what it saw the task has no plan; it forgets the other printers (redrawn every
    step) and goes on trying until the papers come."""
    from ippc.experiments.print_fetch.office import EXPERIMENTS
    from ippc.experiments.print_fetch.run import APPROACHES, run_one

    row = run_one(EXPERIMENTS[4], APPROACHES["fast-downward"], 8)
    assert row.success and row.first_printer == "p2"
    assert (row.failed_actions, row.replans) == (5, 5)
