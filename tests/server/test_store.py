"""The result store: round trips, WAL durability across kill -9, interruption."""

from __future__ import annotations

import math
import multiprocessing
import os
import selectors
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ippc.server.store import (
    SCHEMA_VERSION,
    ResultStore,
    StoreError,
    decode_fluents,
    encode_fluents,
)


def new_session(store: ResultStore, **over: object) -> int:
    fields: dict[str, object] = dict(
        server_session_id=3,
        instance="sysadmin_inst_mdp__1",
        client_name="prost",
        seed=2,
        num_rounds=30,
        time_allowed_ms=1080000.0,
        peer="127.0.0.1:40512",
        no_header=True,
        started_at=1700000000.25,
    )
    fields.update(over)
    return store.start_session(**fields)  # type: ignore[arg-type]


@pytest.fixture
def store(tmp_path: Path) -> Iterator[ResultStore]:
    s = ResultStore(tmp_path / "results.db")
    yield s
    s.close()


def test_round_trip_of_everything(store: ResultStore) -> None:
    sid = new_session(store)
    r1 = store.start_round(sid, round_num=0, counted=False, started_at=1700000001.0)
    state = [
        ("running", ("c1",), True),
        ("running", ("c2",), False),
        ("pos", ("r1", "x"), 2),
        ("speed", (), 0.5),
        ("light", ("i1",), "@A"),
    ]
    actions = [("reboot", ("c2",), True), ("move", (), -1.5e-4)]
    store.record_step(
        r1,
        turn_num=1,
        state=state,
        actions=actions,
        reward=9.25,
        turn_sent_at=1700000001.5,
        actions_received_at=1700000001.75,
    )
    store.record_step(
        r1,
        turn_num=2,
        state=state[:1],
        actions=[],
        reward=-0.75,
        turn_sent_at=1700000002.0,
        actions_received_at=1700000002.5,
    )
    store.end_round(r1, reward=8.5, turns_used=2, status="illegal-action", ended_at=1700000003.0)
    r2 = store.start_round(sid, round_num=1, counted=True, started_at=1700000004.0)
    store.end_round(r2, reward=0.0, turns_used=0, status="terminal", ended_at=1700000005.0)
    store.end_session(
        sid, total_reward=0.0, rounds_used=2, status="finished", reason=None, ended_at=1700000006.0
    )
    sid2 = new_session(
        store,
        server_session_id=4,
        client_name="java",
        no_header=False,
        seed=3,
        time_allowed_ms=2000.0,
    )
    store.end_session(
        sid2,
        total_reward=None,
        rounds_used=0,
        status="dropped",
        reason="unknown action 'fly'",
        ended_at=1700000007.0,
    )

    sessions = store.sessions()
    assert [s["id"] for s in sessions] == [sid, sid2]
    s = sessions[0]
    assert {k: v for k, v in s.items() if k not in ("id", "owner")} == {
        "server_session_id": 3,
        "instance": "sysadmin_inst_mdp__1",
        "client_name": "prost",
        "seed": 2,
        "num_rounds": 30,
        "time_allowed_ms": 1080000.0,
        "peer": "127.0.0.1:40512",
        "no_header": True,
        "started_at": 1700000000.25,
        "ended_at": 1700000006.0,
        "status": "finished",
        "total_reward": 0.0,
        "rounds_used": 2,
        "reason": None,
    }
    assert s["owner"] == store.owner
    assert store.session(sid2)["no_header"] is False
    assert store.session(sid2)["total_reward"] is None
    assert store.session(sid2)["reason"] == "unknown action 'fly'"
    assert store.session(sid2)["time_allowed_ms"] == 2000.0

    rounds = store.rounds(sid)
    assert [
        (
            r["id"],
            r["round_num"],
            r["counted"],
            r["status"],
            r["reward"],
            r["turns_used"],
            r["started_at"],
            r["ended_at"],
        )
        for r in rounds
    ] == [
        (r1, 0, False, "illegal-action", 8.5, 2, 1700000001.0, 1700000003.0),
        (r2, 1, True, "terminal", 0.0, 0, 1700000004.0, 1700000005.0),
    ]
    assert store.rounds(sid2) == []

    steps = store.steps(r1)
    assert [st["turn_num"] for st in steps] == [1, 2]
    assert steps[0]["state"] == state
    assert steps[0]["actions"] == actions
    assert steps[0]["reward"] == 9.25
    assert steps[0]["turn_sent_at"] == 1700000001.5
    assert steps[0]["actions_received_at"] == 1700000001.75
    assert steps[1]["state"] == state[:1] and steps[1]["actions"] == []
    assert steps[1]["reward"] == -0.75
    assert steps[0]["outcome"] is None and steps[0]["execution_seconds"] is None
    assert store.steps(r2) == []
    assert store.count_steps() == 2 and store.count_steps(r1) == 2


