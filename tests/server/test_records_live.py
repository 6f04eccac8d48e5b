"""What a live server writes beside its replies: transcripts in the format
of the rddlsim recordings, and rddlsim's log file."""

from __future__ import annotations

from pathlib import Path

import pytest
from ippc.server.app import open_services
from ippc.server.config import ServerConfig
from ippc.server.records import read_transcript

from .harness import DECL, noop_session, running_server, shared_registry

pytestmark = pytest.mark.trio


async def test_transcript_and_log_of_a_session(tmp_path: Path) -> None:
    config = ServerConfig(port=0, rounds=2, transcripts=tmp_path / "tr", log_dir=tmp_path / "logs")
    (tmp_path / "logs").mkdir()
    services = open_services(config, shared_registry(), port=9999)
    async with running_server(config, services=services) as (port, _):
        result = await noop_session(port, client="recorded")
    services.rddlsim_log.close()
    files = list((tmp_path / "tr").glob("*.jsonl"))
    assert len(files) == 1
    meta, records = read_transcript(files[0])
    assert meta["instance"] == "sysadmin_inst_mdp__1" and meta["client"] == "recorded"
    data = [r for r in records if "data" in r]
    c2s = [r["data"] for r in data if r["dir"] == "c2s"]
    s2c = [r["data"] for r in data if r["dir"] == "s2c"]
    # every message, framed as on the wire, in order
    assert c2s[0].startswith('<?xml version="1.0" encoding="UTF-8"?>\n<session-request>') and c2s[
        0
    ].endswith("\0")
    assert c2s[1:3] == [(DECL + b"<round-request/>\0").decode(), (DECL + b"<actions/>\0").decode()]
    roots = [s.split("<", 3)[2].split(">")[0] for s in s2c]
    assert roots[:3] == ["session-init", "round-init", "turn"]
    assert roots[-2:] == ["round-end", "session-end"]
    assert roots.count("turn") == 2 * 5 and len(c2s) == 1 + 2 + 2 * 5
    assert all(s.endswith("\0") for s in s2c)
    assert [(r.get("event"), r["dir"]) for r in records if "event" in r] == [
        ("eof", "s2c")
    ]  # we closed
    # rddlsim's log: client-info, each round-end, the session-end
    log = (tmp_path / "logs" / "logs-9999.log").read_text()
    lines = log.splitlines()
    assert lines[0] == DECL.decode().strip() and lines[1].startswith("<client-info>")
    docs = [x for x in lines if not x.startswith("<?xml")]
    assert [d.split(">")[0] for d in docs] == [
        "<client-info",
        "<round-end",
        "<round-end",
        "<session-end",
    ]
    assert f"<total-reward>{result['total']}</total-reward>" in docs[-1]
