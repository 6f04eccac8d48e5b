"""docs/cli.md names every option of every command, in that command's section."""

from __future__ import annotations

import re

import click
import pytest
from ippc.batch.cli import main as batch_main
from ippc.client.cli import main as client_main
from ippc.dispatch.cli import main as dispatch_main
from ippc.kb.cli import main as kb_main
from ippc.rddl.cli import main as rddl_main
from ippc.server.cli import main as server_main

from .docs import REPO

PAGE = REPO / "docs" / "cli.md"

COMMANDS: dict[str, click.Command] = {
    "rddl-server": server_main,
    "rddl-client": client_main,
    "rddl-dispatch": dispatch_main,
    "rddl-kb": kb_main,
    "rddl-batch run": batch_main.commands["run"],
    **{f"rddl {name}": cmd for name, cmd in rddl_main.commands.items()},
}


def section(text: str, command: str) -> str:
    """The part of the page under the heading that starts with the command's name."""
    parts = re.split(r"^## ", text, flags=re.M)
    found = [p for p in parts if p.startswith(f"`{command}")]
    assert len(found) == 1, f"docs/cli.md: {len(found)} sections for {command}"
    return found[0]


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_option_is_documented(command: str) -> None:
    text = section(PAGE.read_text(encoding="utf-8"), command)
    missing = []
    for param in COMMANDS[command].params:
        if not isinstance(param, click.Option):
            continue
        longs = [o for o in param.opts if o.startswith("--")] or param.opts
        if not any(re.search(re.escape(o) + r"(?![\w-])", text) for o in longs):
            missing.append("/".join(param.opts))
    assert not missing, f"docs/cli.md, {command}: options not described: {missing}"
