"""A PROST-style client (the fake PROST: declaration without newline,
<no-header/>, bare XML read by depth) plays whole sessions on our server
while a plain NUL client plays on the same server at the same time."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import trio
from ippc.planners.prost import ProstPlanner
from ippc.server.config import ServerConfig
from ippc.server.session import Services
from ippc.server.store import ResultStore

from .harness import noop_session, running_server, shared_registry

pytestmark = pytest.mark.trio

FAKES = Path(__file__).resolve().parents[1] / "fakes"


@pytest.fixture
def prost_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    folder = tmp_path / "prost"
    folder.mkdir()
    os.symlink(FAKES / "fake_prost.py", folder / "search")
    os.symlink(FAKES / "fake_rddl_parser.py", folder / "rddl-parser-release")
    monkeypatch.setenv("FAKE_PROST_ACTION", "reboot(c3) ")
    monkeypatch.setenv("FAKE_PROST_MAX_SECONDS", "30")
    monkeypatch.delenv("FAKE_PROST_MODE", raising=False)
    return folder


async def test_fake_prost_and_a_nul_client_at_once(prost_dir: Path, tmp_path: Path) -> None:
    config = ServerConfig(port=0, rounds=3)
    store = ResultStore(":memory:")
    services = Services(config, shared_registry(), store=store)
    planner = ProstPlanner(binary=str(prost_dir / "search"))
    async with running_server(config, services=services) as (port, _):
        plain: dict = {}

        async def nul_client() -> None:
            plain.update(await noop_session(port, client="plain", stall=0.005))

        with trio.fail_after(60):
            async with trio.open_nursery() as n:
                n.start_soon(nul_client)
                result = await trio.to_thread.run_sync(
                    lambda: planner.run_session(
                        host="127.0.0.1",
                        port=port,
                        instance="sysadmin_inst_mdp__1",
                        timeout=45,
                        log_path=tmp_path / "prost.log",
                    )
                )
    assert result.ok, (result.error, (tmp_path / "prost.log").read_text()[-2000:])
    assert len(result.rounds) == 3
    assert len(plain["rounds"]) == 3
    sessions = {s["client_name"]: s for s in store.sessions()}
    assert set(sessions) == {"prost", "plain"}
    assert sessions["prost"]["no_header"] is True and sessions["plain"]["no_header"] is False
    rounds = store.rounds(sessions["prost"]["id"])
    assert [r["reward"] for r in rounds] == pytest.approx(result.rounds)
    assert sessions["prost"]["total_reward"] == pytest.approx(result.total_reward)
    # PROST's action reached the simulator: every step of its session rebooted c3
    steps = store.steps(rounds[0]["id"])
    assert all(s["actions"] == [("reboot", ("c3",), "true")] for s in steps)
