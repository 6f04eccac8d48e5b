"""The result store's schema (server/store.py) and its migrations: ``SCHEMA``, the
tables of a new file, and what each later schema version adds to an older file, which
``ResultStore`` upgrades in place when it opens it (``upgrade``)."""

from __future__ import annotations

import sqlite3

#: Value of ``PRAGMA user_version`` for the schema below (1: sessions, rounds, steps;
#: 2: ``outcome`` and ``execution_seconds`` in ``steps``, for rddl-dispatch; 3: rddl-batch's
#: ``jobs``; 4: rddl-dispatch's ``kb_batches`` and ``kb_facts``). An older file is upgraded in
#: place when opened.
SCHEMA_VERSION = 5

SCHEMA = """
CREATE TABLE IF NOT EXISTS sessions (
    id                INTEGER PRIMARY KEY,
    server_session_id INTEGER NOT NULL,   -- rddlsim's session-id (k-th connection)
    instance          TEXT    NOT NULL,
    client_name       TEXT    NOT NULL,
    seed              INTEGER NOT NULL,
    num_rounds        INTEGER NOT NULL,
    time_allowed_ms   REAL    NOT NULL,
    peer              TEXT    NOT NULL,   -- "host:port" of the client
    no_header         INTEGER NOT NULL,   -- 0/1
    started_at        REAL    NOT NULL,   -- unix seconds
    ended_at          REAL,
    status            TEXT    NOT NULL DEFAULT 'open' CHECK (status IN
                      ('open', 'finished', 'timeout', 'dropped', 'interrupted', 'killed')),
    total_reward      REAL,
    rounds_used       INTEGER,
    reason            TEXT,
    owner             TEXT    NOT NULL    -- which ResultStore started it
);
CREATE TABLE IF NOT EXISTS rounds (
    id          INTEGER PRIMARY KEY,
    session_id  INTEGER NOT NULL REFERENCES sessions(id),
    round_num   INTEGER NOT NULL,         -- rddlsim's round-init round-num
    counted     INTEGER NOT NULL,         -- 0 for a practice round (execute-policy no)
    started_at  REAL    NOT NULL,
    ended_at    REAL,
    status      TEXT    NOT NULL DEFAULT 'open' CHECK (status IN
                ('open', 'finished', 'terminal', 'illegal-action', 'timeout', 'dropped',
                 'interrupted')),
    reward      REAL,                     -- discounted sum, as in round-end
    turns_used  INTEGER
);
CREATE INDEX IF NOT EXISTS rounds_by_session ON rounds(session_id);
CREATE TABLE IF NOT EXISTS steps (
    id                  INTEGER PRIMARY KEY,
    round_id            INTEGER NOT NULL REFERENCES rounds(id),
    turn_num            INTEGER NOT NULL,
    state               TEXT    NOT NULL, -- JSON [[name, [args...], value], ...]
    actions             TEXT    NOT NULL, -- JSON, same form
    reward              REAL    NOT NULL, -- reward of this transition
    turn_sent_at        REAL    NOT NULL,
    actions_received_at REAL    NOT NULL,
    outcome             TEXT,             -- JSON, rddl-dispatch's steps only
    execution_seconds   REAL,             -- rddl-dispatch's steps only
    UNIQUE (round_id, turn_num)
);
"""

