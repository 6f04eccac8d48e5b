"""rddl-batch run's lock on DB.lock, in one process (the two-process case, a second
`rddl-batch run` beside a first, is in test_run.py)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from ippc.batch import ExperimentError
from ippc.batch.runner import _run_lock


def test_a_database_in_a_folder_not_made_yet_is_locked_there(tmp_path: Path) -> None:
    db = tmp_path / "new" / "dir" / "runs.sqlite"
    with _run_lock(db):
        lock = db.parent / "runs.sqlite.lock"
        assert lock.read_text().strip() == str(os.getpid())


def test_a_second_holder_is_refused_and_the_lock_is_freed_after(tmp_path: Path) -> None:
    db = tmp_path / "runs.sqlite"
    with _run_lock(db):
        with pytest.raises(ExperimentError, match=rf"another rddl-batch run \(pid {os.getpid()}\)"):
            with _run_lock(db):
                pass
    with _run_lock(db):  # released when the first ended
        pass