def test_numpy_values_are_stored_as_plain_values(store: ResultStore) -> None:
    sid = new_session(store, seed=np.int64(7), time_allowed_ms=np.float64(5.0))
    rid = store.start_round(
        sid, round_num=np.int64(1), counted=np.bool_(True), started_at=np.float64(1.5)
    )
    state = [
        ("running", (np.str_("c1"),), np.bool_(True)),
        ("count", (), np.int64(-3)),
        ("level", ("t1",), np.float32(0.5)),
        ("x", (), np.float64(0.1)),
    ]
    store.record_step(
        rid,
        turn_num=np.int64(1),
        state=state,
        actions=[],
        reward=np.float64(2.5),
        turn_sent_at=2.0,
        actions_received_at=3.0,
    )
    step = store.steps(rid)[0]
    assert step["state"] == [
        ("running", ("c1",), True),
        ("count", (), -3),
        ("level", ("t1",), 0.5),
        ("x", (), 0.1),
    ]
    assert [type(v) for _, _, v in step["state"]] == [bool, int, float, float]
    assert type(step["reward"]) is float and step["reward"] == 2.5
    assert store.session(sid)["seed"] == 7
    assert store.rounds(sid)[0]["counted"] is True
    # what is in the column is plain JSON text
    raw = store._conn.execute("SELECT state FROM steps").fetchone()[0]
    assert raw == '[["running",["c1"],true],["count",[],-3],["level",["t1"],0.5],["x",[],0.1]]'


def test_encode_fluents_refuses_other_values() -> None:
    with pytest.raises(TypeError, match="not bool, int, float or str"):
        encode_fluents([("a", (), object())])
    assert decode_fluents(encode_fluents([("a", ("b", "c"), "@x")])) == [("a", ("b", "c"), "@x")]


def test_database_is_wal_normal_with_foreign_keys(tmp_path: Path) -> None:
    path = tmp_path / "r.db"
    store = ResultStore(path, busy_timeout_ms=1234)
    try:
        assert store._conn.execute("PRAGMA synchronous").fetchone()[0] == 1  # NORMAL
        assert store._conn.execute("PRAGMA foreign_keys").fetchone()[0] == 1
        assert store._conn.execute("PRAGMA busy_timeout").fetchone()[0] == 1234
        other = sqlite3.connect(path)
        try:  # journal mode and schema version live in the file itself
            assert other.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
            assert other.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION
            tables = {r[0] for r in other.execute("SELECT name FROM sqlite_master")}
            assert {"sessions", "rounds", "steps"} <= tables
        finally:
            other.close()
    finally:
        store.close()


def test_memory_store_works() -> None:
    with ResultStore(":memory:") as store:
        sid = new_session(store)
        assert store.session(sid)["client_name"] == "prost"


