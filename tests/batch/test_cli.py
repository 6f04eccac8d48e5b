"""rddl-batch's answers to bad input: one line naming the file, never a traceback."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from click.testing import CliRunner
from ippc.batch import BatchStore, Job, JobResult, PlannerSpec
from ippc.batch.cli import main

from .conftest import REPO

LOG = REPO / "tests" / "data" / "batch" / "rddlsim-logs-2323.log"
SMALL = REPO / "examples" / "small.toml"


def invoke(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(main, list(args))
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exc_info
    return result.exit_code, result.output


def played(db: Path, planner: str, instance: str, rewards: list[float]) -> None:
    """A finished job of experiment 'e' with these round rewards."""
    job = Job(
        "e", PlannerSpec(planner, planner), instance, "game_of_life_mdp", (), False, 2, 60.0, 1, 2
    )
    now = time.time()
    session = {
        "server_session_id": 1,
        "instance": instance,
        "client_name": planner,
        "seed": 1,
        "num_rounds": len(rewards),
        "time_allowed_ms": 60000.0,
        "peer": "127.0.0.1:1",
        "no_header": False,
        "started_at": now,
        "ended_at": now,
        "status": "finished",
        "total_reward": sum(rewards),
        "rounds_used": len(rewards),
        "reason": None,
        "owner": "test",
    }
    rounds = [
        {
            "round_num": i,
            "counted": True,
            "started_at": now,
            "ended_at": now,
            "status": "finished",
            "reward": r,
            "turns_used": 5,
            "steps": [],
        }
        for i, r in enumerate(rewards, 1)
    ]
    with BatchStore(db) as store:
        store.register([job])
        store.import_result("e", JobResult(job.key, "finished", None, now, now, session, rounds))


@pytest.mark.parametrize(
    "args",
    [
        ("score", "--db", "{db}"),
        ("score", "--db", "{db}", "--json"),
        ("report", "--db", "{db}", "--out", "{tmp}/report"),
        ("run", str(SMALL), "--db", "{db}"),
    ],
)
def test_a_file_that_is_not_sqlite_gets_one_line(tmp_path: Path, args: tuple[str, ...]) -> None:
    db = tmp_path / "notes.sqlite"
    db.write_text("not a database\n")
    code, out = invoke(*(a.format(db=db, tmp=tmp_path) for a in args))
    assert code == 1
    assert out == f"Error: --db {db}: file is not a database\n"


def test_logs_alone_are_scored_alone(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # a results.sqlite in the folder holds a noop baseline for an instance of the log
    monkeypatch.chdir(tmp_path)
    played(tmp_path / "results.sqlite", "noop", "game_of_life_inst_mdp__1", [10.0, 12.0])
    code, out = invoke("score", "--rddlsim-log", str(LOG))
    assert code == 1 and "no instance could be scored" in out  # the log has no baseline
    code, out = invoke("score", "--rddlsim-log", str(LOG), "--db", "results.sqlite")
    assert code == 0 and "javaclient" in out  # asked for: both, in one table
    code, out = invoke("score")  # no log: results.sqlite is the default
    assert code == 0 and "noop" in out


def test_an_unknown_experiment_names_those_there(tmp_path: Path) -> None:
    db = tmp_path / "r.sqlite"
    played(db, "noop", "game_of_life_inst_mdp__1", [10.0])
    code, out = invoke("score", "--db", str(db), "--experiment", "nope")
    assert code == 1
    assert out == f"Error: --experiment nope: not in {db} (experiments there: e)\n"


def test_a_failed_session_is_recorded_the_batch_goes_on_and_reruns_say_so(
    tmp_path: Path,
) -> None:
    instance = REPO / "domains" / "print_jobs" / "instance1.rddl"
    exp = tmp_path / "fail.toml"
    exp.write_text(
        f'rounds = 1\ntimeout = 30\ninstances = ["{instance}"]\n'
        "[planners.crash]\ncommand = \"sh -c 'exit 3' {port}\"\n"
    )
    db = tmp_path / "fail.sqlite"
    code, out = invoke("run", str(exp), "--db", str(db))
    log = db.with_name("fail.sqlite.logs") / "crash@print_jobs_inst_1.log"
    assert code == 1  # a job failed: the exit status says so, after the others were played
    assert "\nfail: 2/3 sessions done (2 now, 0 before), 1 failed, " in out
    assert (
        "1 job(s) failed:\n"
        f"  crash@print_jobs_inst_1: the command exited with status 3 (output: {log})\n"
    ) in out
    with BatchStore(db) as store:
        rows = {j.planner: j for j in store.jobs()}
    assert {p: j.status for p, j in rows.items()} == {
        "noop": "finished",
        "random": "finished",
        "crash": "failed",
    }
    assert rows["crash"].reason == f"the command exited with status 3 (output: {log})"
    # again: nothing is played, and the line still counts the failure
    code, out = invoke("run", str(exp), "--db", str(db))
    assert code == 0  # nothing failed in this run
    assert out.startswith(
        "0 of 3 jobs to play\nfail: 2/3 sessions done (0 now, 2 before), 0 failed (1 more failed before and were"
        " not played again: --retry-failed), "
    )
    code, out = invoke("run", str(exp), "--db", str(db), "--retry-failed")
    assert code == 1 and "\nfail: 2/3 sessions done (0 now, 2 before), 1 failed, " in out
    with BatchStore(db) as store:
        assert {j.planner: j.attempts for j in store.jobs()} == {"noop": 1, "random": 1, "crash": 2}


def test_a_scheduler_that_does_not_answer_is_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import socket

    from ippc.batch import runner

    pytest.importorskip("distributed")
    monkeypatch.setattr(runner, "SCHEDULER_TIMEOUT", 1.0)
    with socket.socket() as s:  # a free port on loopback, closed again: nobody listens
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    db = tmp_path / "c.sqlite"
    code, out = invoke("run", str(SMALL), "--db", str(db), "--cluster", f"tcp://127.0.0.1:{port}")
    assert code == 1
    assert out.splitlines()[-1].startswith(
        f"Error: --cluster: cannot reach the Dask scheduler at tcp://127.0.0.1:{port}: "
    )
    with BatchStore(db) as store:
        assert {j.status for j in store.jobs()} == {"pending"}  # nothing was marked running


def test_a_planner_that_raises_fails_its_job_with_the_planners_words(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from ippc.batch.jobs import run_job
    from ippc.planners import base
    from ippc.planners.base import Planner

    class Broken(Planner):
        name = "broken"

        def act(self, obs):  # type: ignore[no-untyped-def]
            raise RuntimeError("planner bug")

    find, make = base.find_planner, base.make_planner
    monkeypatch.setattr(base, "find_planner", lambda n: Broken if n == "broken" else find(n))
    monkeypatch.setattr(
        base, "make_planner", lambda n, o: Broken() if n == "broken" else make(n, o)
    )
    files = tuple(str(p) for p in sorted((REPO / "domains" / "print_jobs").glob("*.rddl")))
    job = Job(
        "e", PlannerSpec("broken", "broken"), "print_jobs_inst_1", "d", files, False, 1, 30.0, 1, 2
    )
    result = run_job(job)
    assert result.status == "failed"
    # was "ExceptionGroup: Exceptions from Trio nursery (1 sub-exception)"
    assert result.reason == (
        "the client closed the connection; the client: the planner raised RuntimeError: planner bug"
    )
