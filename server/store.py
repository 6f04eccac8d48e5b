"""The result store: every session, round and step the server plays, in SQLite.

Theory of operation
-------------------
The server calls this store synchronously from its trio thread, so every call is one
short transaction that is committed before the call returns. The database runs in WAL
mode with ``synchronous=NORMAL``: a commit appends to the write-ahead log without an
fsync, which is quick (tens of microseconds) and survives the death of the process
(``kill -9``) because the log lives in the operating system's page cache; only a power
failure can lose the last commits. A step is therefore safe once ``record_step``
returns, and the server sends its next message only after that.

Three tables (see ``SCHEMA`` in server/migrations.py): ``sessions`` (one row per session-request that named an
instance), ``rounds`` (one per round-init) and ``steps`` (one per transition: the state
the server sent in the turn, the actions the client answered and the reward of that
transition). State and actions are JSON text, a list of ``[name, [args...], value]``.
A step played by rddl-dispatch also has ``outcome`` (JSON: what each action's handler
reported, see ``ippc.dispatch``) and ``execution_seconds`` (how long the actions took);
both are NULL for a simulated step. Planning time is ``actions_received_at -
turn_sent_at``. Rows start with status ``open``; ``end_round``/``end_session`` close them and
``interrupt_open`` closes whatever a shutting-down server leaves open.

Schema version 3 adds a fourth table, ``jobs``, which rddl-batch fills (one row per
planner x instance of an experiment, with its seeds, status and failure reason, pointing
at the session that played it); the server never writes it. An older file is migrated
in place when it is opened (version 2's columns and the table are added; nothing else changes), so files written
by an older ippc stay readable and older readers of the three tables are unaffected.

Schema version 4 adds rddl-dispatch's knowledge-base journal: ``kb_batches`` (every batch
of changes applied to a dispatcher's knowledge base: its source, when, and the changed
groundings with their new values, JSON) and ``kb_facts`` (the latest value of every
grounding any batch changed, per instance), from which a restarted rddl-dispatch on the
same file resumes with the facts it had. Both are written in the same transaction.

Several processes may open the same file (a busy timeout makes writers wait for each
other). Each store tags the sessions it starts with an owner token, so that
``interrupt_open`` of one server does not close the live sessions of another.
"""

from __future__ import annotations

import itertools
import json
import logging
import os
import random
import socket
import sqlite3
import threading
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from .migrations import SCHEMA as _SCHEMA  # noqa: F401  (kept importable: tests build old files)
from .migrations import SCHEMA_VERSION, upgrade

__all__ = [
    "JOB_STATUSES",
    "ROUND_STATUSES",
    "SCHEMA_VERSION",
    "SESSION_STATUSES",
    "ResultStore",
    "StoreError",
    "decode_fluents",
    "encode_fluents",
]

log = logging.getLogger(__name__)


#: Final statuses of a session (``open`` while it runs).
SESSION_STATUSES = frozenset({"finished", "timeout", "dropped", "interrupted", "killed"})
#: Final statuses of a round (``open`` while it runs).
ROUND_STATUSES = frozenset(
    {"finished", "terminal", "illegal-action", "timeout", "dropped", "interrupted"}
)

#: Job statuses of rddl-batch (``pending`` until a worker takes the job).
JOB_STATUSES = frozenset({"pending", "running", "finished", "timeout", "failed", "interrupted"})

Fluent = tuple[str, tuple[str, ...], object]


def _json_default(value: object) -> object:
    # numpy scalars (numpy.bool_, numpy.int64, numpy.str_ ...) have .item(), which gives
    # the plain Python value; anything else is a caller error.
    item = getattr(value, "item", None)
    if callable(item):
        plain = item()
        if isinstance(plain, bool | int | float | str):
            return plain
    raise TypeError(
        f"fluent value {value!r} of type {type(value).__name__} is not bool, int, float or str"
    )


_ENCODER = json.JSONEncoder(separators=(",", ":"), default=_json_default)