def test_foreign_keys_and_unique_turns(store: ResultStore) -> None:
    with pytest.raises(sqlite3.IntegrityError):
        store.start_round(999, round_num=1, counted=True, started_at=0.0)
    sid = new_session(store)
    rid = store.start_round(sid, round_num=1, counted=True, started_at=0.0)
    with pytest.raises(sqlite3.IntegrityError):
        store.record_step(
            rid + 1,
            turn_num=1,
            state=[],
            actions=[],
            reward=0.0,
            turn_sent_at=0.0,
            actions_received_at=0.0,
        )
    store.record_step(
        rid, turn_num=1, state=[], actions=[], reward=1.0, turn_sent_at=0.0, actions_received_at=0.0
    )
    with pytest.raises(sqlite3.IntegrityError):
        store.record_step(
            rid,
            turn_num=1,
            state=[],
            actions=[],
            reward=2.0,
            turn_sent_at=0.0,
            actions_received_at=0.0,
        )
    # a failed write leaves no transaction open: the next write is committed and visible
    store.record_step(
        rid, turn_num=2, state=[], actions=[], reward=3.0, turn_sent_at=0.0, actions_received_at=0.0
    )
    assert not store._conn.in_transaction
    with ResultStore(store.path) as other:
        assert [s["reward"] for s in other.steps(rid)] == [1.0, 3.0]


def test_bad_status_and_unknown_rows(store: ResultStore) -> None:
    sid = new_session(store)
    rid = store.start_round(sid, round_num=1, counted=True, started_at=0.0)
    with pytest.raises(ValueError, match="round status"):
        store.end_round(rid, reward=0.0, turns_used=0, status="done", ended_at=1.0)
    with pytest.raises(ValueError, match="session status"):
        store.end_session(
            sid, total_reward=0.0, rounds_used=0, status="terminal", reason=None, ended_at=1.0
        )
    with pytest.raises(KeyError):
        store.end_round(rid + 10, reward=0.0, turns_used=0, status="finished", ended_at=1.0)
    with pytest.raises(KeyError):
        store.end_session(
            sid + 10, total_reward=0.0, rounds_used=0, status="finished", reason=None, ended_at=1.0
        )
    with pytest.raises(KeyError):
        store.session(sid + 10)
    assert store.rounds(sid)[0]["status"] == "open"


def test_first_close_wins(store: ResultStore) -> None:
    sid = new_session(store)
    rid = store.start_round(sid, round_num=1, counted=True, started_at=0.0)
    store.end_round(rid, reward=4.0, turns_used=3, status="finished", ended_at=1.0)
    store.end_round(rid, reward=0.0, turns_used=0, status="interrupted", ended_at=2.0)
    assert store.rounds(sid)[0]["status"] == "finished"
    assert store.rounds(sid)[0]["reward"] == 4.0
    assert store.interrupt_open("SIGTERM", 3.0) == 1
    store.end_session(
        sid, total_reward=4.0, rounds_used=1, status="finished", reason=None, ended_at=4.0
    )
    s = store.session(sid)
    assert (s["status"], s["reason"], s["ended_at"], s["total_reward"]) == (
        "interrupted",
        "SIGTERM",
        3.0,
        None,
    )


def test_end_session_closes_rounds_left_open(store: ResultStore) -> None:
    sid = new_session(store)
    rid = store.start_round(sid, round_num=1, counted=True, started_at=0.0)
    for t in (1, 2, 3):
        store.record_step(
            rid,
            turn_num=t,
            state=[],
            actions=[],
            reward=1.0,
            turn_sent_at=0.0,
            actions_received_at=0.0,
        )
    store.end_session(
        sid,
        total_reward=None,
        rounds_used=1,
        status="dropped",
        reason="client vanished",
        ended_at=9.0,
    )
    r = store.rounds(sid)[0]
    assert (r["status"], r["turns_used"], r["reward"], r["ended_at"]) == ("dropped", 3, None, 9.0)


