"""Sessions a killed process left open, and goal outcomes, in the result store."""

from __future__ import annotations

import os
import socket
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
from ippc.server.store import ResultStore


def dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def open_session(store: ResultStore) -> int:
    return store.start_session(
        server_session_id=1,
        instance="i",
        client_name="c",
        seed=0,
        num_rounds=1,
        time_allowed_ms=1.0,
        peer="127.0.0.1:1",
        no_header=False,
        started_at=1.0,
    )


def test_sessions_of_a_dead_process_are_closed_as_killed(tmp_path: Path) -> None:
    db = tmp_path / "r.db"
    host = socket.gethostname()
    with ResultStore(db, owner=f"{host}:{dead_pid()}:x") as gone:
        sid = open_session(gone)
        gone.start_round(sid, round_num=1, counted=True, started_at=1.0)
    with ResultStore(db, owner=f"{host}:{os.getpid()}:alive") as alive:
        live = open_session(alive)
    with ResultStore(db, owner="elsewhere:1:y") as other:
        far = open_session(other)
    with ResultStore(db) as store:
        assert store.close_killed(5.0) == 1
        assert store.session(sid)["status"] == "killed"
        assert "killed" in store.session(sid)["reason"]
        assert [r["status"] for r in store.rounds(sid)] == ["interrupted"]
        assert store.session(live)["status"] == "open"
        assert store.session(far)["status"] == "open"
        assert store.close_killed(6.0) == 0


def test_a_store_of_schema_4_learns_killed_and_goal_outcomes(tmp_path: Path) -> None:
    db = tmp_path / "old.db"
    conn = sqlite3.connect(db)
    conn.executescript(
        """
        CREATE TABLE sessions (id INTEGER PRIMARY KEY, server_session_id INTEGER NOT NULL,
          instance TEXT NOT NULL, client_name TEXT NOT NULL, seed INTEGER NOT NULL,
          num_rounds INTEGER NOT NULL, time_allowed_ms REAL NOT NULL, peer TEXT NOT NULL,
          no_header INTEGER NOT NULL, started_at REAL NOT NULL, ended_at REAL,
          status TEXT NOT NULL DEFAULT 'open' CHECK (status IN
                      ('open', 'finished', 'timeout', 'dropped', 'interrupted')),
          total_reward REAL, rounds_used INTEGER, reason TEXT, owner TEXT NOT NULL);
        CREATE TABLE rounds (id INTEGER PRIMARY KEY,
          session_id INTEGER NOT NULL REFERENCES sessions(id), round_num INTEGER NOT NULL,
          counted INTEGER NOT NULL, started_at REAL NOT NULL, ended_at REAL,
          status TEXT NOT NULL DEFAULT 'open', reward REAL, turns_used INTEGER);
        CREATE TABLE steps (id INTEGER PRIMARY KEY, round_id INTEGER NOT NULL,
          turn_num INTEGER NOT NULL, state TEXT NOT NULL, actions TEXT NOT NULL,
          reward REAL NOT NULL, turn_sent_at REAL NOT NULL, actions_received_at REAL NOT NULL,
          outcome TEXT, execution_seconds REAL);
        CREATE TABLE jobs (id INTEGER PRIMARY KEY);
        CREATE TABLE kb_batches (id INTEGER PRIMARY KEY);
        CREATE TABLE kb_facts (instance TEXT);
        PRAGMA user_version = 4;
        """
    )
    conn.execute(
        "INSERT INTO sessions (server_session_id, instance, client_name, seed, num_rounds,"
        " time_allowed_ms, peer, no_header, started_at, owner)"
        " VALUES (1, 'i', 'c', 0, 1, 1.0, 'p', 0, 1.0, ?)",
        (f"{socket.gethostname()}:{dead_pid()}:old",),
    )
    conn.commit()
    conn.close()
    with ResultStore(db) as store:
        assert store.close_killed(2.0) == 1
        assert store.sessions()[0]["status"] == "killed"
        store.record_goal_outcome("i", {"goal": "g", "version": 1, "outcome": "reached", "turn": 4})
        assert store.goal_outcomes("i") == [
            {"goal": "g", "version": 1, "outcome": "reached", "turn": 4}
        ]
    with ResultStore(db) as again:  # the edited schema reads back
        assert again.sessions()[0]["status"] == "killed"
        with pytest.raises(sqlite3.IntegrityError):
            again.record_goal_outcome("i", {"outcome": "maybe"})
