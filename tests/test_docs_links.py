"""Every relative link in README.md and docs/*.md resolves: the file exists, and an
#anchor names a heading of the target page (GitHub's heading ids)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from .docs import REPO, doc_pages, heading_ids, links

PAGES = doc_pages()


def test_the_pages_are_found() -> None:
    names = {p.relative_to(REPO).as_posix() for p in PAGES}
    assert "README.md" in names
    assert {"docs/cli.md", "docs/architecture.md", "docs/benchmarks.md"} <= names


def test_heading_ids_follow_github() -> None:
    text = "# `rddl check PATH...`\n## replan: determinise and replan\n## Tests\n## Tests\n"
    assert heading_ids(text) == {
        "rddl-check-path",
        "replan-determinise-and-replan",
        "tests",
        "tests-1",
    }
    # a fenced block's comment lines are not headings
    assert heading_ids("```python\n# not a heading\n```\n") == set()


def test_links_are_read_outside_code() -> None:
    text = "[a](x.md) `[b](y.md)`\n```\n[c](z.md)\n```\n[d](https://e.org) [f](#g)\n"
    assert [target for target, _ in links(text)] == ["x.md", "https://e.org", "#g"]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(REPO).as_posix())
def test_relative_links_resolve(page: Path) -> None:
    broken = []
    for target, line in links(page.read_text(encoding="utf-8")):
        if re.match(r"[a-z][a-z0-9+.-]*:", target):  # https:, mailto: ...: not ours to check
            continue
        path_part, _, anchor = target.partition("#")
        dest = (page.parent / path_part).resolve() if path_part else page
        where = f"{page.relative_to(REPO)}:{line}: {target}"
        if not dest.exists():
            broken.append(f"{where}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in heading_ids(dest.read_text()):
            broken.append(f"{where}: no heading #{anchor} in {dest.relative_to(REPO)}")
        elif anchor and dest.suffix != ".md":
            broken.append(f"{where}: an anchor into a file that is not markdown")
        elif REPO not in dest.parents and dest != REPO:
            broken.append(f"{where}: points outside the repository")
    assert not broken, "\n".join(broken)


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(REPO).as_posix())
def test_files_named_in_code_spans_exist(page: Path) -> None:
    """A path in a code span that starts at one of the repository's folders (`rddl/lexer.py`,
    `tests/fakes/fake_prost.py`) names a file or folder that is there."""
    tops = {p.name for p in REPO.iterdir() if p.is_dir() and not p.name.startswith(".")}
    missing = []
    for span in re.findall(r"`([^`\s]+)`", page.read_text(encoding="utf-8")):
        first = span.split("/", 1)[0]
        if "/" in span and first in tops and not any(c in span for c in "*<>$"):
            if not (REPO / span.rstrip("/")).exists():
                missing.append(span)
    assert not missing, f"{page.relative_to(REPO)} names paths that are not there: {missing}"


def test_the_readme_stays_a_front_page() -> None:
    """The reference lives in docs/; the README is the front page (issue 14: about 250 lines)."""
    lines = (REPO / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 250, f"README.md has {len(lines)} lines: move the reference into docs/"
