"""A robot on the wall clock (handlers and sensors in Python): a sensor that
contradicts an action's expected effect, and a handler that hangs."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
import trio
from ippc.dispatch.actions import Dispatch, Status
from ippc.dispatch.config import SensingConfig
from ippc.dispatch.run import PlannerSpec, build_robot, dispatch_session, server_config
from ippc.kb import KnowledgeBase
from ippc.server.store import ResultStore

from .conftest import DOMAIN, ONE

ROOMS = ("hall", "office", "lab")
SENSING = {
    "rate": 50,
    "sensors": {
        "robot-at": {"stream": "odometry", "params": ["r1", "*"], "value": "msg.at"},
        "present": {"stream": "camera", "params": ["*"], "value": "msg.seen"},
    },
}


def run_robot(db: Path, *, lie_once: bool = False, hang_once: bool = False):  # type: ignore[no-untyped-def]
    kb = KnowledgeBase.from_files(DOMAIN, ONE)
    robot, dispatcher = build_robot(
        kb, SensingConfig.from_dict(SENSING, kb.model), action_timeout=0.5, settle_limit=0.5
    )
    assert robot.sensing is not None
    odometry = robot.sensing.publisher("odometry")
    where = {"room": "hall"}
    once = {"done": False}

    @robot.handler("move")
    async def move(d: Dispatch) -> Status:
        first, once["done"] = not once["done"], True
        if hang_once and first:
            await trio.sleep_forever()
        await trio.sleep(0.01)  # driving
        if not (lie_once and first):  # the lie: it reports success but never left
            where["room"] = d.params["r2"]
        odometry({"at": {r: r == where["room"] for r in ROOMS}})
        return Status.SUCCEEDED

    @robot.handler("pickup")
    @robot.handler("drop")
    async def hand(d: Dispatch) -> bool:
        return True

    async def camera() -> None:
        robot.sensing.feed("camera", {"seen": {"office": True}})  # type: ignore[union-attr]
        await trio.sleep_forever()

    async def broken_sensor() -> None:
        raise OSError("lidar unplugged")  # logged; the dispatcher goes on

    robot.start_soon(camera)
    robot.start_soon(broken_sensor)
    config = server_config(rounds=2, db=db)

    async def bounded():  # type: ignore[no-untyped-def]
        # a run takes about a second; a broken action timeout must fail the test, not hang it
        with trio.fail_after(60):
            return await dispatch_session(
                dispatcher,
                PlannerSpec("exact"),
                config,
                sensing_task=True,
                robot=robot,
                planner_timeout=60.0,
            )

    report = trio.run(bounded)
    return report, kb


def test_a_sensor_that_contradicts_the_expected_effect_wins(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    with caplog.at_level(logging.WARNING, logger="ippc.dispatch.dispatcher"):
        report, kb = run_robot(tmp_path / "r.db", lie_once=True)
    # a WARNING (not INFO, silent under -q) with what was sensed and what the model allowed
    (line,) = [r.getMessage() for r in caplog.records if "contradicts the model" in r.getMessage()]
    assert line == (
        "turn 1: sensing contradicts the model after move(r1,hall,office): sensed "
        "robot-at(r1, hall) = true, robot-at(r1, office) = false; the model allowed "
        "robot-at(r1, hall) = false, robot-at(r1, office) = true"
    )
    assert report.goal_reached and report.session_status == "finished"
    actions = [(e["action"], e["outcome"]) for e in report.executed]
    # the first move "succeeded" but the odometry kept the robot in the hall:
    # the next turn is planned from there and the move is tried again
    assert actions[:2] == [("move(r1,hall,office)", "succeeded")] * 2
    assert actions[-1] == ("drop(r1)", "succeeded") and len(actions) == 6
    assert report.contradictions == 2
    assert kb.get("robot-at", ("r1", "lab")) is True and kb.get("delivered") is True
    with ResultStore(tmp_path / "r.db") as store:
        (session,) = store.sessions()
        first = store.steps(store.rounds(session["id"])[0]["id"])[0]
    assert sorted(
        (c["fluent"], tuple(c["args"]), c["expected"], c["sensed"])
        for c in first["outcome"]["contradictions"]
    ) == [("robot-at", ("r1", "hall"), False, True), ("robot-at", ("r1", "office"), True, False)]


def test_a_hanging_handler_fails_its_action_and_the_loop_goes_on(tmp_path: Path) -> None:
    report, kb = run_robot(tmp_path / "h.db", hang_once=True)
    assert report.goal_reached
    first = report.executed[0]
    assert (first["action"], first["outcome"]) == ("move(r1,hall,office)", "timed-out")
    assert first["message"] == (
        "the handler of move(r1,hall,office) did not answer within 0.5 s (timeout)"
    )
    assert first["seconds"] == pytest.approx(0.5, abs=0.3)
    assert report.failed_actions == 1 and report.replans == 1
    assert kb.get("robot-at", ("r1", "hall")) is False and kb.get("delivered") is True
