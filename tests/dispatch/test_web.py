"""rddl-dispatch's web page over real sockets on 127.0.0.1: the page and its event stream
while a robot plays (actions, facts, notes, the session), hostile text escaped, the
CLI's --web, and a headless Chromium that watches the turns advance."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import trio
from click.testing import CliRunner
from ippc.dispatch.actions import Dispatch, Result, Status
from ippc.dispatch.cli import main
from ippc.dispatch.run import PlannerSpec, build_robot, dispatch_session, server_config
from ippc.dispatch.web import web_task
from ippc.kb import KnowledgeBase, Update
from ippc.web import WebOptions

from ..chromium import console_errors, headless_chromium
from ..web.httpclient import events, fetch
from .conftest import DOMAIN, ONE

HOSTILE = "<img src=x onerror=alert(1)>"
ESCAPED = "&lt;img src=x onerror=alert(1)&gt;"


def rows_of(event: dict[str, Any], table: str) -> dict[str, dict[str, Any]]:
    return {r["key"]: r.get("cells", {}) for r in event.get("rows", []) if r["table"] == table}


@pytest.mark.trio
async def test_the_page_follows_a_robot_and_escapes_what_it_shows() -> None:
    kb = KnowledgeBase.from_files(DOMAIN, ONE)
    robot, dispatcher = build_robot(kb, None, action_timeout=10)
    failed_once: list[bool] = []
    go = trio.Event()

    async def act(d: Dispatch) -> Result:
        await go.wait()  # the first action waits until the viewer watches
        # the first runs over a flush of the page (0.25 s): seen running, then ended
        await trio.sleep(0.6 if d.id == 1 else 0.05)
        if d.action.name == "pickup" and not failed_once:
            failed_once.append(True)
            return Result(Status.FAILED, f"gripper says {HOSTILE}")
        return Result(Status.SUCCEEDED)

    async def wait(d: Dispatch) -> bool:
        # the sender turns up while the robot waits at the desk (a sensor would say so)
        kb.apply([Update("set", "present", ("office",), True)], f"desk {HOSTILE}")
        await trio.sleep(0.05)
        return True

    robot.handlers.register("*", act)
    robot.handlers.register("noop", wait)
    ports: list[int] = []
    seen: list[dict[str, Any]] = []
    stop = trio.Event()
    async with trio.open_nursery() as nursery:

        async def run() -> None:
            # serving goals: after the goal, the run (and its page) waits for the next
            report = await dispatch_session(
                dispatcher,
                PlannerSpec("exact"),
                server_config(rounds=2),
                robot=robot,
                serve_goals=True,
                stop=stop,
                web=web_task(WebOptions(port=0), ports.append, tick=0.1),
            )
            assert report.goals[0]["reached"] and report.interrupted == "stop"

        nursery.start_soon(run)
        with trio.fail_after(30):
            while not ports:
                await trio.sleep(0.01)
        port = ports[0]
        async with events(port, "/events") as stream:
            first = await stream.next()
            assert first["type"] == "rows" and first["reset"]
            assert rows_of(first, "facts")["robot-at(r1,hall)"]["value"] == "true"
            go.set()
            with trio.fail_after(60):
                while True:
                    event = await stream.next(timeout=60)
                    seen.append(event)
                    if "goal" in event.get("fields", {}) and event["fields"]["goal"].endswith(
                        ": holds"
                    ):
                        break
        page = await fetch(port, "/")
        raw = await fetch(port, "/snapshot.json")
        svg = await fetch(port, "/figure/rewards.svg")
        missing = await fetch(port, "/nothing")
        stop.set()
    # the actions: running, then how they ended, with the handler's message as text
    actions = [c for e in seen for c in rows_of(e, "actions").values()]
    assert {"action": "move(r1,hall,office)", "state": "running"}.items() <= actions[0].items()
    assert any(c.get("state") == "failed" and HOSTILE in c["message"] for c in actions)
    notes = [c for e in seen for c in rows_of(e, "notes").values()]
    assert [n["kind"] for n in notes] == ["failure", "replan"]
    assert HOSTILE in notes[0]["text"]
    # facts changed, marked, by whom
    facts = [(k, c) for e in seen for k, c in rows_of(e, "facts").items()]
    assert ("robot-at(r1,office)", "true", "dispatcher") in [
        (k, c["value"], c["source"]) for k, c in facts
    ]
    assert any(c["mark"] == "changed" for _, c in facts)
    assert any(c["source"] == f"desk {HOSTILE}" for _, c in facts)
    assert any(c["mark"] == "" for _, c in facts)  # a mark cleared when it got old
    sessions = [e["fields"]["session"] for e in seen if "session" in e.get("fields", {})]
    assert any(s.startswith("session 1: round 1, turn ") for s in sessions)
    turns = [e["fields"]["turns"] for e in seen if "turns" in e.get("fields", {})]
    assert turns == sorted(turns) and turns[-1] >= 5
    # every response escapes what it shows
    assert page.status == 200 and HOSTILE not in page.text and ESCAPED in page.text
    assert "robot-at(r1,lab)" in page.text
    assert raw.status == 200 and b"<" not in raw.body and b">" not in raw.body
    snap = raw.json()
    assert snap["stats"]["failed_actions"] == 1 and snap["goal"]["holds"] is True
    last = {f["key"]: f for f in snap["facts"]}
    assert last["robot-at(r1,lab)"]["changed"] is True  # moved there a turn ago
    assert last["robot-at(r1,office)"]["changed"] is False  # left turns ago
    assert any(f["source"] == f"desk {HOSTILE}" for f in snap["facts"])
    assert svg.status == 200 and svg.headers["content-type"] == "image/svg+xml"
    assert svg.text.startswith("<svg") and HOSTILE not in svg.text
    assert missing.status == 404 and HOSTILE not in missing.text


def test_the_cli_simulates_with_a_page() -> None:
    result = CliRunner().invoke(
        main, [str(DOMAIN), str(ONE), "--simulate", "--planner", "exact", "--web", "0", "-q"]
    )
    assert result.exit_code == 0, result.output
    assert result.output.startswith("web view on http://127.0.0.1:")
    assert "goal reached" in result.output


def test_a_taken_port_is_one_line() -> None:
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = CliRunner().invoke(
            main, [str(DOMAIN), str(ONE), "--simulate", "--web", str(port), "-q"]
        )
    assert result.exit_code == 1
    assert f"cannot listen on 127.0.0.1:{port} (the web page's socket, --web)" in result.output
    result = CliRunner().invoke(main, [str(DOMAIN), str(ONE), "--simulate", "--web-host", "::1"])
    assert result.exit_code == 2 and "needs --web PORT" in result.output


ROBOT = """
import trio

