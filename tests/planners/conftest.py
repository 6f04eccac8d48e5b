"""Fixtures for the planner tests: the recorded PROST sessions and a folder
laid out like a PROST installation that holds the fake PROST."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

FAKES = Path(__file__).resolve().parents[1] / "fakes"
FAKE_PROST = FAKES / "fake_prost.py"
FAKE_PARSER = FAKES / "fake_rddl_parser.py"


@pytest.fixture(scope="session")
def prost_transcripts(recordings: Path) -> Path:
    return recordings / "prost"


@pytest.fixture
def prost_dir(tmp_path: Path) -> Path:
    """A folder like the one PROST's prost.py runs in: the search program
    and `rddl-parser-release` side by side (links to the fakes)."""
    folder = tmp_path / "prost"
    folder.mkdir()
    os.symlink(FAKE_PROST, folder / "search")
    os.symlink(FAKE_PARSER, folder / "rddl-parser-release")
    return folder


@pytest.fixture(autouse=True)
def _no_fake_settings(monkeypatch: pytest.MonkeyPatch) -> None:
    """No test inherits fake-PROST settings or PROST_BIN from the caller."""
    for var in (
        "PROST_BIN",
        "FAKE_PROST_MODE",
        "FAKE_PROST_ACTIONS_FILE",
        "FAKE_PROST_ACTION",
        "FAKE_PROST_IGNORE_TERM",
    ):
        monkeypatch.delenv(var, raising=False)
    # Whatever goes wrong, a fake stops by itself well within the test run.
    monkeypatch.setenv("FAKE_PROST_MAX_SECONDS", "30")
