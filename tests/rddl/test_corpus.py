"""The IPPC corpus: every domain and instance of the rddlrepository package
parses and checks. Slow: marked, and run in CI by `make test`."""

from __future__ import annotations

from pathlib import Path

import pytest
from ippc.rddl import check_files, check_pair, parse_file

from ..conftest import corpus_pairs, corpus_root

pytestmark = pytest.mark.slow

PAIRS = corpus_pairs()

# Instances whose own file names a domain that is not the one beside it in
# the package (rddlrepository pairs files by folder; rddlsim pairs by name).
# Paired by name they fail, and must fail with exactly this error.
NAME_MISMATCHES = {
    "bicycle_inst": "names domain 'bicycle'",  # the domain is called 'Bicycle'
    "Reservoir_cont_0": "names domain 'reservoir_control_dis'",  # Continuous folder
    "Reservoir_cont_1": "names domain 'reservoir_control_dis'",
}


def _id(pair: tuple[Path, Path]) -> str:
    root = corpus_root()
    assert root is not None
    return str(pair[1].relative_to(root))


def test_corpus_is_there() -> None:
    # 586 instance files across IPPC 2011-2023 and the other contexts
    assert len(PAIRS) >= 586


@pytest.mark.parametrize("pair", PAIRS, ids=[_id(p) for p in PAIRS])
def test_instance_checks(pair: tuple[Path, Path]) -> None:
    domain, instance = pair
    results = check_pair(domain, instance)
    assert results, instance
    for r in results:
        assert r.ok, "\n".join(d.render() for d in r.diagnostics)
        assert r.model is not None and r.model.horizon is not None


def test_every_domain_file_parses() -> None:
    root = corpus_root()
    domains = sorted(root.rglob("domain.rddl"))
    assert len(domains) >= 100
    for f in domains:
        assert parse_file(f).domains, f


def test_folders_by_name_as_rddlsim_pairs_them() -> None:
    root = corpus_root()
    failures = {}
    count = 0
    for folder in sorted({d.parent for d in root.rglob("domain.rddl")}):
        for r in check_files(*sorted(folder.glob("*.rddl"))):
            count += 1
            if not r.ok:
                failures[r.name] = r.diagnostics[0]
    assert count >= 586
    assert set(failures) == set(NAME_MISMATCHES)
    for name, fragment in NAME_MISMATCHES.items():
        assert failures[name].kind == "unknown-domain" and fragment in failures[name].message
