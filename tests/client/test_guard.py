"""Budgets that hold whatever a planner does: `ippc.client.guard` on its own, and
rddl-client with a planner plug-in whose start-up never returns and one that allocates
without bound, against a real rddl-server whose session budget is 3 s."""

from __future__ import annotations

import re
import select
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from ippc.client.guard import default_memory_budget, memory_available_mb, run_guarded
from ippc.planners.base import find_planner
from ippc.server.store import ResultStore

from . import runaway
from .loopback import Server

CLIENT = Path(sys.executable).parent / "rddl-client"
BUDGET_MB = 300.0


@pytest.fixture
def plugins(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    return runaway.register(monkeypatch, tmp_path / "plugins")


def test_a_child_returns_its_value_and_its_messages(plugins: dict[str, str]) -> None:
    heard: list[Any] = []
    out = run_guarded(
        "ippc_runaway_planners:echo",
        [1, "two"],
        seconds=60,
        memory_mb=None,
        on_message=lambda m: heard.append(m),
    )
    assert (out.status, out.value, out.reason) == ("ok", {"got": [1, "two"]}, None)
    assert heard == [("note", [1, "two"])]
    assert out.peak_mb > 0


def test_a_child_that_raises_fails_with_its_words(plugins: dict[str, str]) -> None:
    out = run_guarded("ippc_runaway_planners:fail", "input", seconds=60, memory_mb=None)
    assert (out.status, out.reason) == ("failed", "ValueError: bad input")


def test_a_message_sets_the_limit_and_the_child_is_stopped_at_it(
    plugins: dict[str, str], tmp_path: Path
) -> None:
    # 600 s at first; the child's message says 1 s from then
    out = run_guarded(
        "ippc_runaway_planners:wait_forever",
        1.0,
        seconds=600,
        memory_mb=None,
        on_message=lambda m: m[1] if m[0] == "budget" else None,
        log_path=tmp_path / "child.log",
    )
    assert out.status == "timeout"
    assert re.fullmatch(r"still running after \d+\.\d s, past its time limit; stopped", out.reason)
    assert out.seconds < 600


def test_a_child_over_its_memory_budget_is_killed(plugins: dict[str, str]) -> None:
    out = run_guarded("ippc_runaway_planners:allocate", None, seconds=120, memory_mb=BUDGET_MB)
    assert out.status == "memory"
    assert re.fullmatch(
        r"out of memory: the planner's process held \d+ MB, over its budget of 300 MB; killed",
        out.reason,
    )
    assert BUDGET_MB < out.peak_mb < 4096


def test_a_cancel_stops_the_child(plugins: dict[str, str]) -> None:
    import threading

    cancel = threading.Event()
    cancel.set()
    # a child that would run on (time.sleep would fail at once: it takes no `send`)
    out = run_guarded(
        "ippc_runaway_planners:wait_forever", None, seconds=60, memory_mb=None, cancel=cancel
    )
    assert out.status == "interrupted"


def test_the_default_budget_is_a_share_of_the_memory_available() -> None:
    avail = memory_available_mb()
    assert avail is not None and avail > 0
    budget = default_memory_budget(4)
    assert budget is not None and 0 < budget <= 0.8 * avail / 4 * 1.1


def test_the_plugins_are_registered(plugins: dict[str, str]) -> None:
    assert find_planner("stuck").name == "stuck" and find_planner("hog").name == "hog"


# ----------------------------------------------------------------- rddl-client


def client(port: int, env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [
            str(CLIENT),
            "--port",
            str(port),
            "--instance",
            "corridor_enum_inst_1",
            "--timeout",
            "600",
            "-q",
            *args,
        ],
        capture_output=True,
        text=True,
        timeout=120,  # the client's own limits end it long before
        env=env,
    )


@pytest.mark.alone
def test_rddl_client_stops_a_planner_whose_start_up_never_returns(
    budget_server: Server, plugins: dict[str, str]
) -> None:
    port, db = budget_server.port, budget_server.db
    done = client(port, plugins, "--planner", "stuck", "--grace", "1")
    assert done.returncode == 1, done.stderr
    assert re.fullmatch(
        r"Error: planner stuck: still playing \d+\.\d s after session-init, past the "
        r"session's budget of 3 s plus 1 s grace; its process was stopped\n",
        done.stderr,
    ), done.stderr
    # the server goes on: the next client plays its session
    done = client(port, plugins, "--planner", "noop", "--name", "after")
    assert done.returncode == 0, done.stderr
    assert "total reward -30.0000  mean round reward -15.0000" in done.stdout, done.stdout
    with ResultStore(db) as store:
        assert [s["status"] for s in store.sessions() if s["client_name"] == "after"] == [
            "finished"
        ]


@pytest.mark.alone
def test_rddl_client_kills_a_planner_over_its_memory_budget(
    budget_server: Server, plugins: dict[str, str]
) -> None:
    port = budget_server.port
    done = client(port, plugins, "--planner", "hog", "--memory-budget", "300")
    assert done.returncode == 1, done.stderr
    assert re.fullmatch(
        r"Error: planner hog: out of memory: the planner's process held \d+ MB, over its "
        r"budget of 300 MB; killed\n",
        done.stderr,
    ), done.stderr


@pytest.mark.alone
def test_rddl_client_gives_a_planner_that_sizes_its_memory_its_share(
    budget_server: Server, plugins: dict[str, str]
) -> None:
    port = budget_server.port
    done = subprocess.run(
        [
            str(CLIENT),
            "--port",
            str(port),
            "--instance",
            "corridor_enum_inst_1",
            "--planner",
            "mcts",
            "--planner-option",
            "iterations=2",
            "--memory-budget",
            "400",
        ],
        capture_output=True,
        text=True,
        timeout=120,
        env=plugins,
    )
    # 75% of 400 MB through mcts's option `memory` (whatever the 3 s session's end)
    assert "memory budget 300 MiB (option memory)" in done.stderr, done.stderr


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"  # a zombie is gone
    except OSError:
        return False


def test_a_child_whose_caller_is_killed_ends_itself(plugins: dict[str, str]) -> None:
    caller = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "from ippc.client.guard import run_guarded\n"
            "run_guarded('ippc_runaway_planners:report_pid', None, seconds=600, memory_mb=None,"
            " on_message=lambda m: print(m[1], flush=True))\n",
        ],
        stdout=subprocess.PIPE,
        text=True,
        env=plugins,
    )
    try:
        assert caller.stdout is not None
        ready, _, _ = select.select([caller.stdout], [], [], 60)
        assert ready, "the child never said its pid"
        child = int(caller.stdout.readline())
        assert _alive(child)
        caller.send_signal(signal.SIGKILL)  # the caller cannot stop anything now
        caller.wait(10)
        deadline = time.monotonic() + 30
        while _alive(child):
            assert time.monotonic() < deadline, "the orphan is still running"
            time.sleep(0.1)
    finally:
        if caller.poll() is None:
            caller.kill()
            caller.wait(10)