def test_interrupt_open_marks_open_sessions_and_rounds(tmp_path: Path) -> None:
    path = tmp_path / "r.db"
    with ResultStore(path) as store, ResultStore(path) as other_server:
        done = new_session(store)
        rd = store.start_round(done, round_num=1, counted=True, started_at=0.0)
        store.end_round(rd, reward=1.0, turns_used=1, status="finished", ended_at=1.0)
        store.end_session(
            done, total_reward=1.0, rounds_used=1, status="finished", reason=None, ended_at=2.0
        )
        open1 = new_session(store)
        ra = store.start_round(open1, round_num=1, counted=True, started_at=0.0)
        store.end_round(ra, reward=2.0, turns_used=5, status="finished", ended_at=1.0)
        rb = store.start_round(open1, round_num=2, counted=True, started_at=1.0)
        store.record_step(
            rb,
            turn_num=1,
            state=[],
            actions=[],
            reward=1.0,
            turn_sent_at=0.0,
            actions_received_at=0.0,
        )
        open2 = new_session(store)
        theirs = new_session(other_server)
        rt = other_server.start_round(theirs, round_num=1, counted=True, started_at=0.0)

        assert store.interrupt_open("server shut down (SIGINT)", 50.0) == 2
        by_id = {s["id"]: s for s in store.sessions()}
        assert by_id[done]["status"] == "finished" and by_id[done]["reason"] is None
        for sid in (open1, open2):
            assert by_id[sid]["status"] == "interrupted"
            assert by_id[sid]["reason"] == "server shut down (SIGINT)"
            assert by_id[sid]["ended_at"] == 50.0
        assert [(r["status"], r["turns_used"]) for r in store.rounds(open1)] == [
            ("finished", 5),
            ("interrupted", 1),
        ]
        assert store.rounds(open1)[1]["ended_at"] == 50.0
        # the other server's live session is not ours to close
        assert by_id[theirs]["status"] == "open"
        assert store.rounds(theirs)[0]["status"] == "open"
        assert store.interrupt_open("again", 60.0) == 0
        # a step that arrives after the interruption is still kept
        store.record_step(
            rb,
            turn_num=2,
            state=[],
            actions=[],
            reward=1.0,
            turn_sent_at=0.0,
            actions_received_at=0.0,
        )
        assert store.count_steps(rb) == 2
        # recovery after a crash closes everything still open in the file
        assert store.interrupt_open("recovered", 70.0, every_owner=True) == 1
        assert other_server.session(theirs)["status"] == "interrupted"
        assert other_server.rounds(theirs)[0]["status"] == "interrupted"
        assert rt


def test_reopen_keeps_data_and_refuses_newer_schema(tmp_path: Path) -> None:
    path = tmp_path / "r.db"
    with ResultStore(path) as store:
        sid = new_session(store)
    with ResultStore(path) as store:
        assert [s["id"] for s in store.sessions()] == [sid]
    conn = sqlite3.connect(path)
    conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    conn.commit()
    conn.close()
    with pytest.raises(RuntimeError, match="schema version"):
        ResultStore(path)


def test_dispatch_steps_keep_their_outcome_and_execution_time(store: ResultStore) -> None:
    sid = new_session(store)
    rid = store.start_round(sid, round_num=1, counted=True, started_at=1.0)
    outcome = {"actions": [{"action": "goto(r1,a,b)", "outcome": "failed"}], "goal": False}
    store.record_step(
        rid,
        turn_num=1,
        state=[],
        actions=[("goto", ("r1", "a", "b"), True)],
        reward=-1.0,
        turn_sent_at=2.0,
        actions_received_at=2.5,
        outcome=outcome,
        execution_seconds=np.float64(3.25),
    )
    (step,) = store.steps(rid)
    assert step["outcome"] == outcome
    assert step["execution_seconds"] == 3.25


