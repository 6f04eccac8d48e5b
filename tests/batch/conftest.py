"""A small experiment for the batch tests: two planners (and the baselines) on three
small instances, two rounds each; every planner is seeded and deterministic (MCTS with
a fixed number of iterations), so that a replayed session gives the same rewards."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from ippc.batch import BatchStore, load_experiment, run_batch, score

from ..conftest import RDDLSIM_RDDL, REPO

SMALL = f"""
name = "small-e2e"
rounds = 2
timeout = 120
seed = 7
instances = [
    "{REPO / "domains" / "print_jobs" / "instance1.rddl"}",
    "{RDDLSIM_RDDL / "sysadmin_inst_mdp__1.rddl"}",
    "{RDDLSIM_RDDL / "game_of_life_inst_mdp__1.rddl"}",
]

[planners.mcts]
planner = "mcts"
options = {{ iterations = "2", batch = "64" }}

[planners.mcts_deep]
planner = "mcts"
options = {{ iterations = "4", rollout_depth = "4", batch = "64" }}
"""


def write_small(folder: Path) -> Path:
    path = folder / "small.toml"
    path.write_text(SMALL)
    return path


def outcome(db: Path) -> tuple[str, list[tuple[str, str, float]]]:
    """The scores (as JSON text) and every round's (planner, instance, reward)."""
    with BatchStore(db) as store:
        records = store.round_records()
        expected = store.expected()
    table = score(records, "ippc2014", expected=expected)
    rewards = sorted((r.planner, r.instance, r.reward) for r in records)
    return json.dumps(table.as_json(), sort_keys=True), rewards


@pytest.fixture(scope="session")
def small_reference(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, tuple]:
    """The small experiment played once, serially in this process: (file, db, outcome)."""
    folder = tmp_path_factory.mktemp("batch-reference")
    path = write_small(folder)
    db = folder / "reference.sqlite"
    summary = run_batch(load_experiment(path), db, jobs=1)
    assert (summary.finished, summary.failed) == (12, 0)
    return path, db, outcome(db)
