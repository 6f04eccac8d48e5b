"""rddl-server as a user runs it: a process, a port, signals, a database."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
import trio

from .harness import NOOP, RDDL, ROUND_REQUEST, RawClient, root_of, session_request

# server processes, signals and kills with deadlines: needs the machine to itself
pytestmark = pytest.mark.alone

SERVER = [sys.executable, "-c", "from ippc.server.cli import main; main()"]


def start(*args: str) -> tuple[subprocess.Popen, int]:
    proc = subprocess.Popen(
        [*SERVER, str(RDDL), "--port", "0", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    deadline = time.monotonic() + 60
    line = ""
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if line.startswith("listening on"):
            return proc, int(line.rsplit(":", 1)[1])
        if proc.poll() is not None:
            break
    proc.kill()
    raise AssertionError(
        f"no 'listening on' line: {line!r} {proc.stderr.read() if proc.stderr else ''}"
    )


async def play_turns(port: int, turns: int) -> int:
    """Start a session and answer `turns` turns; returns how many steps the
    server has answered (a turn after our action means it was recorded)."""
    c = await RawClient.connect(port)
    await c.send(session_request(client="victim"))
    assert root_of(await c.recv()) == "session-init"
    answered = 0
    await c.send(ROUND_REQUEST)
    assert root_of(await c.recv()) == "round-init"
    assert root_of(await c.recv()) == "turn"
    while answered < turns:
        await c.send(NOOP)
        msg = await c.recv()
        answered += 1
        if root_of(msg) == "round-end":
            await c.send(ROUND_REQUEST)
            assert root_of(await c.recv()) == "round-init"
            assert root_of(await c.recv()) == "turn"
    return answered


def test_listening_line_and_bad_dir(tmp_path: Path) -> None:
    proc, port = start("--rounds", "1")
    try:
        assert port > 0
    finally:
        proc.terminate()
        proc.wait(10)
    r = subprocess.run([*SERVER, str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert r.returncode != 0 and "no instance to serve" in r.stderr


def test_a_bad_result_database_is_refused_in_one_line(tmp_path: Path) -> None:
    newer = tmp_path / "newer.db"
    conn = sqlite3.connect(newer)
    conn.execute("PRAGMA user_version = 99")
    conn.commit()
    conn.close()
    junk = tmp_path / "junk.db"
    junk.write_bytes(b"not a database at all, " * 100)
    cases = [(newer, "schema version 99"), (junk, "file is not a database")]
    for db, why in cases:
        for workers in ("1", "2"):
            r = subprocess.run(
                [*SERVER, str(RDDL), "--port", "0", "--workers", workers, "--db", str(db)],
                capture_output=True,
                text=True,
                timeout=60,
            )
            assert r.returncode == 1, r.stderr
            assert f"Error: --db {db}: " in r.stderr and why in r.stderr, r.stderr
            assert "Traceback" not in r.stderr and "listening on" not in r.stdout


def test_busy_poll_bounds() -> None:
    for bad in ("-1", "20000"):
        r = subprocess.run(
            [*SERVER, str(RDDL), "--busy-poll-us", bad], capture_output=True, text=True, timeout=60
        )
        assert (
            r.returncode == 2 and "--busy-poll-us" in r.stderr and "between 0 and 10000" in r.stderr
        )


def test_kill_9_loses_no_answered_step(tmp_path: Path) -> None:
    # one process: killing it kills the session (the workers of a killed
    # main process finish theirs: test_workers)
    db = tmp_path / "results.db"
    proc, port = start("--rounds", "30", "--db", str(db), "--workers", "1")
    try:
        answered = trio.run(play_turns, port, 12)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    con = sqlite3.connect(db)
    steps = con.execute("select count(*) from steps").fetchone()[0]
    assert steps >= answered == 12


def test_sigterm_records_open_sessions_as_interrupted(tmp_path: Path) -> None:
    db = tmp_path / "results.db"
    logs = tmp_path / "logs"
    proc, port = start("--rounds", "30", "--db", str(db), "--log-dir", str(logs))

    async def victim_then_signal() -> None:
        c = await RawClient.connect(port)
        await c.send(session_request(client="victim"))
        assert root_of(await c.recv()) == "session-init"
        await c.send(ROUND_REQUEST)
        assert root_of(await c.recv()) == "round-init"
        assert root_of(await c.recv()) == "turn"
        proc.send_signal(signal.SIGTERM)  # while the session is open
        await c.expect_eof()
        await c.close()

    try:
        trio.run(victim_then_signal)
        proc.wait(20)
    finally:
        if proc.poll() is None:
            proc.kill()
    con = sqlite3.connect(db)
    rows = con.execute("select status from sessions").fetchall()
    assert rows == [("interrupted",)]
    assert (
        (logs / f"logs-{port}.log")
        .read_text()
        .startswith('<?xml version="1.0" encoding="UTF-8"?>\n<client-info>')
    )


def test_individual_session_exits_after_one(tmp_path: Path) -> None:
    proc, port = start("--rounds", "1", "--individual-session")
    try:

        async def one() -> None:
            from .harness import noop_session

            await noop_session(port)

        trio.run(one)
        assert proc.wait(20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()


def test_busy_poll_is_off_with_one_cpu() -> None:
    import shutil

    if shutil.which("taskset") is None:
        import pytest

        pytest.skip("no taskset")
    proc = subprocess.Popen(
        ["taskset", "-c", "0", *SERVER, str(RDDL), "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().startswith("listening on")
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=20)
    assert "one CPU: the busy poll is off" in err
