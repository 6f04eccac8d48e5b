"""examples/ippc-budgets.toml, the test of issue 37 that the budgets hold in a batch
(docs/runs/2026-12-04-budgets-batch.md): it reads, every instance resolves, it holds
every built-in planner that plays inside the client, RecSim 2023 #7 and the
highest-numbered instance of every IPPC 2018 problem rddlrepository lists, and its session
budget is honest for one round."""

from __future__ import annotations

from ippc.batch import load_experiment, resolve_instances
from ippc.planners.base import BUILTIN_PLANNERS, find_planner
from ippc.planners.exact import DEFAULT_STARTUP as EXACT_STARTUP

from .conftest import REPO

FILE = REPO / "examples" / "ippc-budgets.toml"


def test_every_in_client_planner_on_recsim_7_and_the_largest_2018_instances() -> None:
    from rddlrepository.core.manager import RDDLRepoManager

    exp = load_experiment(FILE)
    assert (exp.name, exp.rounds, exp.jobs) == ("ippc-budgets", 1, 1)
    in_client = {n for n in BUILTIN_PLANNERS if not find_planner(n).external}
    assert {p.planner for p in exp.planners} == in_client
    assert {p.label for p in exp.planners} == in_client
    for p in exp.planners:
        if "time_per_step" in p.options:
            assert p.options["time_per_step"] == "0.1", p.label

    manager = RDDLRepoManager()
    largest = {
        f"{name}:{max(int(i) for i in manager.get_problem(name).list_instances())}"
        for name in manager.list_problems()
        if name.endswith("_ippc2018")
    }
    assert len(largest) == 7
    assert set(exp.instances) == largest | {"RecSim_ippc2023:7"}

    instances = resolve_instances(exp)
    assert len(instances) == 8
    for inst in instances:
        # a round's 0.1 s turns plus the longest start-up allowance (exact's) fit
        assert inst.model.horizon is not None, inst.name
        assert inst.model.horizon * 0.1 + EXACT_STARTUP <= exp.timeout - 30, inst.name
