"""A controller over the JSON-lines socket: remote handlers and sensors, and
bad requests that must not end anything."""

from __future__ import annotations

from typing import Any

import pytest
import trio
from ippc.dispatch.config import SensingConfig
from ippc.dispatch.run import (
    PlannerSpec,
    RunReport,
    build_robot,
    dispatch_session,
    run_planner,
    server_config,
)
from ippc.kb import KnowledgeBase
from ippc.kb.jsonl import JsonlClient, RequestError, connect

from .conftest import DOMAIN, ONE
from .test_robot import ROOMS, SENSING


async def play(controller: Any, *, action_timeout: float = 2.0) -> RunReport:
    """Serve a dispatcher with the socket on, let `controller(client)` set
    itself up, then start the exact planner; the report."""
    kb = KnowledgeBase.from_files(DOMAIN, ONE)
    _, dispatcher = build_robot(
        kb,
        SensingConfig.from_dict(SENSING, kb.model),
        action_timeout=action_timeout,
        settle_limit=0.5,
    )
    ports: dict[str, int] = {}
    ready = trio.Event()
    reports: list[RunReport] = []

    async def dispatcher_side() -> None:
        reports.append(
            await dispatch_session(
                dispatcher,
                None,
                server_config(rounds=2),
                sensing_task=True,
                kb_port=0,
                on_listening=lambda p: ports.__setitem__("ippc", p),
                on_kb_listening=lambda p: ports.__setitem__("kb", p),
            )
        )

    with trio.fail_after(60):
        async with trio.open_nursery() as nursery:
            nursery.start_soon(dispatcher_side)
            while "ippc" not in ports:
                await trio.sleep(0.01)
            async with connect(ports["kb"]) as client:
                nursery.start_soon(controller, client, ready)
                await ready.wait()
                error = await run_planner(
                    PlannerSpec("exact"), "127.0.0.1", ports["ippc"], "courier_one"
                )
                assert error is None
                while not reports:
                    await trio.sleep(0.01)
                nursery.cancel_scope.cancel()
    return reports[0]


def robot_controller(*, ignore_first: bool = False, bad_requests: bool = False) -> Any:
    async def controller(client: JsonlClient, ready: trio.Event) -> None:
        where = "hall"

        async def odometry() -> None:
            await client.call(
                "sensing.publish",
                {"stream": "odometry", "msg": {"at": {r: r == where for r in ROOMS}}},
            )

        if bad_requests:
            await client.send_line(b"this is not json\n")
            await client.send_line(b'{"id": "x", "method": "no.such.method"}\n')
            replies = [await client.next_event(), await client.next_event()]
            assert [(r["id"], r["error"]["code"]) for r in replies] == [
                (None, "parse-error"),
                ("x", "unknown-method"),
            ]
            for method, params, code in [
                ("sensing.publish", {"stream": "lidar", "msg": {}}, "unknown-stream"),
                ("sensing.publish", {"stream": "odometry"}, "bad-params"),
                ("handlers.register", {"actions": ["fly"]}, "bad-params"),
                ("handlers.result", {"id": 999, "outcome": "succeeded"}, "unknown-dispatch"),
                ("handlers.result", {"id": 1, "outcome": "maybe"}, "bad-params"),
                ("kb.get", {"fluent": "nope"}, None),
            ]:
                with pytest.raises(RequestError) as info:
                    await client.call(method, params)
                if code is not None:
                    assert info.value.code == code, (method, info.value)
        assert await client.call("handlers.register", {"actions": ["move", "pickup", "drop"]}) == {
            "registered": ["drop", "move", "pickup"]
        }
        assert await client.call("sensing.streams") == ["camera", "odometry"]
        changed = await client.call(
            "sensing.publish", {"stream": "camera", "msg": {"seen": {"office": True}}}
        )
        assert changed == {
            "changed": 1,
            "accepted": [{"fluent": "present", "args": ["office"], "value": True}],
            "refused": [],
        }
        # odometry that puts the robot in two rooms: the knowledge base refuses it
        both = await client.call(
            "sensing.publish",
            {"stream": "odometry", "msg": {"at": {"hall": True, "office": True, "lab": False}}},
        )
        assert both["changed"] == 0 and both["accepted"] == []
        # (the message's batch is refused whole)
        assert sorted((r["fluent"], r["args"][1], r["value"]) for r in both["refused"]) == [
            ("robot-at", "hall", True),
            ("robot-at", "lab", False),
            ("robot-at", "office", True),
        ]
        assert "state invariant" in both["refused"][0]["reason"]
        # a value the sensor cannot use: refused by the sensor
        bad = await client.call("sensing.publish", {"stream": "camera", "msg": {"seen": 3}})
        assert bad["changed"] == 0 and bad["refused"][0]["fluent"] == "present"
        ready.set()
        ignored = False
        while True:
            try:
                event = await client.next_event()
            except trio.EndOfChannel:
                return  # the dispatcher is done: its socket closed
            if event.get("event") != "dispatch.action":
                continue
            if ignore_first and not ignored:
                ignored = True  # never answered: the dispatch times out
                continue
            if event["action"] == "move":
                assert event["params"]["r2"] == event["args"][2]
                where = event["args"][2]
                await odometry()
            await client.call(
                "handlers.result", {"id": event["id"], "outcome": "succeeded", "cost": 1.5}
            )

    return controller


@pytest.mark.trio
async def test_a_remote_controller_handles_actions_and_senses() -> None:
    report = await play(robot_controller(bad_requests=True))
    assert report.goal_reached
    assert [e["action"] for e in report.executed] == [
        "move(r1,hall,office)",
        "pickup(r1)",
        "move(r1,office,hall)",
        "move(r1,hall,lab)",
        "drop(r1)",
    ]
    assert all(e["outcome"] == "succeeded" and e["cost"] == 1.5 for e in report.executed)
    assert report.cost == 7.5


@pytest.mark.trio
async def test_a_remote_handler_that_never_answers_times_out() -> None:
    report = await play(robot_controller(ignore_first=True), action_timeout=0.3)
    assert report.goal_reached
    first = report.executed[0]
    assert first["outcome"] == "timed-out" and "(timeout)" in first["message"]
    assert report.failed_actions == 1


@pytest.mark.trio
async def test_a_closed_connection_fails_its_dispatches_at_once() -> None:
    async def leaves(client: JsonlClient, ready: trio.Event) -> None:
        await client.call(
            "sensing.publish", {"stream": "camera", "msg": {"seen": {"office": True}}}
        )
        # a second, raw connection registers, takes one dispatch and hangs up
        port = client.stream.socket.getpeername()[1]
        raw = await trio.open_tcp_stream("127.0.0.1", port)
        await raw.send_all(
            b'{"id": 1, "method": "handlers.register", "params": {"actions": ["*"]}}\n'
        )
        seen = b""
        while b'"registered"' not in seen:
            seen += await raw.receive_some(65536)
        ready.set()
        while b"dispatch.action" not in seen:
            seen += await raw.receive_some(65536)
        await raw.aclose()  # gone, mid-dispatch

    report = await play(leaves, action_timeout=30.0)
    # the first dispatch failed at once (not after 30 s); the actions after it
    # found no handler; the session ran its rounds to their horizon
    first = report.executed[0]
    assert first["outcome"] == "failed" and "connection" in first["message"]
    assert first["seconds"] < 5.0
    assert "no handler for action" in report.executed[1]["message"]
    assert not report.goal_reached and report.rounds == 2
