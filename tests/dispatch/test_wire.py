"""rddl-dispatch speaks rddl-server's bytes: the same session-init, the same
framing, the same first turn for the same instance (the knowledge base starts
from the instance's initial state)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import trio
from ippc.client.session import ClientConfig, run_session
from ippc.dispatch.run import PlannerSpec, simulate
from ippc.planners.base import make_planner
from ippc.server.app import serve
from ippc.server.config import ServerConfig
from ippc.server.records import data_bytes, read_transcript
from ippc.server.registry import Registry

from .conftest import DOMAIN, ONE

TIME = re.compile(rb"<time-left>[^<]*</time-left>")


def server_messages(folder: Path) -> list[bytes]:
    (path,) = folder.glob("*.jsonl")
    _, records = read_transcript(path)
    return [data_bytes(r) for r in records if r.get("dir") == "s2c" and "data" in r]


def rddl_server_session(folder: Path, no_header: bool) -> None:
    async def main() -> None:
        config = ServerConfig(
            port=0, rounds=1, timeout=0, individual_session=True, transcripts=folder
        )
        async with trio.open_nursery() as nursery:
            port = await nursery.start(serve, config, Registry.load(DOMAIN, ONE))
            await run_session(
                ClientConfig(
                    port=port, instance="courier_one", no_header=no_header, client_name="noop"
                ),
                make_planner("noop", {}),
                "noop",
            )

    trio.run(main)


@pytest.mark.parametrize("no_header", [False, True], ids=["nul", "no-header"])
def test_the_dispatcher_sends_rddl_servers_bytes(tmp_path: Path, no_header: bool) -> None:
    ours, reference = tmp_path / "dispatch", tmp_path / "server"
    report = simulate(
        DOMAIN,
        ONE,
        seed=0,
        planner=PlannerSpec("noop", no_header=no_header),
        rounds=1,
        transcripts=ours,
    )
    assert report.turns == 12 and not report.goal_reached  # noop never delivers
    rddl_server_session(reference, no_header)
    a, b = server_messages(ours), server_messages(reference)
    assert len(a) == len(b) == 1 + 1 + 12 + 1 + 1  # init, round-init, 12 turns, round-end, end
    assert a[0] == b[0]  # session-init: the task, session-id, rounds, time-allowed
    assert TIME.sub(b"", a[1]) == TIME.sub(b"", b[1])  # round-init
    assert TIME.sub(b"", a[2]) == TIME.sub(b"", b[2])  # the first turn: the initial state
    for x, y in zip(a, b, strict=True):
        assert x.endswith(b"\0") is (not no_header) and y.endswith(b"\0") is (not no_header)
        assert x.startswith(b"<?xml") is (not no_header)
        assert re.match(rb"(<\?xml[^>]*>\n)?<([a-z-]+)", x).group(2) == re.match(  # type: ignore[union-attr]
            rb"(<\?xml[^>]*>\n)?<([a-z-]+)", y
        ).group(2)