def encode_fluents(fluents: list[tuple[str, tuple[str, ...], object]]) -> str:
    """JSON text for a list of ``(name, args, value)``: ``[[name, [args...], value], ...]``.

    Values must be bool, int, float or str (numpy scalars are converted). Non-finite
    floats are written as ``NaN``/``Infinity``, which Python's json reads back.
    """
    # Tuples serialise as JSON arrays, so the list goes to the (C) encoder as it is.
    return _ENCODER.encode(fluents)


def decode_fluents(text: str) -> list[Fluent]:
    """The inverse of :func:`encode_fluents`: a list of ``(name, args, value)`` tuples."""
    return [(name, tuple(args), value) for name, args, value in json.loads(text)]


def _real(x: object) -> float:
    return float(x)  # type: ignore[arg-type]  # numpy floats and ints convert


def _opt_real(x: object | None) -> float | None:
    return None if x is None else _real(x)


def _owner_is_dead(owner: str, host: str) -> bool:
    """Whether a store's owner token ("host:pid:tag", a worker's "host:pid:tag:wN") names a process of
    `host` that no longer runs."""
    parts = owner.split(":")
    if len(parts) < 3 or parts[0] != host or not parts[1].isdigit():
        return False
    pid = int(parts[1])
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False  # alive, another user's
    return False


class StoreError(RuntimeError):
    """A file that cannot be opened as a result store: not an SQLite database, a
    schema newer than this ippc's, or locked beyond the busy timeout. The message
    is SQLite's (or says which version); callers add the path."""


def _is_busy(err: sqlite3.OperationalError) -> bool:
    text = str(err)
    return "database is locked" in text or "database is busy" in text


