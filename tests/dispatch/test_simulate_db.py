"""`--simulate` with `--db`: the knowledge base journaled and resumed as in a
robot's run; sessions a killed process left open closed as killed."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

from ippc.dispatch.run import PlannerSpec, simulate
from ippc.server.store import ResultStore

from .conftest import DOMAIN, ONE

PLAN = [
    "move(r1,hall,office)",
    "pickup(r1)",
    "move(r1,office,hall)",
    "move(r1,hall,lab)",
    "drop(r1)",
]


def where(facts: list[list[object]]) -> list[object]:
    return [args for fluent, args, value in facts if fluent == "robot-at"]


def test_a_simulated_run_resumes_from_its_journal(tmp_path: Path) -> None:
    db = tmp_path / "sim.db"
    first = simulate(DOMAIN, ONE, planner=PlannerSpec("exact"), db=db, rounds=1)
    assert first.goal_reached and [e["action"] for e in first.executed] == PLAN
    assert first.journaled and first.journaled > 0
    # a process killed with -9 while it played: its session stays open
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    with ResultStore(db, owner=f"{socket.gethostname()}:{dead.pid}:gone") as gone:
        orphan = gone.start_session(
            server_session_id=9,
            instance="courier_one",
            client_name="x",
            seed=0,
            num_rounds=1,
            time_allowed_ms=1.0,
            peer="127.0.0.1:1",
            no_header=False,
            started_at=1.0,
        )
    # restarted: the robot is where the first run left it, with the parcel
    # delivered; nothing is done again
    again = simulate(DOMAIN, ONE, planner=PlannerSpec("exact"), db=db, rounds=1)
    assert again.goal_reached and again.executed == []
    assert where(again.facts) == [["r1", "lab"]]
    with ResultStore(db) as store:
        assert store.session(orphan)["status"] == "killed"
        assert all(s["status"] != "open" for s in store.sessions())
    # --fresh: from the instance's initial state, the moves again
    fresh = simulate(DOMAIN, ONE, planner=PlannerSpec("exact"), db=db, rounds=1, resume=False)
    assert [e["action"] for e in fresh.executed] == PLAN
