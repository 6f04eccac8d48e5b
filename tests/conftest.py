"""Shared fixtures: the recorded rddlsim material beside the checkout and the
rddlrepository corpus."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
RDDLSIM_RDDL = SHARED / "rddlsim-transcripts" / "rddl"


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    if not SHARED.is_dir():
        pytest.skip(f"the shared folder is not beside the checkout ({SHARED})")
    return SHARED


@pytest.fixture(scope="session")
def rddlsim_rddl(shared_dir: Path) -> Path:
    return shared_dir / "rddlsim-transcripts" / "rddl"


def corpus_root() -> Path | None:
    try:
        import rddlrepository
    except ImportError:
        return None
    return Path(rddlrepository.__file__).parent


def corpus_pairs() -> list[tuple[Path, Path]]:
    """(domain.rddl, instanceN.rddl) for every instance of rddlrepository,
    paired by folder as the package itself pairs them."""
    root = corpus_root()
    if root is None:
        return []
    pairs = []
    for dom in sorted(root.rglob("domain.rddl")):
        for inst in sorted(dom.parent.glob("instance*.rddl")):
            pairs.append((dom, inst))
    return pairs