# What each schema version adds to the one before (``SCHEMA`` is version 2 itself).
MIGRATIONS: dict[int, str] = {
    # version 1 -> 2: columns added, rows kept
    2: """
ALTER TABLE steps ADD COLUMN outcome TEXT;
ALTER TABLE steps ADD COLUMN execution_seconds REAL
""",
    3: """
CREATE TABLE IF NOT EXISTS jobs (
    id           INTEGER PRIMARY KEY,
    experiment   TEXT    NOT NULL,
    job_key      TEXT    NOT NULL,        -- "planner@instance", unique in its experiment
    planner      TEXT    NOT NULL,        -- the experiment's label for the planner
    instance     TEXT    NOT NULL,
    domain       TEXT    NOT NULL,
    server_seed  INTEGER NOT NULL,
    planner_seed INTEGER NOT NULL,
    status       TEXT    NOT NULL DEFAULT 'pending' CHECK (status IN
                 ('pending', 'running', 'finished', 'timeout', 'failed', 'interrupted')),
    reason       TEXT,                    -- why it failed or timed out
    session_id   INTEGER REFERENCES sessions(id),
    attempts     INTEGER NOT NULL DEFAULT 0,
    started_at   REAL,
    ended_at     REAL,
    UNIQUE (experiment, job_key)
);
CREATE INDEX IF NOT EXISTS jobs_by_status ON jobs(experiment, status);
""",
    4: """
CREATE TABLE IF NOT EXISTS kb_batches (
    id          INTEGER PRIMARY KEY,
    instance    TEXT    NOT NULL,         -- the dispatcher's instance name
    source      TEXT    NOT NULL,         -- who applied it: sensing, dispatcher, a client
    applied_at  REAL    NOT NULL,         -- unix seconds
    changes     TEXT    NOT NULL,         -- JSON [[fluent, [args...], new value], ...]
    goal        TEXT                      -- a goal change: JSON, the goal's facts
                                          -- (null: back to the domain's goal), else NULL
);
CREATE INDEX IF NOT EXISTS kb_batches_by_instance ON kb_batches(instance, id);
CREATE TABLE IF NOT EXISTS kb_facts (
    instance    TEXT    NOT NULL,
    fluent      TEXT    NOT NULL,
    args        TEXT    NOT NULL,         -- JSON [args...]
    value       TEXT    NOT NULL,         -- JSON
    batch_id    INTEGER NOT NULL REFERENCES kb_batches(id),
    PRIMARY KEY (instance, fluent, args)
);
""",
    # (and, in upgrade, 'killed' among the sessions' statuses)
    5: """
CREATE TABLE IF NOT EXISTS goal_outcomes (
    id          INTEGER PRIMARY KEY,
    instance    TEXT    NOT NULL,         -- the dispatcher's instance name
    goal        TEXT,                     -- the goal, one line
    version     INTEGER,                  -- the knowledge base's goal version
    outcome     TEXT    NOT NULL CHECK (outcome IN
                ('reached', 'abandoned', 'removed', 'interrupted')),
    turn        INTEGER,                  -- the run's turn when reached
    recorded_at REAL    NOT NULL,         -- unix seconds
    detail      TEXT    NOT NULL          -- JSON: the whole outcome as the report has it
);
CREATE INDEX IF NOT EXISTS goal_outcomes_by_instance ON goal_outcomes(instance, id);
""",
}


def _allow_killed(cur: sqlite3.Cursor) -> None:
    """Add 'killed' to the sessions' status CHECK of a store made before
    schema 5: SQLite cannot alter a CHECK, and rebuilding the table would
    break the rounds' references to it, so the table's stored definition
    is edited, as SQLite's documentation describes for CHECK changes."""
    old = "'dropped', 'interrupted'))"
    new = "'dropped', 'interrupted', 'killed'))"
    cur.execute("PRAGMA writable_schema = ON")
    cur.execute(
        "UPDATE sqlite_master SET sql = replace(sql, ?, ?)"
        " WHERE type = 'table' AND name = 'sessions' AND instr(sql, 'killed') = 0",
        (old, new),
    )
    version = cur.execute("PRAGMA schema_version").fetchone()[0]
    cur.execute(f"PRAGMA schema_version = {int(version) + 1}")
    cur.execute("PRAGMA writable_schema = OFF")


def upgrade(cur: sqlite3.Cursor, version: int) -> None:
    """Bring a store at schema `version` (0: a new file) to ``SCHEMA_VERSION``, in the
    caller's transaction: a new file gets ``SCHEMA`` (version 2) and what came after; an
    older one each step from its version on."""
    scripts = [SCHEMA] if version < 1 else []
    start = 3 if version < 1 else version + 1
    scripts += [MIGRATIONS[v] for v in range(start, SCHEMA_VERSION + 1)]
    for script in scripts:
        for statement in script.split(";"):
            if statement.strip():
                cur.execute(statement)
    if 1 <= version < 5:
        _allow_killed(cur)
    cur.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
