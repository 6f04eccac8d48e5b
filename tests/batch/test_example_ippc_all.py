"""examples/ippc-all.toml, the IPPC 2011/2014/2018 measurement of mcts against PROST
(docs/planners.md): it reads, every instance resolves and checks, and it holds what the
comparison needs."""

from __future__ import annotations

import re
import tomllib

from ippc.batch import load_experiment, resolve_instances

from .conftest import REPO

FILE = REPO / "examples" / "ippc-all.toml"


def test_the_file_reads_and_every_instance_resolves() -> None:
    exp = load_experiment(FILE)
    assert (exp.name, exp.rounds, exp.jobs) == ("ippc-all", 10, 1)
    # PROST is optional: without PROST_BIN it is left out with a warning
    assert {"noop", "random", "mcts"} <= {p.label for p in exp.planners}
    assert exp.planner("mcts").options == {"time_per_step": "0.1"}
    prost = tomllib.loads(FILE.read_text())["planners"]["prost"]
    assert prost == {
        "planner": "prost",
        "optional": True,
        "options": {"config": "[Prost -s 1 -se [IPC2014 -t 0.1]]"},
    }

    instances = resolve_instances(exp)
    # every spec is instances 1-5 of one rddlrepository problem, and none collapses into
    # another (rddl-batch keeps an instance name once)
    assert len(instances) == 5 * len(exp.instances) == 80
    assert all(re.fullmatch(r"\w+_(MDP_)?ippc20(11|14|18):1-5", s) for s in exp.instances)
    years = {s.split("ippc")[1][:4] for s in exp.instances}
    assert years == {"2011", "2014", "2018"}
    assert len({i.domain for i in instances}) == 16

    # a session of 10 rounds at 0.1 s a step fits the budget with room for the
    # planners' start (PROST's parser and learning, mcts's compilation)
    for inst in instances:
        assert inst.model.horizon is not None, inst.name
        assert inst.model.horizon * exp.rounds * 0.1 <= exp.timeout / 2, inst.name


def test_the_one_second_subset_reads_and_resolves() -> None:
    path = REPO / "examples" / "ippc-1s.toml"
    exp = load_experiment(path)
    assert (exp.name, exp.rounds, exp.jobs) == ("ippc-1s", 10, 1)
    assert exp.planner("mcts").options == {"time_per_step": "1"}
    prost = tomllib.loads(path.read_text())["planners"]["prost"]
    assert prost["options"] == {"config": "[Prost -s 1 -se [IPC2014 -t 1]]"}
    # the same seed as the 0.1 s run: the same server draws on the shared instances
    assert exp.seed == load_experiment(FILE).seed
    instances = resolve_instances(exp)
    assert len(instances) == 3
    for inst in instances:
        assert inst.model.horizon is not None, inst.name
        assert inst.model.horizon * exp.rounds * 1.0 <= exp.timeout / 2, inst.name
