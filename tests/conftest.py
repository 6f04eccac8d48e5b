"""Shared fixtures: the recorded rddlsim and PROST sessions in tests/data and the
rddlrepository corpus."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: Every file the tests read lives here (see tests/data/README.md).
DATA = REPO / "tests" / "data"
RDDLSIM_RDDL = DATA / "rddlsim" / "rddl"


@pytest.fixture(scope="session")
def recordings() -> Path:
    """tests/data: the recorded rddlsim sessions (rddlsim/) and PROST sessions (prost/)."""
    return DATA


@pytest.fixture(scope="session")
def rddlsim_rddl(recordings: Path) -> Path:
    return recordings / "rddlsim" / "rddl"


def corpus_root() -> Path:
    """The rddlrepository package's folder (a test dependency: pip install -e '.[test]')."""
    import rddlrepository

    return Path(rddlrepository.__file__).parent


def corpus_pairs() -> list[tuple[Path, Path]]:
    """(domain.rddl, instanceN.rddl) for every instance of rddlrepository,
    paired by folder as the package itself pairs them."""
    root = corpus_root()
    pairs = []
    for dom in sorted(root.rglob("domain.rddl")):
        for inst in sorted(dom.parent.glob("instance*.rddl")):
            pairs.append((dom, inst))
    return pairs
