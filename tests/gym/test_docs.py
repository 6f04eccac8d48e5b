"""docs/gym.md's example learns, and its illustrative plotting block draws the
learning curve the page shows (tests/test_docs_examples.py runs the example itself
and compares its printout with the page; this runs the plot after it, in a scratch
folder, so the committed figure is not rewritten by the tests)."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import pytest

from ..docs import REPO, blocks

PAGE = REPO / "docs" / "gym.md"


def test_the_example_learns_and_draws_its_curve(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    python = [b for b in blocks(PAGE.read_text(encoding="utf-8")) if b.lang == "python"]
    example = next(b for b in python if "def episode_returns" in b.text)
    plot = python[-1]
    assert "savefig" in plot.text and "docs/gym-cem-sysadmin.png" in plot.text
    assert (REPO / "docs" / "gym-cem-sysadmin.png").stat().st_size > 10_000
    (tmp_path / "docs").mkdir()
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {"__name__": "__main__"}
    with contextlib.redirect_stdout(io.StringIO()):
        exec(compile(example.text, f"{PAGE}:{example.line}", "exec"), namespace)
        exec(compile(plot.text, f"{PAGE}:{plot.line}", "exec"), namespace)
    random_return, learned = namespace["random_return"], namespace["learned_return"]
    assert isinstance(random_return, float) and isinstance(learned, float)
    assert learned > random_return + 50  # SysAdmin #1: about 217 against 342
    png = (tmp_path / "docs" / "gym-cem-sysadmin.png").read_bytes()
    assert png.startswith(b"\x89PNG") and len(png) > 10_000
