"""rddl-dispatch's budgets hold whatever its planner does: a planner plug-in whose
start-up never returns (``stuck``) and one that allocates without bound (``hog``,
tests/client/runaway.py) play in a child process that is ended at the session's budget
plus the grace, or over the memory budget; the dispatcher records why, its knowledge
base's socket answers meanwhile, and it goes on (real sockets on 127.0.0.1)."""

from __future__ import annotations

import logging
import os
import re
from pathlib import Path
from typing import Any

import pytest
import trio
from click.testing import CliRunner
from ippc.dispatch.cli import main
from ippc.dispatch.run import (
    LinkPolicy,
    PlannerSpec,
    RunReport,
    build_robot,
    dispatch_session,
    server_config,
)
from ippc.kb import KnowledgeBase
from ippc.kb.jsonl import connect
from ippc.server.store import ResultStore

from ..client import runaway
from .conftest import DOMAIN, ONE

BUDGET_MB = 300.0


@pytest.fixture
def plugins(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    return runaway.register(monkeypatch, tmp_path / "plugins")


def guard_children() -> list[int]:
    """Our child processes that run `ippc.client.guard` (a planner's process)."""
    me = str(os.getpid())
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", encoding="ascii", errors="replace") as f:
                ppid = f.read().rsplit(")", 1)[1].split()[1]
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                cmd = f.read()
        except (OSError, IndexError):
            continue
        if ppid == me and b"ippc.client.guard" in cmd:
            found.append(int(entry))
    return found


async def robot_run(
    spec: PlannerSpec,
    db: Path,
    *,
    timeout: float,
    memory_mb: float | None,
    link: LinkPolicy,
    until: Any,
) -> tuple[RunReport, list[Any]]:
    """A robot's run (its handlers succeed) with the knowledge base's socket on: the
    socket is asked for the robot's place every 0.2 s while the planner is out; once
    `until(answers)` says so (or the run ends by itself), the run is stopped. The
    report and the socket's answers."""
    kb = KnowledgeBase.from_files(DOMAIN, ONE)
    robot, dispatcher = build_robot(kb, None, action_timeout=5.0, settle_limit=0.0)

    @robot.handler("*")
    async def ok(d: Any) -> Any:
        from ippc.dispatch.actions import Status

        return Status.SUCCEEDED

    ports: dict[str, int] = {}
    answers: list[Any] = []
    stop = trio.Event()
    box: list[RunReport] = []

    async def serve() -> None:
        box.append(
            await dispatch_session(
                dispatcher,
                spec,
                server_config(rounds=1, timeout=timeout, db=db),
                planner_memory_mb=memory_mb,
                planner_grace=1.0,
                kb_port=0,
                on_kb_listening=lambda p: ports.__setitem__("kb", p),
                link=link,
                stop=stop,
            )
        )

    with trio.fail_after(240):
        async with trio.open_nursery() as nursery:
            nursery.start_soon(serve)
            while "kb" not in ports:
                await trio.sleep(0.01)
            async with connect(ports["kb"]) as client:
                for _ in range(1200):  # 240 s at most
                    if box or until(answers):
                        break
                    answers.append(
                        await client.call("kb.get", {"fluent": "robot-at", "args": ["r1", "hall"]})
                    )
                    await trio.sleep(0.2)
            stop.set()
    return box[0], answers


@pytest.mark.alone
def test_a_stuck_planner_is_stopped_at_its_budget_and_started_again(
    plugins: dict[str, str], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, logger="ippc.dispatch")

    def restarted(answers: list[Any]) -> bool:
        return any("starting it again" in r.getMessage() for r in caplog.records)

    report, answers = trio.run(
        lambda: robot_run(
            PlannerSpec("stuck"),
            tmp_path / "stuck.db",
            timeout=3.0,
            memory_mb=None,
            link=LinkPolicy(reconnect=True, silence=0.0),  # the guard's limit, not silence
            until=restarted,
        )
    )
    # ended by the guard at 3 s of budget + 1 s of grace, its reason recorded
    assert report.planner_error is not None
    assert re.fullmatch(
        r"planner stuck: still playing \d+\.\d s after session-init, past the session's "
        r"budget of 3 s plus 1 s grace; its process was stopped",
        report.planner_error,
    ), report.planner_error
    assert report.sessions[0] == "dropped" and report.turns == 0
    # the restart policy went on; the run then ended by its stop, cleanly
    assert report.planner_restarts >= 1 and report.interrupted == "stop"
    assert any(
        "planner stuck ended (planner stuck: still playing" in r.getMessage()
        for r in caplog.records
    )
    # the knowledge base's socket answered all along, and no planner's process is left
    assert len(answers) >= 5 and set(answers) == {True}
    assert guard_children() == []
    with ResultStore(tmp_path / "stuck.db") as store:
        first = store.sessions()[0]
        assert first["status"] == "dropped"


@pytest.mark.alone
def test_a_planner_over_its_memory_budget_is_killed_and_the_run_ends_clearly(
    plugins: dict[str, str], tmp_path: Path
) -> None:
    report, answers = trio.run(
        lambda: robot_run(
            PlannerSpec("hog"),
            tmp_path / "hog.db",
            timeout=60.0,
            memory_mb=BUDGET_MB,
            link=LinkPolicy(reconnect=False),
            until=lambda answers: False,
        )
    )
    assert report.planner_error is not None
    assert re.fullmatch(
        r"planner hog: out of memory: the planner's process held \d+ MB, over its budget "
        r"of 300 MB; killed",
        report.planner_error,
    ), report.planner_error
    # the run ended by itself (on-planner-loss exit), the session recorded as dropped
    assert report.session_status == "dropped" and report.sessions == ["dropped"]
    assert report.interrupted is None and report.turns == 0
    assert answers and set(answers) == {True}
    assert guard_children() == []


@pytest.mark.alone
def test_the_command_line_takes_a_memory_budget_and_says_why_the_planner_ended(
    plugins: dict[str, str], tmp_path: Path
) -> None:
    args = [str(DOMAIN), str(ONE), "--port", "0", "--planner", "hog", "--timeout", "60"]
    args += ["--memory-budget", "300", "--grace", "5", "--on-planner-loss", "exit", "-q"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 1, result.output
    assert re.search(
        r"planner: planner hog: out of memory: the planner's process held \d+ MB, over its "
        r"budget of 300 MB; killed\n",
        result.output,
    ), result.output
    assert result.output.endswith("rddl-dispatch: the session dropped\n")
    # the simulated world plays its planner in its own loop: no budget holds there
    result = CliRunner().invoke(
        main, [str(DOMAIN), str(ONE), "--simulate", "--memory-budget", "300"]
    )
    assert result.exit_code == 2
    assert "--memory-budget" in result.output and "simulated world" in result.output