def setup(robot):
    @robot.handler("*")
    async def act(d):
        await trio.sleep(0.4)
        return True

    @robot.handler("noop")
    async def wait(d):
        await trio.sleep(0.4)
        return True
"""


@pytest.mark.alone  # a browser and a robot on the wall clock
def test_chromium_sees_the_turns_advance(tmp_path: Path) -> None:
    browser = headless_chromium()
    from selenium.webdriver.common.by import By

    robot = tmp_path / "robot.py"
    robot.write_text(ROBOT)
    cmd = [sys.executable, "-m", "ippc.dispatch.cli", str(DOMAIN), str(ONE), "--robot", str(robot)]
    cmd += ["--planner", "exact", "--port", "0", "--web", "0", "--rounds", "3", "-q"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith("web view on http://127.0.0.1:"), (line, proc.stderr)
        url = line.split(" on ", 1)[1].strip()
        browser.get(url)
        turns = browser.find_element(By.CSS_SELECTOR, '[data-page-field="turns"]')

        def count() -> int:
            text = turns.text.strip()
            return int(text) if text.isdigit() else -1

        deadline = time.monotonic() + 60
        first = count()
        while count() <= first:
            assert time.monotonic() < deadline, "the turn count did not advance in 60 s"
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.1)
        later = count()
        assert later > first >= 0
        # live.js applied the events (no reload): the actions table grew too
        rows = browser.find_elements(By.CSS_SELECTOR, 'tbody[data-table="actions"] tr')
        assert rows and int(browser.execute_script("return document.body.dataset.eventsSeen")) > 0
        assert browser.find_element(By.ID, "conn").text == "live"
        # nothing broke the page's Content-Security-Policy, no script error, no failed load
        assert console_errors(browser) == []
    finally:
        browser.quit()
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)


def test_the_counts_are_the_tables_rows_and_the_reports_figures() -> None:
    """Actions refused for a precondition are rows of the table too, and the page's
    counts are its rows: the planner's actions and those that did not succeed agree
    with the run's report, the noop dispatched on the turns where none ran apart."""
    from ippc.dispatch.live import DispatchLive
    from ippc.dispatch.run import build_simulation
    from ippc.dispatch.web import _fields, _rows

    kb = KnowledgeBase.from_files(DOMAIN, ONE)
    # the hall-office door is locked (the planner's task still has it open): every
    # move the planner sends there is refused, its precondition false
    kb.apply([Update("set", "CONNECTED", ("hall", "office"), False)], "setup")
    _, dispatcher = build_simulation(kb, 1)
    live = DispatchLive(dispatcher)
    report = trio.run(
        lambda: dispatch_session(dispatcher, PlannerSpec("exact"), server_config(rounds=1))
    )
    snap = live.snapshot()
    rows = dict(_rows(snap)["actions"])
    fields = _fields(snap)
    counts = snap["counts"]
    refused = [c for c in rows.values() if c["state"] == "precondition-false"]
    noops = [c for c in rows.values() if c["action"] == "noop()"]
    assert report.executed_total == len(refused) == counts["actions"] > 0
    assert report.failed_actions == counts["not_succeeded"] == len(refused)
    assert len(rows) == counts["actions"] + counts["noop"]
    assert len(noops) == counts["noop"] == report.turns  # (no action ran on any turn)
    assert all("move(?r, ?x, ?y) => (robot-at(?r, ?x)" in c["message"] for c in refused)
    assert fields["actions"] == f"{len(refused)} ({len(refused)} precondition-false)"
    assert fields["not-succeeded"] == len(refused)
    assert fields["reached"] == "not reached yet" and not report.goal_reached