def test_a_version_1_database_is_upgraded_in_place(tmp_path: Path) -> None:
    path = tmp_path / "v1.db"
    with ResultStore(path) as store:
        sid = new_session(store)
        rid = store.start_round(sid, round_num=1, counted=True, started_at=1.0)
        store.record_step(
            rid,
            turn_num=1,
            state=[("x", (), True)],
            actions=[],
            reward=1.5,
            turn_sent_at=2.0,
            actions_received_at=2.5,
        )
    # what version 1 of the schema was: steps without the two columns
    conn = sqlite3.connect(path)
    conn.execute("ALTER TABLE steps DROP COLUMN outcome")
    conn.execute("ALTER TABLE steps DROP COLUMN execution_seconds")
    conn.execute("PRAGMA user_version = 1")
    conn.commit()
    conn.close()
    with ResultStore(path) as store:
        (step,) = store.steps(rid)
        assert step["state"] == [("x", (), True)] and step["reward"] == 1.5
        assert step["outcome"] is None and step["execution_seconds"] is None
        store.record_step(
            rid,
            turn_num=2,
            state=[],
            actions=[],
            reward=0.0,
            turn_sent_at=3.0,
            actions_received_at=3.5,
            outcome={"goal": True},
            execution_seconds=0.5,
        )
        assert store.steps(rid)[1]["outcome"] == {"goal": True}
    conn = sqlite3.connect(path)
    assert conn.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION == 5
    conn.close()


def test_commit_is_visible_to_another_connection_at_once(tmp_path: Path) -> None:
    path = tmp_path / "r.db"
    with ResultStore(path) as writer, ResultStore(path) as reader:
        sid = new_session(writer)
        rid = writer.start_round(sid, round_num=1, counted=True, started_at=0.0)
        for t in range(1, 6):
            writer.record_step(
                rid,
                turn_num=t,
                state=[("s", (), t)],
                actions=[],
                reward=t,
                turn_sent_at=0.0,
                actions_received_at=0.0,
            )
            assert reader.count_steps(rid) == t


CHILD = textwrap.dedent("""
    import sys, time
    from ippc.server.store import ResultStore
    store = ResultStore(sys.argv[1])
    sid = store.start_session(server_session_id=1, instance="inst", client_name=sys.argv[2],
                              seed=0, num_rounds=1000, time_allowed_ms=1080000.0,
                              peer="127.0.0.1:1", no_header=False, started_at=time.time())
    for r in range(1, int(sys.argv[3]) + 1):
        rid = store.start_round(sid, round_num=r, counted=True, started_at=time.time())
        for t in range(1, 41):
            store.record_step(rid, turn_num=t, state=[("running", ("c%d" % t,), t % 2 == 0)],
                              actions=[("reboot", ("c1",), True)], reward=float(t),
                              turn_sent_at=time.time(), actions_received_at=time.time())
            print(rid, t, flush=True)
        store.end_round(rid, reward=820.0, turns_used=40, status="finished",
                        ended_at=time.time())
    store.end_session(sid, total_reward=0.0, rounds_used=r, status="finished", reason=None,
                      ended_at=time.time())
    print("done", flush=True)
""")


def read_lines(proc: subprocess.Popen[bytes], n: int, deadline: float) -> list[bytes]:
    """Up to n lines of the child's stdout, read without blocking past the deadline."""
    assert proc.stdout is not None
    fd = proc.stdout.fileno()
    os.set_blocking(fd, False)
    buf = b""
    lines: list[bytes] = []
    with selectors.DefaultSelector() as sel:
        sel.register(fd, selectors.EVENT_READ)
        while len(lines) < n:
            left = deadline - time.monotonic()
            if left <= 0 or not sel.select(timeout=left):
                break
            chunk = os.read(fd, 65536)
            if not chunk:
                break
            buf += chunk
            *complete, buf = buf.split(b"\n")
            lines.extend(complete)
    return lines[:n]