class ResultStore:
    """Sessions, rounds and steps in one SQLite database (WAL, ``synchronous=NORMAL``).

    Every writing method is one transaction, committed before it returns. ``path`` may be
    ``":memory:"`` (tests); a missing parent folder of a file is created. The store may
    be used from any thread (calls are serialised by a lock). ``busy_timeout_ms`` bounds
    how long a write waits for another process that holds the database's write lock.
    A file that cannot be opened as a store raises `StoreError` (and is not changed).
    """

    def __init__(
        self, path: str | Path, *, busy_timeout_ms: int = 5000, owner: str | None = None
    ) -> None:
        self.path = str(path)
        #: Token stored with every session this store starts (see ``interrupt_open``);
        #: a caller may name it, as rddl-server does for each of its worker processes so
        #: that it can close the sessions of a worker that died.
        self.owner = owner or f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:12]}"
        self._lock = threading.Lock()
        self._closed = False
        if self.path != ":memory:" and not self.path.startswith("file:"):
            Path(self.path).parent.mkdir(parents=True, exist_ok=True)
        # isolation_level=None: the sqlite3 module opens no transactions on its own;
        # a lone statement commits when it completes and the longer writes use an
        # explicit BEGIN IMMEDIATE (so two processes never deadlock upgrading a lock).
        self._conn = sqlite3.connect(
            self.path,
            timeout=busy_timeout_ms / 1000.0,
            isolation_level=None,
            check_same_thread=False,
        )
        try:
            self._conn.execute(f"PRAGMA busy_timeout = {int(busy_timeout_ms)}")
            # Several processes may open a new database at once (rddl-server's workers,
            # several servers sharing one file). Switching it to WAL needs an exclusive lock, and
            # SQLite answers "database is locked" at once, without its busy handler, when
            # that would deadlock with another connection's read; so the setup is retried
            # for up to the busy timeout.
            deadline = time.monotonic() + busy_timeout_ms / 1000.0
            for attempt in itertools.count():
                try:
                    self._setup()
                    break
                except sqlite3.OperationalError as err:
                    if not _is_busy(err) or time.monotonic() >= deadline:
                        raise
                    time.sleep(min(0.2, 0.005 * 2**attempt) * random.uniform(0.5, 1.0))
        except sqlite3.DatabaseError as err:
            self._conn.close()
            raise StoreError(str(err)) from None
        except BaseException:
            self._conn.close()
            raise

    def _setup(self) -> None:
        mode = self._conn.execute("PRAGMA journal_mode = WAL").fetchone()[0]
        if mode != "wal" and self.path != ":memory:":
            log.warning("result store %s: journal mode is %r, not WAL", self.path, mode)
        self._conn.execute("PRAGMA synchronous = NORMAL")
        self._conn.execute("PRAGMA foreign_keys = ON")
        self._create_schema()

    def _create_schema(self) -> None:
        with self._tx() as cur:
            version = cur.execute("PRAGMA user_version").fetchone()[0]
            if version > SCHEMA_VERSION:
                raise StoreError(
                    f"result store {self.path} has schema version {version}; this ippc "
                    f"knows only up to {SCHEMA_VERSION}"
                )
            if version < SCHEMA_VERSION:
                upgrade(cur, version)
                if version >= 1:
                    log.info(
                        "result store %s: schema %d migrated to %d",
                        self.path,
                        version,
                        SCHEMA_VERSION,
                    )

    def close_killed(self, ended_at: float) -> int:
        """Mark as ``killed`` the open sessions of this host's processes that
        no longer run (a process killed with -9 never closed them; the owner
        token names its host and process id), with their open rounds (as
        ``interrupted``); the number marked. Sessions of other hosts, and of
        owners named otherwise, are left as they are."""
        host = socket.gethostname()
        with self._tx() as cur:
            rows = cur.execute("SELECT id, owner FROM sessions WHERE status = 'open'").fetchall()
            dead = [sid for sid, owner in rows if _owner_is_dead(str(owner), host)]
            for sid in dead:
                cur.execute(
                    "UPDATE sessions SET status = 'killed', ended_at = ?, reason = ? WHERE id = ?",
                    (
                        _real(ended_at),
                        "the process that played it ended without closing it (killed)",
                        sid,
                    ),
                )
                self._close_open_rounds(cur, "session_id = ?", (sid,), "interrupted", ended_at)
        if dead:
            log.warning(
                "result store %s: %d session(s) left open by a killed process marked as killed",
                self.path,
                len(dead),
            )
        return len(dead)

    def record_goal_outcome(self, instance: str, outcome: dict[str, Any]) -> int:
        """Record one goal's outcome (`ippc.dispatch.goals`): its row id."""
        with self._tx() as cur:
            cur.execute(
                "INSERT INTO goal_outcomes"
                " (instance, goal, version, outcome, turn, recorded_at, detail)"
                " VALUES (?, ?, ?, ?, ?, ?, ?)",
                (
                    str(instance),
                    outcome.get("goal"),
                    outcome.get("version"),
                    str(outcome["outcome"]),
                    outcome.get("turn"),
                    _real(outcome.get("recorded_at", time.time())),
                    _ENCODER.encode(outcome),
                ),
            )
            return int(cur.lastrowid or 0)

    def goal_outcomes(self, instance: str | None = None) -> list[dict[str, Any]]:
        """The recorded goal outcomes (of `instance`, or all), oldest first,
        each the outcome as the report has it."""
        sql = "SELECT detail FROM goal_outcomes"
        params: tuple[Any, ...] = ()
        if instance is not None:
            sql += " WHERE instance = ?"
            params = (str(instance),)
        return [json.loads(r["detail"]) for r in self._rows(sql + " ORDER BY id", params)]

    @contextmanager
    def _tx(self) -> Iterator[sqlite3.Cursor]:
        """One write transaction under the lock: committed on success, rolled back on error."""
        with self._lock:
            cur = self._conn.cursor()
            try:
                cur.execute("BEGIN IMMEDIATE")
                yield cur
                cur.execute("COMMIT")
            except BaseException:
                # Also after a failed COMMIT: a transaction left open would swallow every
                # later autocommitted write.
                if self._conn.in_transaction:
                    self._conn.execute("ROLLBACK")
                raise
            finally:
                cur.close()

    def _one(self, sql: str, params: tuple[Any, ...]) -> int:
        """Run one autocommitted write statement; its lastrowid."""
        with self._lock:
            cur = self._conn.execute(sql, params)
            return int(cur.lastrowid or 0)

    def close(self) -> None:
        """Close the connection (idempotent); everything written is already committed."""
        with self._lock:
            if not self._closed:
                self._closed = True
                self._conn.close()

    def __enter__(self) -> ResultStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ writing

    def start_session(
        self,
        *,
        server_session_id: int,
        instance: str,
        client_name: str,
        seed: int,
        num_rounds: int,
        time_allowed_ms: float,
        peer: str,
        no_header: bool,
        started_at: float,
    ) -> int:
        """Record a session that has begun (status ``open``); its row id."""
        return self._one(
            "INSERT INTO sessions (server_session_id, instance, client_name, seed, num_rounds,"
            " time_allowed_ms, peer, no_header, started_at, owner)"
            " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (
                int(server_session_id),
                str(instance),
                str(client_name),
                int(seed),
                int(num_rounds),
                _real(time_allowed_ms),
                str(peer),
                int(bool(no_header)),
                _real(started_at),
                self.owner,
            ),
        )

    def start_round(self, session: int, *, round_num: int, counted: bool, started_at: float) -> int:
        """Record a round that has begun (status ``open``); its row id.

        ``round_num`` is the number rddlsim puts in round-init; ``counted`` is false for a
        practice round (``execute-policy no`` under monitor-execution).
        """
        return self._one(
            "INSERT INTO rounds (session_id, round_num, counted, started_at) VALUES (?, ?, ?, ?)",
            (int(session), int(round_num), int(bool(counted)), _real(started_at)),
        )

    def record_step(
        self,
        round_: int,
        *,
        turn_num: int,
        state: list[tuple[str, tuple[str, ...], object]],
        actions: list[tuple[str, tuple[str, ...], object]],
        reward: float,
        turn_sent_at: float,
        actions_received_at: float,
        outcome: object = None,
        execution_seconds: float | None = None,
    ) -> None:
        """Record one transition: the state sent in turn ``turn_num``, the actions the client
        answered and the reward of that transition; for rddl-dispatch also the outcome
        (JSON-able) and the execution time. Committed when this returns.

        Raises ``sqlite3.IntegrityError`` for an unknown round or a turn recorded twice.
        A step is accepted even if its round was already closed (by ``interrupt_open``
        during a shutdown): it was played, so it is kept.
        """
        self._one(
            "INSERT INTO steps (round_id, turn_num, state, actions, reward, turn_sent_at,"
            " actions_received_at, outcome, execution_seconds) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (
                int(round_),
                int(turn_num),
                encode_fluents(state),
                encode_fluents(actions),
                _real(reward),
                _real(turn_sent_at),
                _real(actions_received_at),
                None if outcome is None else _ENCODER.encode(outcome),
                _opt_real(execution_seconds),
            ),
        )

    def end_round(
        self, round_: int, *, reward: float, turns_used: int, status: str, ended_at: float
    ) -> None:
        """Close a round with the values of its round-end.

        ``status`` is one of :data:`ROUND_STATUSES`. Closing a round that is already
        closed (a shutdown got there first) keeps the first record and logs it; an
        unknown round raises ``KeyError``.
        """
        if status not in ROUND_STATUSES:
            raise ValueError(f"round status {status!r} is not one of {sorted(ROUND_STATUSES)}")
        with self._tx() as cur:
            cur.execute(
                "UPDATE rounds SET reward = ?, turns_used = ?, status = ?, ended_at = ?"
                " WHERE id = ? AND status = 'open'",
                (_real(reward), int(turns_used), status, _real(ended_at), int(round_)),
            )
            if cur.rowcount == 0:
                self._already_closed(cur, "rounds", round_, status)

    def end_session(
        self,
        session: int,
        *,
        total_reward: float | None,
        rounds_used: int,
        status: str,
        reason: str | None,
        ended_at: float,
    ) -> None:
        """Close a session with the values of its session-end (``total_reward`` None when no
        session-end was sent).

        ``status`` is one of :data:`SESSION_STATUSES`. Rounds of the session still open
        are closed with the same status (their reward stays NULL, ``turns_used`` is the
        number of recorded steps), since the caller should have ended them: that is
        logged. Closing an already closed session keeps the first record; an unknown
        session raises ``KeyError``.
        """
        if status not in SESSION_STATUSES:
            raise ValueError(f"session status {status!r} is not one of {sorted(SESSION_STATUSES)}")
        with self._tx() as cur:
            cur.execute(
                "UPDATE sessions SET total_reward = ?, rounds_used = ?, status = ?, reason = ?,"
                " ended_at = ? WHERE id = ? AND status = 'open'",
                (
                    _opt_real(total_reward),
                    int(rounds_used),
                    status,
                    reason,
                    _real(ended_at),
                    int(session),
                ),
            )
            if cur.rowcount == 0:
                self._already_closed(cur, "sessions", session, status)
                return
            n = self._close_open_rounds(cur, "session_id = ?", (int(session),), status, ended_at)
            if n:
                log.warning(
                    "session %d ended (%s) with %d round(s) still open; closed them",
                    session,
                    status,
                    n,
                )

    def interrupt_open(self, reason: str, ended_at: float, *, every_owner: bool = False) -> int:
        """Mark the sessions still open, and their open rounds, as ``interrupted`` with
        ``reason``; the number of sessions marked.

        By default only the sessions this store started are touched, so a server that
        shuts down leaves alone the live sessions of other servers writing to the same
        file. ``every_owner=True`` closes every open session in the file, for recovery
        after a crash when no other server is running.
        """
        with self._tx() as cur:
            where, params = (
                ("status = 'open'", ())
                if every_owner
                else ("status = 'open' AND owner = ?", (self.owner,))
            )
            ids = [r[0] for r in cur.execute(f"SELECT id FROM sessions WHERE {where}", params)]
            cur.execute(
                "UPDATE sessions SET status = 'interrupted', reason = ?, ended_at = ?"
                f" WHERE {where}",
                (reason, _real(ended_at), *params),
            )
            if every_owner:
                self._close_open_rounds(cur, "1", (), "interrupted", ended_at)
            else:
                for sid in ids:
                    self._close_open_rounds(cur, "session_id = ?", (sid,), "interrupted", ended_at)
        if ids:
            log.info("marked %d open session(s) as interrupted: %s", len(ids), reason)
        return len(ids)

    @staticmethod
    def _close_open_rounds(
        cur: sqlite3.Cursor, where: str, params: tuple[Any, ...], status: str, ended_at: float
    ) -> int:
        cur.execute(
            "UPDATE rounds SET status = ?, ended_at = ?,"
            " turns_used = (SELECT count(*) FROM steps WHERE steps.round_id = rounds.id)"
            f" WHERE status = 'open' AND {where}",
            (status, _real(ended_at), *params),
        )
        return cur.rowcount

    @staticmethod
    def _already_closed(cur: sqlite3.Cursor, table: str, row: int, status: str) -> None:
        found = cur.execute(f"SELECT status FROM {table} WHERE id = ?", (int(row),)).fetchone()
        if found is None:
            raise KeyError(f"no row {row} in {table}")
        log.info("%s row %d already closed as %r; not changed to %r", table, row, found[0], status)

    def record_kb_batch(
        self,
        instance: str,
        source: str,
        changes: list[tuple[str, tuple[str, ...], object]],
        applied_at: float,
        *,
        goal: object = None,
        goal_changed: bool = False,
    ) -> int:
        """Journal one batch applied to the knowledge base of `instance`: the changed
        groundings with their new values (``(fluent, args, value)``), or, with
        `goal_changed`, a change of its goal to `goal` (JSON-able; None: back to the
        domain's own goal). The batch and the latest value of each grounding
        (``kb_facts``) are written in one transaction, committed when this returns; the
        batch's row id."""
        with self._tx() as cur:
            cur.execute(
                "INSERT INTO kb_batches (instance, source, applied_at, changes, goal)"
                " VALUES (?, ?, ?, ?, ?)",
                (
                    str(instance),
                    str(source),
                    _real(applied_at),
                    encode_fluents(changes),
                    _ENCODER.encode(goal) if goal_changed else None,
                ),
            )
            batch = int(cur.lastrowid or 0)
            cur.executemany(
                "INSERT INTO kb_facts (instance, fluent, args, value, batch_id)"
                " VALUES (?, ?, ?, ?, ?) ON CONFLICT (instance, fluent, args)"
                " DO UPDATE SET value = excluded.value, batch_id = excluded.batch_id",
                [
                    (
                        str(instance),
                        str(fluent),
                        _ENCODER.encode(list(args)),
                        _ENCODER.encode(value),
                        batch,
                    )
                    for fluent, args, value in changes
                ],
            )
        return batch

    # ------------------------------------------------------------------ reading

    def kb_facts(self, instance: str) -> list[Fluent]:
        """The latest journaled value of every grounding of `instance`'s knowledge base
        that a batch changed, as ``(fluent, args, value)``, in the order last changed."""
        rows = self._rows(
            "SELECT fluent, args, value FROM kb_facts WHERE instance = ? ORDER BY batch_id",
            (str(instance),),
        )
        return [(r["fluent"], tuple(json.loads(r["args"])), json.loads(r["value"])) for r in rows]

    def kb_goal(self, instance: str) -> tuple[bool, Any]:
        """The last goal journaled for `instance`: ``(True, goal)`` (None: the domain's
        own goal), or ``(False, None)`` when no goal change was journaled."""
        rows = self._rows(
            "SELECT goal FROM kb_batches WHERE instance = ? AND goal IS NOT NULL"
            " ORDER BY id DESC LIMIT 1",
            (str(instance),),
        )
        return (True, json.loads(rows[0]["goal"])) if rows else (False, None)

    def kb_batches(self, instance: str, *, after: int = 0) -> list[dict[str, Any]]:
        """The journaled batches of `instance` with an id above `after`, oldest first;
        ``changes`` decoded to ``(fluent, args, value)`` tuples."""
        rows = self._rows(
            "SELECT * FROM kb_batches WHERE instance = ? AND id > ? ORDER BY id",
            (str(instance), int(after)),
        )
        for r in rows:
            r["changes"] = decode_fluents(r["changes"])
            if r["goal"] is not None:
                r["goal"] = json.loads(r["goal"])
        return rows

    def _rows(self, sql: str, params: tuple[Any, ...] = ()) -> list[dict[str, Any]]:
        with self._lock:
            cur = self._conn.execute(sql, params)
            names = [d[0] for d in cur.description]
            return [dict(zip(names, row, strict=True)) for row in cur.fetchall()]

    def sessions(self) -> list[dict[str, Any]]:
        """Every session, oldest first, as plain dicts (``no_header`` as bool)."""
        rows = self._rows("SELECT * FROM sessions ORDER BY id")
        for r in rows:
            r["no_header"] = bool(r["no_header"])
        return rows

    def session(self, session: int) -> dict[str, Any]:
        """One session as a dict; ``KeyError`` if unknown."""
        rows = self._rows("SELECT * FROM sessions WHERE id = ?", (int(session),))
        if not rows:
            raise KeyError(f"no session {session}")
        rows[0]["no_header"] = bool(rows[0]["no_header"])
        return rows[0]

    def rounds(self, session: int) -> list[dict[str, Any]]:
        """The rounds of a session in the order played (``counted`` as bool)."""
        rows = self._rows("SELECT * FROM rounds WHERE session_id = ? ORDER BY id", (int(session),))
        for r in rows:
            r["counted"] = bool(r["counted"])
        return rows

    def steps(self, round_: int) -> list[dict[str, Any]]:
        """The steps of a round by turn number; ``state`` and ``actions`` decoded to lists
        of ``(name, args, value)`` tuples, ``outcome`` decoded from JSON (None for a
        simulated step)."""
        rows = self._rows(
            "SELECT * FROM steps WHERE round_id = ? ORDER BY turn_num", (int(round_),)
        )
        for r in rows:
            r["state"] = decode_fluents(r["state"])
            r["actions"] = decode_fluents(r["actions"])
            if r["outcome"] is not None:
                r["outcome"] = json.loads(r["outcome"])
        return rows

    def count_steps(self, round_: int | None = None) -> int:
        """How many steps are stored (in one round, or in all)."""
        with self._lock:
            if round_ is None:
                return int(self._conn.execute("SELECT count(*) FROM steps").fetchone()[0])
            return int(
                self._conn.execute(
                    "SELECT count(*) FROM steps WHERE round_id = ?", (int(round_),)
                ).fetchone()[0]
            )
