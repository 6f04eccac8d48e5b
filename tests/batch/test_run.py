"""End to end: run, kill half-way (SIGKILL and Ctrl-C), resume, and get the same scores
as an uninterrupted run; the same experiment on a Dask LocalCluster; rddlsim's logs."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
from ippc.batch import (
    BatchStore,
    ExperimentError,
    load_experiment,
    read_rddlsim_log,
    run_batch,
    score,
)

from .conftest import REPO, outcome, write_small

pytestmark = pytest.mark.alone  # worker processes and a kill timed on the database

LOG = REPO / "tests" / "data" / "batch" / "rddlsim-logs-2323.log"


def finished_jobs(db: Path) -> int:
    if not db.exists():
        return 0
    try:
        with sqlite3.connect(db, timeout=5) as conn:
            return conn.execute("SELECT count(*) FROM jobs WHERE status = 'finished'").fetchone()[0]
    except sqlite3.OperationalError:  # the schema is not there yet
        return 0


def start_batch(path: Path, db: Path, jobs: int = 2) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ippc.batch.cli",
            "run",
            str(path),
            "--db",
            str(db),
            "--jobs",
            str(jobs),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,  # our own group: a stray worker can be cleaned up
        # Started in the background by a non-interactive shell (`make test &`), pytest
        # and its children inherit SIGINT ignored, and the Ctrl-C test would send a
        # signal nobody hears: the batch gets the default disposition, so Python
        # installs its KeyboardInterrupt handler as in a terminal.
        preexec_fn=_default_sigint,
    )


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def wait_for(db: Path, proc: subprocess.Popen[bytes], n: int, seconds: float = 180.0) -> int:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        done = finished_jobs(db)
        if done >= n:
            return done
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    raise AssertionError(f"fewer than {n} jobs finished in {seconds} s")


def cleanup(proc: subprocess.Popen[bytes]) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait(10)


def test_sigkill_half_way_then_resume_gives_the_same_scores(
    tmp_path: Path, small_reference
) -> None:
    _, _, reference = small_reference
    path = write_small(tmp_path)
    db = tmp_path / "killed.sqlite"
    proc = start_batch(path, db)
    try:
        wait_for(db, proc, 4)
        os.kill(proc.pid, signal.SIGKILL)  # the parent only: its spawned workers see EOF
        proc.wait(30)
    finally:
        cleanup(proc)
    done_before = finished_jobs(db)
    assert 4 <= done_before < 12, done_before
    summary = run_batch(load_experiment(path), db, jobs=2)
    assert summary.skipped == done_before  # finished sessions are not played again
    assert summary.finished == 12 - done_before and summary.failed == 0
    assert outcome(db) == reference
    with BatchStore(db) as store:
        # one session per job, and every job points at its own
        jobs = store.jobs()
        assert len({j.session_id for j in jobs}) == 12 and all(j.status == "finished" for j in jobs)
        assert store.raw("SELECT count(*) FROM sessions")[0][0] == 12


def test_a_second_run_on_the_same_database_is_refused(tmp_path: Path) -> None:
    # Two runs on one database would each play every job left (and the second takes the
    # first's running jobs for left over): the second is refused, naming the first.
    # (30 ms a turn instead of 2 or 4 trials: the compiled engine plays the 12 jobs within
    # the second a new `rddl-batch run` takes to start, and the first run would be over
    # before the second asks; this way it lasts several seconds)
    path = write_small(tmp_path)
    text = path.read_text()
    for trials in ('iterations = "2"', 'iterations = "4"'):
        text = text.replace(trials, 'time_per_step = "0.03"')
    path.write_text(text)
    db = tmp_path / "shared.sqlite"
    proc = start_batch(path, db, jobs=1)
    try:
        wait_for(db, proc, 1)
        before = finished_jobs(db)
        with pytest.raises(ExperimentError, match=rf"another rddl-batch run \(pid {proc.pid}\)"):
            run_batch(load_experiment(path), db, jobs=1)
        cli = subprocess.run(
            [sys.executable, "-m", "ippc.batch.cli", "run", str(path), "--db", str(db)],
            capture_output=True,
            timeout=60,
        )
        assert cli.returncode != 0 and b"another rddl-batch run" in cli.stderr, cli.stderr
        # the first one went on undisturbed, and ends with every job played once
        out, err = proc.communicate(timeout=180)
    finally:
        cleanup(proc)
    assert proc.returncode == 0, err.decode()
    assert finished_jobs(db) == 12 > before
    with BatchStore(db) as store:
        assert store.raw("SELECT count(*) FROM sessions")[0][0] == 12
    # once it has ended, the database is free again: nothing left to play
    assert run_batch(load_experiment(path), db, jobs=1).skipped == 12


@pytest.mark.parametrize("jobs", [2, 1], ids=["pool", "serial"])
def test_ctrl_c_stops_cleanly_and_the_rest_resumes(
    tmp_path: Path, small_reference, jobs: int
) -> None:
    # serial: Ctrl-C lands inside the job's own trio run (a traceback and a job left
    # 'running' before); pool: in the parent, which ends its workers
    _, _, reference = small_reference
    path = write_small(tmp_path)
    db = tmp_path / "interrupted.sqlite"
    proc = start_batch(path, db, jobs)
    try:
        wait_for(db, proc, 3)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        cleanup(proc)
    assert proc.returncode == 130, err.decode()
    assert b"interrupted: run the same command again to resume" in err
    with BatchStore(db) as store:
        statuses = [j.status for j in store.jobs()]
    assert "running" not in statuses  # the ones that were running are marked
    assert statuses.count("finished") >= 3 and statuses.count("finished") < 12
    assert set(statuses) <= {"finished", "interrupted", "pending"}
    run_batch(load_experiment(path), db, jobs=1)
    assert outcome(db) == reference


def test_dask_local_cluster_gives_the_same_scores(tmp_path: Path, small_reference) -> None:
    distributed = pytest.importorskip("distributed")
    _, _, reference = small_reference
    path = write_small(tmp_path)
    db = tmp_path / "dask.sqlite"
    with (
        distributed.LocalCluster(
            n_workers=1,
            threads_per_worker=2,
            processes=False,
            protocol="tcp://",  # a real scheduler socket, on loopback only
            host="127.0.0.1",
            dashboard_address=None,
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        summary = run_batch(load_experiment(path), db, cluster=client)
    assert (summary.finished, summary.failed) == (12, 0)
    assert outcome(db) == reference


def test_rddlsim_log_sits_in_one_table_with_our_results(small_reference) -> None:
    _, db, _ = small_reference
    logged = read_rddlsim_log(LOG)
    # rddlsim's own round-ends, as its Java server wrote them (tests/data/README.md)
    assert [(r.planner, r.instance, r.reward) for r in logged] == [
        ("javaclient", "elevators_inst_mdp__1", 0.0),
        ("javaclient", "elevators_inst_mdp__1", 0.0),
        ("javaclient", "game_of_life_inst_mdp__1", 19.0),
        ("javaclient", "game_of_life_inst_mdp__1", 18.0),
        ("javaclient", "crossing_traffic_inst_mdp__1", -5.0),
        ("javaclient", "crossing_traffic_inst_mdp__1", -5.0),
    ]
    assert logged[0].domain == "elevators_mdp"
    with BatchStore(db) as store:
        ours = store.round_records()
    table = score(ours + logged, "ippc2011")
    # the instances rddlsim alone played have no baseline: not scored
    assert set(table.skipped) == {"elevators_inst_mdp__1", "crossing_traffic_inst_mdp__1"}
    java = [s for s in table.instances if s.planner == "javaclient"]
    assert {s.instance for s in java} == {
        "print_jobs_inst_1",
        "sysadmin_inst_mdp__1",
        "game_of_life_inst_mdp__1",
    }
    gol = next(s for s in java if s.instance == "game_of_life_inst_mdp__1")
    lo, hi = table.bounds["game_of_life_inst_mdp__1"]
    assert gol.mean == 18.5 and gol.rounds == 2
    assert gol.score == pytest.approx(0.0 if hi == lo else (max(18.5, lo) - lo) / (hi - lo))
    assert hi >= 18.5


def test_cli_score_json_and_report(tmp_path: Path, small_reference) -> None:
    import json

    _, db, _ = small_reference
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "ippc.batch.cli",
            "score",
            "--db",
            str(db),
            "--json",
            "--rules",
            "ippc2018",
            "--rddlsim-log",
            str(LOG),
        ],
        capture_output=True,
        check=True,
    )
    data = json.loads(out.stdout)
    assert data["rules"] == "ippc2018"
    assert {p["planner"] for p in data["planners"]} == {
        "noop",
        "random",
        "mcts",
        "mcts_deep",
        "javaclient",
    }
    report = tmp_path / "report"
    subprocess.run(
        [sys.executable, "-m", "ippc.batch.cli", "report", "--db", str(db), "--out", str(report)],
        capture_output=True,
        check=True,
    )
    text = (report / "report.md").read_text()
    assert "| mcts_deep |" in text and "## Per domain" in text
    for stem in ("score_per_instance", "reward_per_round", "time_per_turn"):
        for ext in ("png", "svg", "csv", "json"):
            assert (report / f"{stem}.{ext}").stat().st_size > 0
    assert (report / "score_per_instance.png").read_bytes()[:4] == b"\x89PNG"
    rows = (report / "reward_per_round.csv").read_text().splitlines()
    assert rows[0] == "instance,planner,round,running_mean,ci95" and len(rows) == 1 + 12 * 2


def test_against_an_existing_server_records_what_the_client_saw(tmp_path: Path) -> None:
    server = subprocess.Popen(
        [
            str(Path(sys.executable).parent / "rddl-server"),
            str(REPO / "domains" / "print_jobs"),
            "--port",
            "0",
            "--rounds",
            "2",
            "--workers",
            "1",
            "-q",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        assert server.stdout is not None
        line = server.stdout.readline().decode()  # "listening on 127.0.0.1:PORT"
        port = int(line.rsplit(":", 1)[1])
        path = tmp_path / "srv.toml"
        path.write_text(
            f'name = "srv"\nrounds = 2\ntimeout = 60\ninstances = ["{REPO / "domains" / "print_jobs" / "instance1.rddl"}"]\n'
            '[planners.cmd]\ncommand = "true {port}"\n'
        )
        from ippc.batch import ExperimentError

        with pytest.raises(
            ExperimentError, match="planners given as commands .cmd. need the batch's own server"
        ):
            run_batch(load_experiment(path), tmp_path / "x.sqlite", server=("127.0.0.1", port))
        path.write_text(path.read_text().split("[planners.cmd]")[0])
        db = tmp_path / "srv.sqlite"
        summary = run_batch(load_experiment(path), db, server=("127.0.0.1", port))
        assert (summary.finished, summary.failed) == (2, 0)
        with BatchStore(db) as store:
            noop = [r.reward for r in store.round_records() if r.planner == "noop"]
            assert noop == [-20.0, -20.0]  # noop on print_jobs_inst_1, every round
            assert store.raw("SELECT count(*) FROM steps")[0][0] == 0  # the client saw no steps
            assert {r[0] for r in store.raw("SELECT peer FROM sessions")} == {f"127.0.0.1:{port}"}
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(20)


def test_the_small_example_runs_as_written(tmp_path: Path) -> None:
    db = tmp_path / "small.sqlite"
    summary = run_batch(load_experiment(REPO / "examples" / "small.toml"), db)
    assert (summary.total, summary.finished, summary.failed) == (12, 12, 0)
    with BatchStore(db) as store:
        table = score(store.round_records(), "ippc2014", expected=store.expected())
    assert set(table.planners()) == {"noop", "random", "replan"}
    assert len(table.instances) == 12 and all(0.0 <= s.score <= 1.0 for s in table.instances)
    assert all(s.rounds == 5 for s in table.instances)
