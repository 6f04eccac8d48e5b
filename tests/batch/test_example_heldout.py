"""examples/ippc-heldout.toml and ippc-heldout-1s.toml, the held-out set of the mcts
measurement (instances 6-10 of the 16 domains whose instances 1-5, examples/ippc-all.toml,
are the tuning set): they read, every instance resolves, and no instance is shared with
the tuning set."""

from __future__ import annotations

import re
import tomllib

from ippc.batch import load_experiment, resolve_instances

from .conftest import REPO

HELDOUT = REPO / "examples" / "ippc-heldout.toml"
TUNING = REPO / "examples" / "ippc-all.toml"


def _domains(specs: list[str]) -> set[str]:
    return {s.split(":")[0] for s in specs}


def test_heldout_is_instances_6_to_10_of_the_tuning_domains() -> None:
    exp = load_experiment(HELDOUT)
    tuning = load_experiment(TUNING)
    assert (exp.name, exp.rounds, exp.jobs) == ("ippc-heldout", 10, 1)
    assert _domains(exp.instances) == _domains(tuning.instances)
    assert all(re.fullmatch(r"\w+_(MDP_)?ippc20(11|14|18):6-10", s) for s in exp.instances)
    assert exp.planner("mcts").options == {"time_per_step": "0.1"}
    prost = tomllib.loads(HELDOUT.read_text())["planners"]["prost"]
    assert prost["options"] == {"config": "[Prost -s 1 -se [IPC2014 -t 0.1]]"}

    instances = resolve_instances(exp)
    assert len(instances) == 80
    assert len({i.domain for i in instances}) == 16
    # disjoint from the tuning set, instance by instance
    assert not {i.name for i in instances} & {i.name for i in resolve_instances(tuning)}
    for inst in instances:
        assert inst.model.horizon is not None, inst.name
        assert inst.model.horizon * exp.rounds * 0.1 <= exp.timeout / 2, inst.name


def test_heldout_one_second_subset_is_held_out_too() -> None:
    path = REPO / "examples" / "ippc-heldout-1s.toml"
    exp = load_experiment(path)
    assert exp.planner("mcts").options == {"time_per_step": "1"}
    assert exp.seed == load_experiment(HELDOUT).seed
    instances = resolve_instances(exp)
    assert len(instances) == 5
    assert all(int(s.split(":")[1]) >= 6 for s in exp.instances)
    for inst in instances:
        assert inst.model.horizon is not None, inst.name
        assert inst.model.horizon * exp.rounds * 1.0 <= exp.timeout / 2, inst.name
