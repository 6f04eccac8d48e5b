"""The batch's side of the result database: jobs, and the sessions they played.

The file is the server's (`ippc.server.store.ResultStore`, schema version 3): sessions,
rounds and steps as ``rddl-server`` writes them, plus the ``jobs`` table. The batch's
parent process is its only writer: a worker's `JobResult` is imported in one transaction
(session, rounds, steps, and the job's new status), so a kill at any moment leaves every
finished session whole and no half session behind.
"""

from __future__ import annotations

import sqlite3
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..server.store import ResultStore
from .jobs import Job, JobResult

__all__ = ["BatchStore", "JobRow", "RoundRecord"]

_SESSION_COLUMNS = (
    "server_session_id",
    "instance",
    "client_name",
    "seed",
    "num_rounds",
    "time_allowed_ms",
    "peer",
    "no_header",
    "started_at",
    "ended_at",
    "status",
    "total_reward",
    "rounds_used",
    "reason",
    "owner",
)
_ROUND_COLUMNS = (
    "round_num",
    "counted",
    "started_at",
    "ended_at",
    "status",
    "reward",
    "turns_used",
)
_STEP_COLUMNS = ("turn_num", "state", "actions", "reward", "turn_sent_at", "actions_received_at")

#: Job statuses that count as done (not played again on resume).
DONE = ("finished", "timeout")


@dataclass(frozen=True)
class JobRow:
    """One row of the jobs table."""

    id: int
    experiment: str
    job_key: str
    planner: str
    instance: str
    domain: str
    server_seed: int
    planner_seed: int
    status: str
    reason: str | None
    session_id: int | None
    attempts: int


@dataclass(frozen=True)
class RoundRecord:
    """One round as scoring sees it (from our database or an rddlsim log)."""

    planner: str
    instance: str
    domain: str
    reward: float
    counted: bool = True  # False: a practice round (execute-policy no)
    time_ms: float | None = None  # the round's wall time, when known
    time_allowed_ms: float | None = None  # the session's budget, when known
    num_rounds: int | None = None  # rounds the session was to play, when known
    session: int = 0  # rounds of one session share this (order within it is the list order)