ROBOT_HOLDS = """
import trio
from ippc.dispatch.actions import Result, Status
from ippc.kb import Update

def setup(robot):
    failed = []

    @robot.handler("*")
    async def act(d):
        await trio.sleep(0.1)
        if d.action.name == "pickup" and not failed:
            failed.append(d.action)
            return Result(Status.FAILED, "the gripper slipped")
        return True

    @robot.handler("noop")
    async def wait(d):
        if robot.kb.goal_holds():
            await trio.sleep(60)  # delivered: the page stays as it is while a test looks
        # the sender turns up while the robot waits (a sensor would say so)
        robot.kb.apply([Update("set", "present", ("office",), True)], "desk-sensor")
        await trio.sleep(0.1)
        return True
"""

ACTIONS_JS = """
const text = f => { const el = document.querySelector('[data-page-field="' + f + '"]');
                    return el ? el.textContent : null; };
const rows = [...document.querySelectorAll('tbody[data-table="actions"] tr')].map(tr => {
  const get = f => tr.querySelector('[data-field="' + f + '"]').textContent;
  return {action: get('action'), state: get('state'), turn: get('turn')};
});
return {rows: rows, actions: text('actions'), not_succeeded: text('not-succeeded'),
        noop: text('noop'), goal: text('goal'), reached: text('reached')};
"""


@pytest.mark.alone  # a browser and a robot on the wall clock
def test_chromium_sees_counts_that_agree_with_the_table_and_the_outcome(tmp_path: Path) -> None:
    """The robot delivers under --no-stop-at-goal, then its noop handler holds: in
    Chromium the page's counts are its table's rows, the goal is shown reached after
    the drop's turn, and the run's report (after SIGTERM) says the same."""
    browser = headless_chromium()
    from selenium.common.exceptions import WebDriverException

    robot = tmp_path / "robot.py"
    robot.write_text(ROBOT_HOLDS)
    cmd = [sys.executable, "-m", "ippc.dispatch.cli", str(DOMAIN), str(ONE), "--robot", str(robot)]
    cmd += ["--planner", "exact", "--port", "0", "--web", "0", "--no-stop-at-goal"]
    cmd += ["--action-timeout", "120"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith("web view on http://127.0.0.1:"), (line, proc.stderr)
        browser.get(line.split(" on ", 1)[1].strip())
        deadline = time.monotonic() + 90
        last = None
        while True:  # until delivered and the page settles (the noop that holds runs)
            assert time.monotonic() < deadline, f"the page did not settle: {last}"
            assert proc.poll() is None, proc.communicate()
            try:
                view = browser.execute_script(ACTIONS_JS)
            except WebDriverException:
                view = None
            if (
                view is not None
                and view["goal"] == "delivered: holds"
                and view["rows"]
                and view["rows"][0]["state"] == "running"
                and view["rows"][0]["action"] == "noop()"
                and view == last
            ):
                break
            last = view
            time.sleep(0.5)
        rows = view["rows"]  # newest first
        planner = [r for r in rows if r["action"] != "noop()"]
        noops = [r for r in rows if r["action"] == "noop()"]
        failed = [r for r in planner if r["state"] not in ("succeeded", "running")]
        assert [r["action"] for r in reversed(planner)] == [
            "move(r1,hall,office)",
            "pickup(r1)",
            "pickup(r1)",
            "move(r1,office,hall)",
            "move(r1,hall,lab)",
            "drop(r1)",
        ]
        assert view["actions"] == f"{len(planner)} (1 failed, {len(planner) - 1} succeeded)"
        assert view["not_succeeded"] == str(len(failed)) == "1"
        assert view["noop"] == (
            f"{len(noops)} noop dispatched on turns where no action ran (none sent, or refused)"
        )
        drop = next(r for r in rows if r["action"] == "drop(r1)")
        assert view["reached"] == f"goal reached (it held after turn {drop['turn']})"
        assert console_errors(browser) == []
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
        # the run's report: the same actions, the same failure, the goal reached
        assert "goal reached: " in out, (out, err)
        assert "1 failed action(s)" in out
    finally:
        browser.quit()
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