def test_kill_9_loses_no_committed_step(tmp_path: Path) -> None:
    path = tmp_path / "killed.db"
    n = 150  # crosses round boundaries (40 steps a round)
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(path), "victim", "1000"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        lines = read_lines(proc, n, time.monotonic() + 60)
    finally:
        proc.send_signal(signal.SIGKILL)
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == -signal.SIGKILL, err.decode(errors="replace")
    assert len(lines) == n, err.decode(errors="replace")
    acknowledged = [tuple(int(x) for x in line.split()) for line in lines]

    conn = sqlite3.connect(path)
    assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    conn.close()
    with ResultStore(path) as store:
        (session,) = store.sessions()
        assert session["status"] == "open" and session["client_name"] == "victim"
        stored = {
            (r["id"], st["turn_num"]): st
            for r in store.rounds(session["id"])
            for st in store.steps(r["id"])
        }
        assert len(stored) >= n
        for rid, t in acknowledged:
            st = stored[(rid, t)]
            assert st["reward"] == float(t)
            assert st["state"] == [("running", (f"c{t}",), t % 2 == 0)]
            assert st["actions"] == [("reboot", ("c1",), True)]
        # the rounds the child finished before the kill are closed; the last one
        # is open, unless the kill landed between one round's end and the next
        # one's start (the child runs ahead of this reader on a busy machine)
        rounds = store.rounds(session["id"])
        assert [r["status"] for r in rounds[:-1]] == ["finished"] * (len(rounds) - 1)
        last_open = rounds[-1]["status"] == "open"
        assert last_open or rounds[-1]["status"] == "finished"
        # the next server can mark what the dead one left open
        assert store.interrupt_open("crash recovery", time.time(), every_owner=True) == 1
        assert store.sessions()[0]["status"] == "interrupted"
        expected = "interrupted" if last_open else "finished"
        assert store.rounds(session["id"])[-1]["status"] == expected


def test_two_processes_write_one_file(tmp_path: Path) -> None:
    path = tmp_path / "shared.db"
    ResultStore(path).close()  # schema first, so both children only write rows
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", CHILD, str(path), f"p{k}", "5"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        for k in (1, 2)
    ]
    for p in procs:
        out, err = p.communicate(timeout=60)
        assert p.returncode == 0, err.decode(errors="replace")
        assert out.splitlines()[-1] == b"done"
    with ResultStore(path) as store:
        sessions = store.sessions()
        assert sorted(s["client_name"] for s in sessions) == ["p1", "p2"]
        for s in sessions:
            assert s["status"] == "finished"
            rounds = store.rounds(s["id"])
            assert len(rounds) == 5
            assert all(store.count_steps(r["id"]) == 40 for r in rounds)


def test_missing_folder_is_created(tmp_path: Path) -> None:
    path = tmp_path / "new" / "deeper" / "r.db"
    with ResultStore(path) as store:
        sid = new_session(store)
    with ResultStore(path) as store:
        assert store.session(sid)["instance"] == "sysadmin_inst_mdp__1"


def _open_each(paths: list[str], barrier: Any, failures: Any) -> None:
    for path in paths:
        barrier.wait(timeout=30)
        try:
            ResultStore(path).close()
        except sqlite3.OperationalError as err:
            failures.put(f"{path}: {err}")


