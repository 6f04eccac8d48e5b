"""Fixtures of the robot side's tests: the courier domain (tests/data/dispatch)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from ippc.kb import KnowledgeBase

DATA = Path(__file__).resolve().parents[1] / "data" / "dispatch"
DOMAIN = DATA / "courier_domain.rddl"
ONE = DATA / "courier_one.rddl"
TWO = DATA / "courier_two.rddl"
FAKES = Path(__file__).resolve().parents[1] / "fakes"


@pytest.fixture
def kb() -> KnowledgeBase:
    """The one-robot courier instance (robot r1 in the hall)."""
    return KnowledgeBase.from_files(DOMAIN, ONE)


@pytest.fixture
def prost_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A folder laid out like PROST's (the fake search program and parser),
    with no fake-PROST settings inherited from the caller."""
    folder = tmp_path / "prost"
    folder.mkdir()
    os.symlink(FAKES / "fake_prost.py", folder / "search")
    os.symlink(FAKES / "fake_rddl_parser.py", folder / "rddl-parser-release")
    for var in ("PROST_BIN", "FAKE_PROST_MODE", "FAKE_PROST_ACTIONS_FILE", "FAKE_PROST_ACTION"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("FAKE_PROST_MAX_SECONDS", "30")
    return folder
