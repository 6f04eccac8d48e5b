"""The repository stands alone: what the tests and benchmarks read is in it, and
the package metadata ships every bundled domain."""

from __future__ import annotations

import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _code_files() -> list[Path]:
    files = [REPO / "Makefile", *sorted((REPO / ".ci").glob("*"))]
    for folder in ("tests", "bench"):
        files += [
            p for p in sorted((REPO / folder).rglob("*")) if p.suffix in {".py", ".sh", ".toml"}
        ]
    return [p for p in files if p.is_file() and p != Path(__file__)]


def test_nothing_reads_a_folder_beside_the_checkout() -> None:
    for path in _code_files():
        text = path.read_text(encoding="utf-8", errors="replace")
        for needle in ("../shared", "rddlsim-transcripts", "prost-transcripts", '"shared"'):
            assert needle not in text, f"{path.relative_to(REPO)} mentions {needle!r}"


def test_every_bundled_domain_folder_is_packaged() -> None:
    meta = tomllib.loads((REPO / "pyproject.toml").read_text())
    packages = set(meta["tool"]["setuptools"]["packages"])
    data = meta["tool"]["setuptools"]["package-data"]
    for folder in sorted((REPO / "domains").iterdir()):
        if folder.is_dir() and any(folder.glob("*.rddl")):
            name = f"ippc.domains.{folder.name}"
            assert name in packages, f"{name} is missing from [tool.setuptools] packages"
            assert "*.rddl" in data.get(name, []), f"{name} is missing from package-data"


def test_recordings_have_their_readme() -> None:
    readme = (REPO / "tests" / "data" / "README.md").read_text()
    for folder in ("rddlsim", "prost"):
        assert f"`{folder}/`" in readme
        assert any((REPO / "tests" / "data" / folder).iterdir())