@pytest.mark.alone
def test_processes_opening_a_new_file_at_once_all_succeed(tmp_path: Path) -> None:
    # rddl-server's workers and parallel batch runs may create one database at the
    # same moment; switching a new file to WAL then fails at once with "database is
    # locked" (SQLite skips its busy handler there), which the store retries.
    # Without the retry this test failed in each of three runs (120 files, 4 processes).
    ctx = multiprocessing.get_context("fork")
    paths = [str(tmp_path / f"r{k}.db") for k in range(120)]
    barrier = ctx.Barrier(4)
    failures = ctx.Queue()
    procs = [ctx.Process(target=_open_each, args=(paths, barrier, failures)) for _ in range(4)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(timeout=120)
    assert all(p.exitcode == 0 for p in procs), [p.exitcode for p in procs]
    found = []
    while not failures.empty():
        found.append(failures.get(timeout=5))
    assert found == []
    for path in paths[:3]:
        with ResultStore(path) as store:
            assert store.sessions() == []
            assert store._conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_setup_is_retried_on_a_lock_and_only_on_a_lock(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    real = ResultStore._setup
    calls = []

    def setup_failing(message: str, times: float) -> Callable[[ResultStore], None]:
        """A `_setup` that raises `message` on its first `times` calls, then does the real one."""

        def setup(self: ResultStore) -> None:
            calls.append(1)
            if len(calls) <= times:
                raise sqlite3.OperationalError(message)
            real(self)

        return setup

    monkeypatch.setattr(ResultStore, "_setup", setup_failing("database is locked", 2))
    with ResultStore(tmp_path / "a.db") as store:
        assert store.sessions() == []
    assert len(calls) == 3

    calls.clear()
    monkeypatch.setattr(ResultStore, "_setup", setup_failing("disk I/O error", math.inf))
    with pytest.raises(StoreError, match="disk I/O"):
        ResultStore(tmp_path / "b.db")
    assert len(calls) == 1

    calls.clear()
    monkeypatch.setattr(ResultStore, "_setup", setup_failing("database is locked", math.inf))
    t0 = time.monotonic()
    with pytest.raises(StoreError, match="locked"):
        ResultStore(tmp_path / "c.db", busy_timeout_ms=300)
    assert 0.25 < time.monotonic() - t0 < 10
    assert 2 < len(calls) < 100


def test_a_file_that_is_not_sqlite_is_a_store_error_and_is_left_alone(tmp_path: Path) -> None:
    path = tmp_path / "notes.sqlite"
    path.write_bytes(b"my notes, not a database\n" * 10)
    with pytest.raises(StoreError, match="^file is not a database$"):
        ResultStore(path)
    assert path.read_bytes() == b"my notes, not a database\n" * 10


def test_the_knowledge_base_journal_keeps_the_latest_facts(tmp_path: Path) -> None:
    path = tmp_path / "r.db"
    with ResultStore(path) as store:
        store.record_kb_batch("courier_one", "sensing", [("robot-at", ("r1", "hall"), False)], 1.0)
        store.record_kb_batch(
            "courier_one",
            "dispatcher",
            [("holding", ("r1",), True), ("robot-at", ("r1", "lab"), True)],
            2.0,
        )
        store.record_kb_batch("other", "sensing", [("battery", (), 0.5)], 3.0)
        store.record_kb_batch("courier_one", "sensing", [("holding", ("r1",), False)], 4.0)
    with ResultStore(path) as store:  # a restarted process reads what the last one wrote
        assert store.kb_facts("courier_one") == [
            ("robot-at", ("r1", "hall"), False),
            ("robot-at", ("r1", "lab"), True),
            ("holding", ("r1",), False),
        ]
        assert store.kb_facts("other") == [("battery", (), 0.5)]
        batches = store.kb_batches("courier_one")
        assert [b["source"] for b in batches] == ["sensing", "dispatcher", "sensing"]
        assert batches[1]["changes"] == [
            ("holding", ("r1",), True),
            ("robot-at", ("r1", "lab"), True),
        ]
        assert store.kb_batches("courier_one", after=batches[1]["id"]) == batches[2:]
    with ResultStore(path) as store:
        assert store.kb_goal("courier_one") == (False, None)
        store.record_kb_batch(
            "courier_one", "api", [], 5.0, goal=[["delivered", [], True]], goal_changed=True
        )
        store.record_kb_batch("courier_one", "api", [], 6.0, goal=None, goal_changed=True)
        assert store.kb_goal("courier_one") == (True, None)
        store.record_kb_batch("courier_one", "sensing", [("holding", ("r1",), True)], 7.0)
        assert store.kb_goal("courier_one") == (True, None)
        assert store.kb_batches("courier_one")[-3]["goal"] == [["delivered", [], True]]