class BatchStore(ResultStore):
    """Jobs and results in one SQLite file (migrated to schema 3 when opened): the
    server's `ResultStore` (its connection, its transactions, its readers) with the
    jobs table's writers and the batch's readers."""

    def __init__(self, path: str | Path, *, busy_timeout_ms: int = 30000) -> None:
        super().__init__(path, busy_timeout_ms=busy_timeout_ms, owner="rddl-batch")
        self._conn.row_factory = sqlite3.Row  # rows by column name (the readers below)

    def __enter__(self) -> BatchStore:
        return self

    # ----------------------------------------------------------------- jobs

    def register(self, jobs: Iterable[Job]) -> list[str]:
        """Add the jobs not yet in the file (status pending); the keys of jobs already
        there whose seeds differ (the experiment changed: their results would not be
        the same experiment's)."""
        conflicts = []
        with self._tx() as cur:
            for job in jobs:
                row = cur.execute(
                    "SELECT server_seed, planner_seed FROM jobs WHERE experiment = ? AND job_key = ?",
                    (job.experiment, job.key),
                ).fetchone()
                if row is None:
                    cur.execute(
                        "INSERT INTO jobs (experiment, job_key, planner, instance, domain, server_seed,"
                        " planner_seed) VALUES (?, ?, ?, ?, ?, ?, ?)",
                        (
                            job.experiment,
                            job.key,
                            job.planner.label,
                            job.instance,
                            job.domain,
                            job.server_seed,
                            job.planner_seed,
                        ),
                    )
                elif (row["server_seed"], row["planner_seed"]) != (
                    job.server_seed,
                    job.planner_seed,
                ):
                    conflicts.append(job.key)
        return conflicts

    def reset_running(self, experiment: str) -> int:
        """Jobs left 'running' by a batch that was killed: back to 'interrupted'."""
        with self._tx() as cur:
            cur.execute(
                "UPDATE jobs SET status = 'interrupted', reason = 'the batch stopped while it ran',"
                " ended_at = ? WHERE experiment = ? AND status = 'running'",
                (time.time(), experiment),
            )
            return cur.rowcount

    def jobs(self, experiment: str | None = None) -> list[JobRow]:
        """The jobs (of one experiment, or all), in the order they were registered."""
        sql = (
            "SELECT * FROM jobs" + (" WHERE experiment = ?" if experiment else "") + " ORDER BY id"
        )
        rows = self.raw(sql, (experiment,) if experiment else ())
        return [
            JobRow(
                r["id"],
                r["experiment"],
                r["job_key"],
                r["planner"],
                r["instance"],
                r["domain"],
                r["server_seed"],
                r["planner_seed"],
                r["status"],
                r["reason"],
                r["session_id"],
                r["attempts"],
            )
            for r in rows
        ]

    def experiments(self) -> list[str]:
        return [r[0] for r in self.raw("SELECT DISTINCT experiment FROM jobs ORDER BY id")]

    def mark(
        self, experiment: str, keys: Iterable[str], status: str, reason: str | None = None
    ) -> None:
        """Set the status of jobs (running when handed out; interrupted on Ctrl-C)."""
        now = time.time()
        with self._tx() as cur:
            for key in keys:
                if status == "running":
                    cur.execute(
                        "UPDATE jobs SET status = 'running', reason = NULL, started_at = ?,"
                        " attempts = attempts + 1 WHERE experiment = ? AND job_key = ?",
                        (now, experiment, key),
                    )
                else:
                    cur.execute(
                        "UPDATE jobs SET status = ?, reason = ?, ended_at = ? WHERE experiment = ?"
                        " AND job_key = ? AND status NOT IN ('finished', 'timeout')",
                        (status, reason, now, experiment, key),
                    )

    def import_result(self, experiment: str, result: JobResult) -> None:
        """Store a worker's result and the job's final status, in one transaction."""
        with self._tx() as cur:
            session_id = None
            if result.session is not None:
                values = [result.session.get(c) for c in _SESSION_COLUMNS]
                values[_SESSION_COLUMNS.index("no_header")] = int(
                    bool(result.session.get("no_header"))
                )
                cur.execute(
                    f"INSERT INTO sessions ({', '.join(_SESSION_COLUMNS)}) VALUES"
                    f" ({', '.join('?' * len(_SESSION_COLUMNS))})",
                    values,
                )
                session_id = cur.lastrowid
                for rnd in result.rounds:
                    cur.execute(
                        f"INSERT INTO rounds (session_id, {', '.join(_ROUND_COLUMNS)}) VALUES"
                        f" (?, {', '.join('?' * len(_ROUND_COLUMNS))})",
                        [session_id]
                        + [int(rnd[c]) if c == "counted" else rnd.get(c) for c in _ROUND_COLUMNS],
                    )
                    round_id = cur.lastrowid
                    cur.executemany(
                        f"INSERT INTO steps (round_id, {', '.join(_STEP_COLUMNS)}) VALUES"
                        f" (?, {', '.join('?' * len(_STEP_COLUMNS))})",
                        [[round_id] + [s[c] for c in _STEP_COLUMNS] for s in rnd.get("steps", [])],
                    )
            cur.execute(
                "UPDATE jobs SET status = ?, reason = ?, session_id = ?, started_at = ?, ended_at = ?"
                " WHERE experiment = ? AND job_key = ?",
                (
                    result.status,
                    result.reason,
                    session_id,
                    result.started_at,
                    result.ended_at,
                    experiment,
                    result.key,
                ),
            )

    # ----------------------------------------------------------------- reading

    def round_records(self, experiment: str | None = None) -> list[RoundRecord]:
        """Every round of every job's session (one experiment, or all), in play order."""
        sql = (
            "SELECT j.planner, j.instance, j.domain, r.reward, r.counted, r.started_at, r.ended_at,"
            " s.time_allowed_ms, s.num_rounds, s.id AS sid FROM jobs j JOIN sessions s ON s.id = j.session_id"
            " JOIN rounds r ON r.session_id = s.id WHERE j.status IN ('finished', 'timeout', 'failed')"
            # rounds that got a round-end (a round cut by a dropped session did not)
            " AND r.reward IS NOT NULL AND r.status NOT IN ('open', 'dropped', 'interrupted')"
            + (" AND j.experiment = ?" if experiment else "")
            + " ORDER BY j.id, r.id"
        )
        out = []
        for r in self.raw(sql, (experiment,) if experiment else ()):
            spent = None
            if r["started_at"] is not None and r["ended_at"] is not None:
                spent = (r["ended_at"] - r["started_at"]) * 1000.0
            out.append(
                RoundRecord(
                    r["planner"],
                    r["instance"],
                    r["domain"],
                    float(r["reward"]),
                    bool(r["counted"]),
                    spent,
                    r["time_allowed_ms"],
                    r["num_rounds"],
                    int(r["sid"]),
                )
            )
        return out

    def expected(self, experiment: str | None = None) -> list[tuple[str, str, str]]:
        """(planner, instance, domain) of every job, played or not (a planner that never
        played an instance still gets a score there: 0)."""
        sql = (
            "SELECT planner, instance, domain FROM jobs"
            + (" WHERE experiment = ?" if experiment else "")
            + " ORDER BY id"
        )
        return [(r[0], r[1], r[2]) for r in self.raw(sql, (experiment,) if experiment else ())]

    def turn_times(self, experiment: str | None = None) -> list[tuple[str, str, str, float]]:
        """(planner, instance, domain, seconds the planner took) for every step."""
        sql = (
            "SELECT j.planner, j.instance, j.domain, st.actions_received_at - st.turn_sent_at"
            " FROM jobs j JOIN rounds r ON r.session_id = j.session_id JOIN steps st ON st.round_id = r.id"
            + (" WHERE j.experiment = ?" if experiment else "")
            + " ORDER BY j.id, r.id, st.turn_num"
        )
        return [
            (a, b, c, float(d)) for a, b, c, d in self.raw(sql, (experiment,) if experiment else ())
        ]

    def raw(self, sql: str, params: tuple[Any, ...] = ()) -> list[sqlite3.Row]:
        """Rows of a read-only query (reports and tests)."""
        with self._lock:
            return self._conn.execute(sql, params).fetchall()
