"""Shared fixtures: the recorded rddlsim and PROST sessions in tests/data and the
rddlrepository corpus."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

# The planners' default start-up allowance (planners/budget.py) in the tests: their
# cold C compiles share two cores with everything else, so a session waits for its
# compile instead of falling back; the tests of the fallbacks set `startup` themselves.
os.environ.setdefault("IPPC_STARTUP", "300")

REPO = Path(__file__).resolve().parents[1]
#: Every file the tests read lives here (see tests/data/README.md).
DATA = REPO / "tests" / "data"
RDDLSIM_RDDL = DATA / "rddlsim" / "rddl"


@pytest.fixture(scope="session", autouse=True)
def cstep_cache(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """The C steps `rddl.sim.cstep` compiles (every thts session with a C
    compiler) are cached in the run's temporary folder (`IPPC_CACHE`), not in
    ~/.cache; one folder for every xdist worker of the run (a library is
    written under a temporary name and renamed, so workers may share it)."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent
    folder = base / "ippc-cache"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("IPPC_CACHE", str(folder))
        yield folder


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


#: The MDP domains of IPPC 2011, 2014 and 2018 in rddlrepository (archive/competitions).
IPPC_MDP_DOMAINS: dict[str, list[str]] = {
    "IPPC2011": [
        "CooperativeRecon",
        "CrossingTraffic",
        "Elevators",
        "GameOfLife",
        "Navigation",
        "SkillTeaching",
        "SysAdmin",
        "Traffic",
    ],
    "IPPC2014": [
        "AcademicAdvising",
        "CrossingTraffic",
        "Elevators",
        "SkillTeaching",
        "Tamarisk",
        "Traffic",
        "TriangleTireworld",
        "Wildfire",
    ],
    "IPPC2018": [
        "AcademicAdvising",
        "ChromaticDice",
        "CooperativeRecon",
        "EarthObservation",
        "Manufacturer",
        "PushYourLuck",
        "RedFinnedBlueEye",
        "WildlifePreserve",
    ],
}


def ippc_files(year: str, domain: str, n: int = 1) -> tuple[Path, Path]:
    """(domain.rddl, instance<n>.rddl) of an IPPC MDP domain in rddlrepository
    (its MDP folder where it has one; WildlifePreserve's p<n> folders)."""
    folder = corpus_root() / "archive" / "competitions" / year / domain
    for sub in ("MDP", f"p{n}"):
        if (folder / sub).is_dir():
            folder = folder / sub
    inst = folder / f"instance{n}.rddl"
    if not inst.exists():  # one instance per folder
        inst = sorted(folder.glob("instance*.rddl"))[0]
    return folder / "domain.rddl", inst
