"""rddl-server --workers N: one listener, sessions played in worker processes."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import pytest
import trio
from ippc.server.config import ServerConfig
from ippc.server.records import read_transcript
from ippc.server.workers import WorkerPool, serve_with_workers, supported

from .harness import (
    NOOP,
    RDDL,
    ROUND_REQUEST,
    RawClient,
    noop_session,
    noop_sessions_at_once,
    root_of,
    running_server,
    session_request,
)
from .test_cli import SERVER, start

# worker processes, kills and restarts with timeouts: needs the machine to itself
pytestmark = [
    pytest.mark.skipif(supported() is not None, reason=str(supported())),
    pytest.mark.alone,
]


async def _until(cond: Callable[[], bool], what: str, timeout: float = 20.0) -> None:
    with trio.fail_after(timeout):
        while not cond():
            await trio.sleep(0.02)
    assert cond(), what


async def _held(port: int, client: str) -> RawClient:
    """A session stopped at its first turn (the client has not answered)."""
    c = await RawClient.connect(port)
    await c.send(session_request(client=client))
    assert root_of(await c.recv()) == "session-init"
    await c.send(ROUND_REQUEST)
    assert root_of(await c.recv()) == "round-init"
    assert root_of(await c.recv()) == "turn"
    return c


async def _finish(c: RawClient, rounds_left: int = 0) -> int:
    """Answer noops to the end of the session (`rounds_left` rounds after
    this one); the turns answered."""
    turns = 0
    await c.send(NOOP)
    while True:
        msg = await c.recv()
        assert msg is not None
        kind = root_of(msg)
        if kind == "turn":
            turns += 1
            await c.send(NOOP)
        elif kind == "round-end" and rounds_left:
            rounds_left -= 1
            await c.send(ROUND_REQUEST)
        elif kind == "round-end":
            continue
        elif kind == "session-end":
            await c.expect_eof()
            await c.close()
            return turns


async def _with_workers(
    config: ServerConfig, n: int, body: Callable[[int, WorkerPool], Any]
) -> None:
    pools: list[WorkerPool] = []
    async with trio.open_nursery() as nursery:
        port = await nursery.start(partial(serve_with_workers, config, [str(RDDL)], n, pools=pools))
        await body(port, pools[0])
        nursery.cancel_scope.cancel()


def test_sessions_are_numbered_seeded_and_recorded_as_in_one_process(tmp_path: Path) -> None:
    """Six concurrent sessions on two workers: the session numbers 1-6, and
    for each number the very rewards and states a server of one process
    plays; every step in the database, every document in rddlsim's log,
    one transcript per session."""
    db, logs, tr = tmp_path / "r.db", tmp_path / "logs", tmp_path / "tr"
    config = ServerConfig(port=0, rounds=2, db=db, log_dir=logs, transcripts=tr)
    spread: list[list[int]] = []

    async def six(port: int) -> dict[int, dict[str, Any]]:
        return {r["session_id"]: r for r in await noop_sessions_at_once(port, 6)}

    async def main() -> tuple[dict[int, Any], dict[int, Any]]:
        got: dict[int, Any] = {}

        async def body(port: int, pool: WorkerPool) -> None:
            got.update(await six(port))
            await _until(lambda: pool.open_sessions == 0, "every end reported")
            spread.extend(sorted(w.open) for w in pool.workers)

        await _with_workers(config, 2, body)
        async with running_server(ServerConfig(port=0, rounds=2)) as (port, _):
            alone = await six(port)
        return got, alone

    got, alone = trio.run(main)
    assert sorted(got) == list(range(1, 7))
    for sid in got:
        assert got[sid]["rounds"] == alone[sid]["rounds"], sid
        assert got[sid]["states"] == alone[sid]["states"], sid
    assert spread == [[], []]
    con = sqlite3.connect(db)
    rows = con.execute(
        "select server_session_id, seed, status, owner from sessions order by server_session_id"
    ).fetchall()
    assert [(r[0], r[1], r[2]) for r in rows] == [(k, k - 1, "finished") for k in range(1, 7)]
    assert (
        con.execute("select count(*) from steps").fetchone()[0]
        == sum(len(r["states"]) for r in got.values())
        == 6 * 2 * 5
    )
    text = (logs / f"logs-{_port_of(rows, logs)}.log").read_text()
    assert text.count("<client-info>") == 6
    assert text.count("<round-end>") == 12
    assert text.count("<session-end>") == 6
    lines = text.splitlines()
    assert all(
        line.startswith("<?xml") or line.startswith("<") and line.endswith(">") for line in lines
    )
    files = sorted(tr.iterdir())
    assert len(files) == 6
    for f in files:
        meta, records = read_transcript(f)
        assert meta["session_id"] in got
        assert (
            sum(r.get("dir") == "s2c" and "eof" not in r.values() for r in records)
            == 1 + 2 * (1 + 5 + 1) + 1
        ), records[-2:]


def _port_of(rows: list[tuple[Any, ...]], logs: Path) -> str:
    (log,) = logs.iterdir()
    return log.name.removeprefix("logs-").removesuffix(".log")


def test_least_busy_worker_and_the_shared_count() -> None:
    """Two held sessions go to two workers; the count the workers read (for
    the busy poll) follows the sessions open in the whole server."""
    config = ServerConfig(port=0, rounds=1)

    async def body(port: int, pool: WorkerPool) -> None:
        a = await _held(port, "a")
        await _until(lambda: pool.open_sessions == 1, "one open")
        b = await _held(port, "b")
        assert pool.open_sessions == 2
        assert [sorted(w.open) for w in pool.workers] == [[1], [2]]
        assert await _finish(a) == 4
        await _until(lambda: pool.open_sessions == 1, "a's end counted")
        assert await _finish(b) == 4
        await _until(lambda: pool.open_sessions == 0, "b's end counted")

    trio.run(_with_workers, config, 2, body)


def test_a_dead_worker_costs_only_its_sessions(tmp_path: Path) -> None:
    """kill -9 of the worker playing session 1: that session is recorded
    interrupted and its client sees the connection close; session 2 in the
    other worker plays to its end; a new worker takes later sessions."""
    db = tmp_path / "r.db"
    config = ServerConfig(port=0, rounds=1, db=db)

    async def body(port: int, pool: WorkerPool) -> None:
        a = await _held(port, "a")
        b = await _held(port, "b")
        (victim,) = [w for w in pool.workers if 1 in w.open]
        old_pid = victim.proc.pid  # type: ignore[union-attr]
        os.kill(old_pid, signal.SIGKILL)
        await a.expect_eof()
        await a.close()
        assert await _finish(b) == 4
        await _until(
            lambda: victim.alive and victim.ready.is_set() and victim.proc.pid != old_pid,
            "restarted",
        )  # type: ignore[union-attr]
        assert pool.open_sessions == 0
        again = [await noop_session(port, client=f"later{i}") for i in range(2)]
        assert [r["session_id"] for r in again] == [3, 4]

    trio.run(_with_workers, config, 2, body)
    con = sqlite3.connect(db)
    rows = dict(
        con.execute(
            "select server_session_id, status || ': ' || coalesce(reason, '') from sessions"
        ).fetchall()
    )
    assert rows[1].startswith("interrupted: worker process died (signal SIGKILL)")
    assert rows[2] == rows[3] == rows[4] == "finished: "


def _children(pid: int) -> list[int]:
    out = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        out += [int(x) for x in (task / "children").read_text().split()]
    return out


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs /proc")
def test_cli_sigterm_interrupts_sessions_and_stops_the_workers(tmp_path: Path) -> None:
    db = tmp_path / "r.db"
    proc, port = start("--rounds", "30", "--db", str(db), "--workers", "2", "-q")
    try:
        workers = _children(proc.pid)
        assert len(workers) == 2

        async def victims() -> None:
            a = await _held(port, "a")
            b = await _held(port, "b")
            proc.send_signal(signal.SIGTERM)
            await a.expect_eof()
            await b.expect_eof()

        trio.run(victims)
        assert proc.wait(30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
    deadline = time.monotonic() + 10
    while (
        any(Path(f"/proc/{w}").exists() and "Z" not in _state(w) for w in workers)
        and time.monotonic() < deadline
    ):
        time.sleep(0.05)
    assert not [w for w in workers if Path(f"/proc/{w}").exists() and "Z" not in _state(w)]
    con = sqlite3.connect(db)
    assert con.execute("select status, count(distinct owner) from sessions").fetchall() == [
        ("interrupted", 2)
    ]


def _state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "Z"


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs /proc")
@pytest.mark.parametrize(
    ("prefix", "extra", "expected"),
    [
        ([], [], None),  # the default, auto: one worker per core
        (["taskset", "-c", "0"], [], 0),  # one core: one process
        ([], ["--individual-session"], 0),
    ],
    ids=["default", "one-core", "individual-session"],
)
def test_workers_auto_is_the_default(
    prefix: list[str], extra: list[str], expected: int | None
) -> None:
    import shutil

    if prefix and shutil.which(prefix[0]) is None:
        pytest.skip(f"no {prefix[0]}")
    cores = len(os.sched_getaffinity(0))
    if expected is None:
        if cores < 2:
            pytest.skip("one core here: auto is one process")
        expected = cores
    proc = subprocess.Popen(
        [*prefix, *SERVER, str(RDDL), "--port", "0", "--rounds", "1", *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().startswith("listening on")
        children = _children(proc.pid)
        assert len(children) == expected
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=30)
    if expected == 0 and not extra:
        assert "one CPU: the busy poll is off" in err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--workers", "0"], "must be at least 1"),
        (["--workers", "many"], "is not a number or 'auto'"),
        (["--workers", "2", "--individual-session"], "--individual-session plays one session"),
    ],
)
def test_workers_option_errors(args: list[str], message: str) -> None:
    r = subprocess.run([*SERVER, str(RDDL), *args], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and message in r.stderr and "--workers" in r.stderr


@pytest.mark.parametrize("workers", ["1", "2"])
def test_port_in_use_is_a_clear_error(workers: str) -> None:
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        r = subprocess.run(
            [*SERVER, str(RDDL), "--port", str(port), "--workers", workers],
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert r.returncode == 1
    assert f"cannot listen on 127.0.0.1:{port}" in r.stderr and "Address already in use" in r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs /proc")
def test_workers_of_a_killed_main_process_finish_their_sessions_and_exit() -> None:
    proc, port = start("--rounds", "1", "--workers", "2", "-q")
    workers = _children(proc.pid)
    try:

        async def orphaned() -> None:
            c = await _held(port, "orphan")
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait(10)
            assert await _finish(c) == 4  # the session goes on to its end

        trio.run(orphaned)
    finally:
        if proc.poll() is None:
            proc.kill()
    deadline = time.monotonic() + 10
    while any(_state(w) != "Z" for w in workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert [_state(w) for w in workers] == ["Z", "Z"]


def test_200_concurrent_clients_on_workers_get_their_results_alone() -> None:
    """The load test of one process (test_load) on three workers: every
    session ends, numbered 1-200, each as it plays alone."""
    clients = 200
    config = ServerConfig(port=0, rounds=2, seed=7)
    results: list[dict[str, Any]] = []

    async def body(port: int, pool: WorkerPool) -> None:
        results.extend(await noop_sessions_at_once(port, clients))
        await _until(lambda: pool.open_sessions == 0, "every end reported")

    async def alone(k: int) -> dict[str, Any]:
        async with running_server(ServerConfig(port=0, rounds=2, seed=7 + k - 1)) as (port, _):
            return await noop_session(port, client="alone")

    trio.run(_with_workers, config, 3, body)
    assert sorted(r["session_id"] for r in results) == list(range(1, clients + 1))
    for r in sorted(results, key=lambda r: r["session_id"])[:: clients // 8]:
        a = trio.run(alone, r["session_id"])
        assert (a["rounds"], a["states"]) == (r["rounds"], r["states"])


def test_a_hung_worker_never_stops_the_accept_loop() -> None:
    """A stopped worker reads no hand-overs; once its control socket is full
    (a few hundred), connections go to the other worker instead of the
    accept loop waiting on it."""
    config = ServerConfig(port=0, rounds=1)

    async def body(port: int, pool: WorkerPool) -> None:
        w0, w1 = pool.workers
        pid = w0.proc.pid  # type: ignore[union-attr]
        os.kill(pid, signal.SIGSTOP)
        try:
            socks = []
            with trio.fail_after(60):
                for i in range(600):
                    s = trio.socket.socket()
                    await s.connect(("127.0.0.1", port))
                    socks.append(s)
                    if i % 50 == 0:
                        await trio.sleep(0.02)
                await _until(lambda: pool.next_id == 600, "all 600 accepted", 30)
            assert len(w0.open) < 600 - 250 and len(w1.open) > 300  # w0's socket filled up
            for s in socks:
                s.close()
            late = await noop_session(port, client="late")
            assert late["session_id"] == 601
        finally:
            os.kill(pid, signal.SIGCONT)

    trio.run(_with_workers, config, 2, body)


def test_when_every_worker_dies_repeatedly_the_server_stops(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import ippc.server.workers as W

    monkeypatch.setattr(W, "MAX_RAPID_DEATHS", 2)
    config = ServerConfig(port=0, rounds=1)

    async def body(port: int, pool: WorkerPool) -> None:
        with trio.fail_after(60):
            while True:
                for w in pool.workers:
                    if (
                        w.alive
                        and w.ready.is_set()
                        and w.proc is not None
                        and w.proc.poll() is None
                    ):
                        os.kill(w.proc.pid, signal.SIGKILL)
                await trio.sleep(0.05)

    with pytest.raises(BaseException) as info:
        trio.run(_with_workers, config, 2, body)
    leaf: BaseException = info.value
    while isinstance(leaf, BaseExceptionGroup) and len(leaf.exceptions) == 1:
        leaf = leaf.exceptions[0]
    assert isinstance(leaf, W.WorkerError) and "every worker process died repeatedly" in str(leaf)


def test_a_restarted_worker_that_is_never_ready_is_killed_and_restarted(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The first restart of a killed worker is stopped (SIGSTOP) before it
    can say it is ready: it is given no sessions, killed after
    RESTART_READY_TIMEOUT (1.5 s here), and started once more; that one
    serves."""
    import ippc.server.workers as W

    spawn = W.WorkerPool._spawn
    stopped: list[int] = []

    def spawn_and_stop_the_first_restart(self: WorkerPool, w: Any) -> None:
        spawn(self, w)
        # (the watchdog of a restart reads the timeout after this returns)
        if w.deaths and not stopped:
            stopped.append(w.proc.pid)
            os.kill(w.proc.pid, signal.SIGSTOP)
            monkeypatch.setattr(W, "RESTART_READY_TIMEOUT", 1.5)
        else:  # a loaded machine may take seconds to start a worker
            monkeypatch.setattr(W, "RESTART_READY_TIMEOUT", 120.0)

    monkeypatch.setattr(W.WorkerPool, "_spawn", spawn_and_stop_the_first_restart)
    send = W.WorkerPool._send
    given: list[tuple[int, int]] = []  # (pid, session) of every hand-over

    async def send_and_note(self: WorkerPool, w: Any, sid: int, fd: int) -> bool:
        ok = await send(self, w, sid, fd)
        if ok:
            given.append((w.proc.pid, sid))
        return ok

    monkeypatch.setattr(W.WorkerPool, "_send", send_and_note)
    config = ServerConfig(port=0, rounds=1)

    async def body(port: int, pool: WorkerPool) -> None:
        w0, w1 = pool.workers
        first = w0.proc.pid  # type: ignore[union-attr]
        os.kill(first, signal.SIGKILL)
        await _until(lambda: bool(stopped), "restarted (and stopped)")
        assert not w0.ready.is_set()
        # the stopped worker is given no session
        done = [await noop_session(port, client=f"meanwhile{i}") for i in range(2)]
        assert [r["session_id"] for r in done] == [1, 2]
        await _until(
            lambda: w0.proc.pid not in (first, stopped[0]) and w0.ready.is_set(),
            "restarted again",
            30,
        )  # type: ignore[union-attr]
        assert len(w0.deaths) == 2 and not w0.given_up
        await _until(lambda: pool.open_sessions == 0, "sessions 1 and 2 reported ended")
        a = await _held(port, "a")
        b = await _held(port, "b")
        assert len(w0.open) == len(w1.open) == 1
        assert await _finish(a) == 4 and await _finish(b) == 4

    trio.run(_with_workers, config, 2, body)
    assert [sid for _, sid in given] == [1, 2, 3, 4]
    assert all(pid != stopped[0] for pid, _ in given)
