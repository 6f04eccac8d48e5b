"""The generated code shown in `ippc.rddl.sim`'s docstring is what the
compiler writes for the RDDL shown there."""

from __future__ import annotations

import textwrap
from pathlib import Path

import ippc.rddl.sim as sim_package
import pytest
from ippc.rddl import load_model
from ippc.rddl.simulator import Simulator


def _indented_block(doc: str, first: str) -> str:
    """The indented block of `doc` whose first line starts with `first`,
    dedented (its lines up to the next unindented non-blank line)."""
    lines = doc.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("    " + first))
    block = []
    for line in lines[start:]:
        if line.strip() and not line.startswith("    "):
            break
        block.append(line)
    return textwrap.dedent("\n".join(block)).strip() + "\n"


def test_the_docstring_example_is_what_the_compiler_writes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    doc = sim_package.__doc__
    assert doc is not None
    rddl = _indented_block(doc, "domain mini {")
    shown = _indented_block(doc, "def _step(")
    (tmp_path / "mini.rddl").write_text(rddl)
    monkeypatch.chdir(tmp_path)  # (the source names the file as it was given)
    sim = Simulator(load_model("mini.rddl"))
    assert sim.source() == shown
    # the constants the text names
    ns = sim._compiler.ns
    assert (ns["k6"].item(), ns["k8"].item(), ns["k10"].item()) == (0.5, 0.2, 2.0**32)
    assert ns["k2"] == sim._fail_nondef
    assert ns["k9"].tolist() == [[False, True], [True, False]]
