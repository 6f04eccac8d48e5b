"""rddl-batch under a pipe, with planners it cannot stop from inside: a plug-in whose
start-up never returns and one that allocates without bound (tests/client/runaway.py,
registered by entry point). Each is ended at its session budget plus the grace, or at
the memory budget; the batch records why, plays the rest, says so line by line while it
runs, and exits 1 with a summary."""

from __future__ import annotations

import os
import re
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from ippc.batch import BatchStore

from ..client import runaway
from .conftest import REPO

pytestmark = pytest.mark.alone  # job processes, a memory hog, a run read as it goes

INSTANCE = REPO / "domains" / "print_jobs" / "instance1.rddl"
KEYS = {f"{p}@print_jobs_inst_1" for p in ("noop", "random", "stuck", "hog")}


def test_runaway_planners_are_stopped_recorded_and_the_batch_goes_on(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    env = runaway.register(monkeypatch, tmp_path / "plugins")
    exp = tmp_path / "runaway.toml"
    exp.write_text(
        f'name = "runaway"\nrounds = 2\ntimeout = 3\ninstances = ["{INSTANCE}"]\n'
        '[planners.stuck]\nplanner = "stuck"\n[planners.hog]\nplanner = "hog"\n'
    )
    db = tmp_path / "runaway.sqlite"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ippc.batch.cli",
            "run",
            str(exp),
            "--db",
            str(db),
            "--jobs",
            "2",
            "--grace",
            "1",
            "--memory-budget",
            "300",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,  # as `> batch.log 2>&1`
        env=env,
        start_new_session=True,
    )
    assert proc.stdout is not None
    lines: list[str] = []
    running_at_first_job: bool | None = None
    buf = b""
    deadline = time.monotonic() + 240
    try:
        while True:
            assert time.monotonic() < deadline, lines
            ready, _, _ = select.select([proc.stdout], [], [], 1.0)
            if not ready:
                continue
            chunk = os.read(proc.stdout.fileno(), 65536)
            if not chunk:
                break
            buf += chunk
            *done, buf = buf.split(b"\n")
            for raw in done:
                line = raw.decode()
                if running_at_first_job is None and line.startswith("[1/4] "):
                    running_at_first_job = proc.poll() is None
                lines.append(line)
        code = proc.wait(30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
    text = "\n".join(lines)
    # lines came while the run went on, one per job, as they ended
    assert running_at_first_job is True, text
    assert lines[0] == "4 of 4 jobs to play"
    job_lines = [ln for ln in lines if re.match(r"\[\d/4\] ", ln)]
    assert [ln[:6] for ln in job_lines] == ["[1/4] ", "[2/4] ", "[3/4] ", "[4/4] "], text
    assert {ln.split()[2] for ln in job_lines} == {"noop", "random", "stuck", "hog"}
    noop = next(ln for ln in job_lines if ln.split()[2] == "noop")
    assert re.fullmatch(
        r"\[\d/4\] finished  noop  print_jobs_inst_1  mean reward -20\.0000  \d+\.\d s  "
        r"\d jobs? left",
        noop,
    ), noop
    # the exit status and the summary name the failure
    assert code == 1, text
    log = tmp_path / "runaway.sqlite.logs" / "hog@print_jobs_inst_1.session.log"
    assert re.search(
        r"\n1 job\(s\) failed:\n  hog@print_jobs_inst_1: out of memory: the planner's process "
        r"held \d+ MB, over its budget of 300 MB; killed; none of its rounds recorded "
        rf"\(log: {re.escape(str(log))}\)\n",
        text + "\n",
    ), text
    assert "runaway: 3/4 sessions done (3 now, 0 before), 1 failed, " in text
    with BatchStore(db) as store:
        jobs = {j.planner: j for j in store.jobs()}
    assert {f"{p}@print_jobs_inst_1" for p in jobs} == KEYS
    assert {p: j.status for p, j in jobs.items()} == {
        "noop": "finished",
        "random": "finished",
        "stuck": "timeout",
        "hog": "failed",
    }
    assert re.fullmatch(
        r"the session was still running \d+ s after it began \(its budget 3 s, plus 1 s "
        r"grace\); the planner's process was stopped and none of its rounds recorded",
        jobs["stuck"].reason,
    ), jobs["stuck"].reason
    assert jobs["hog"].reason.startswith("out of memory: ")


def test_a_planner_that_sizes_its_memory_gets_its_share_of_the_jobs_budget(
    tmp_path: Path,
) -> None:
    from ippc.batch import load_experiment, run_batch

    exp = tmp_path / "sized.toml"
    exp.write_text(
        f'name = "sized"\nrounds = 1\ntimeout = 60\ninstances = ["{INSTANCE}"]\n'
        '[planners.mcts]\nplanner = "mcts"\noptions = { iterations = "2" }\n'
    )
    db = tmp_path / "sized.sqlite"
    logs = tmp_path / "logs"
    summary = run_batch(load_experiment(exp), db, jobs=1, memory_mb=400, log_dir=logs)
    assert (summary.finished, summary.failed) == (3, 0)
    log = (logs / "mcts@print_jobs_inst_1.session.log").read_text()
    # 75% of the job's 400 MB, through the planner's option `memory`
    assert "memory budget 300 MiB (option memory)" in log, log
