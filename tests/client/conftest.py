"""The rddl-server subprocess that rddl-client's tests play against."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from .loopback import Server, serve_domains


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """`rddl-server domains/ --port 0 --rounds 2 --db ...`, one for a test module."""
    with serve_domains(tmp_path_factory.mktemp("server") / "results.db") as running:
        yield running


@pytest.fixture
def budget_server(tmp_path: Path) -> Iterator[Server]:
    """The same with `--timeout 3` (a 3 s session budget), one for each test."""
    with serve_domains(tmp_path / "server.sqlite", "--timeout", "3", start_timeout=60) as running:
        yield running
