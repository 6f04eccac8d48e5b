"""docs/knowledge-base.md runs as written: its Python blocks, in order, in one
namespace; its JSON-lines transcript, replayed against a served knowledge
base with every reply compared; and `rddl-kb` as the page starts it."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import trio
from ippc.kb import KnowledgeBase
from ippc.kb.jsonl import JsonlServer, connect
from ippc.kb.service import register_kb

from .conftest import TURTLEBOT_DOMAIN, TURTLEBOT_INSTANCE

REPO = Path(__file__).resolve().parents[2]
PAGE = REPO / "docs" / "knowledge-base.md"


def blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", PAGE.read_text(), flags=re.S)


def test_the_python_examples_run(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(REPO)  # the page's paths are relative to the repository
    code = blocks("python")
    assert len(code) == 6
    namespace: dict[str, object] = {}
    for block in code:
        exec(compile(block, str(PAGE), "exec"), namespace)


@pytest.mark.trio
async def test_the_transcript_replays() -> None:
    (transcript,) = blocks("jsonl")
    lines = transcript.splitlines()
    assert all(line[:2] in ("> ", "< ") for line in lines)
    kb = KnowledgeBase.from_files(TURTLEBOT_DOMAIN, TURTLEBOT_INSTANCE)
    server = JsonlServer("kb")
    register_kb(server, kb)
    with trio.fail_after(20):
        async with trio.open_nursery() as nursery:
            port = await nursery.start(server.serve, "127.0.0.1", 0)
            async with connect(port) as client:
                for line in lines:
                    if line.startswith("> "):
                        await client.send_line(line[2:].encode() + b"\n")
                    else:
                        assert await client.next_event() == json.loads(line[2:]), line
            nursery.cancel_scope.cancel()
    assert kb.get("distance", ("printer-corridor", "phdarea")) == 10.0  # update 9 refused


def test_rddl_kb_serves_and_prints() -> None:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    cmd = [sys.executable, "-m", "ippc.kb.cli", str(TURTLEBOT_DOMAIN), str(TURTLEBOT_INSTANCE)]
    proc = subprocess.Popen([*cmd, "--port", "0", "-q"], stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()
        m = re.fullmatch(r"listening on 127\.0\.0\.1:(\d+)\n", first)
        assert m, first

        async def ask() -> object:
            async with connect(int(m.group(1))) as client:
                return await client.call("kb.goal_holds")

        assert trio.run(ask) is False
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    out = subprocess.run([*cmd, "--rddl"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout.startswith("non-fluents nf_turtlebot")
    bad = subprocess.run(
        [sys.executable, "-m", "ippc.kb.cli", str(TURTLEBOT_INSTANCE), str(TURTLEBOT_INSTANCE)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert bad.returncode == 1 and "expected one domain block" in bad.stderr
