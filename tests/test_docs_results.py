"""docs/results.md describes the result store as it is: each table's columns, the
statuses, the schema version."""

from __future__ import annotations

import re
import sqlite3
from pathlib import Path

from ippc.server.store import (
    JOB_STATUSES,
    ROUND_STATUSES,
    SCHEMA_VERSION,
    SESSION_STATUSES,
    ResultStore,
)

from .docs import REPO

PAGE = REPO / "docs" / "results.md"


def documented_tables(text: str) -> dict[str, tuple[list[str], set[str]]]:
    """{table: (its columns in the page's order, the statuses named in parentheses)}."""
    tables = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        m = re.fullmatch(r"`([a-z_]+)`", cells[0]) if len(cells) == 3 else None
        if not m:
            continue
        notes = " ".join(re.findall(r"\(([^)]*)\)", cells[2]))
        columns = re.findall(r"`([a-z_]+)`", re.sub(r"\([^)]*\)", "", cells[2]))
        tables[m.group(1)] = (columns, set(re.findall(r"`([a-z-]+)`", notes)))
    return tables


def test_the_tables_are_the_schema(tmp_path: Path) -> None:
    text = PAGE.read_text(encoding="utf-8")
    with ResultStore(tmp_path / "r.db"):
        pass
    db = sqlite3.connect(tmp_path / "r.db")
    try:
        documented = documented_tables(text)
        tables = {
            name
            for (name,) in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")
            if not name.startswith("sqlite_")
        }
        assert set(documented) == tables
        for table, (columns, _) in documented.items():
            actual = [row[1] for row in db.execute(f"PRAGMA table_info({table})")]
            assert columns == actual, table
        assert documented["sessions"][1] >= SESSION_STATUSES | {"open"}
        assert documented["rounds"][1] >= ROUND_STATUSES | {"open"}
        assert documented["jobs"][1] >= JOB_STATUSES
        assert db.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION
    finally:
        db.close()
    assert f"`PRAGMA user_version` ({SCHEMA_VERSION}" in text
