"""Issue 27 over rddl-kb's socket (real sockets on 127.0.0.1, every wait
bounded): a refused batch names its update and reason, not internal-error;
goals at run time reach every subscriber; snapshot and restore."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

import pytest
import trio
from ippc.kb import KnowledgeBase
from ippc.kb.jsonl import JsonlServer, RequestError, connect
from ippc.kb.service import register_kb

from .test_jsonl import running

TIMEOUT = 10
DISPATCH_DATA = Path(__file__).resolve().parents[1] / "data" / "dispatch"
SENSORS = DISPATCH_DATA / "courier_sensors.rddl"


@asynccontextmanager
async def serving(kb: KnowledgeBase) -> AsyncIterator[int]:
    server = JsonlServer("kb")
    register_kb(server, kb)
    async with running(server) as port:
        yield port


@pytest.fixture
def kb() -> KnowledgeBase:
    return KnowledgeBase.from_files(SENSORS, SENSORS)


def update(op: str, fluent: str, args: list[str], value: object = None) -> dict[str, object]:
    out: dict[str, object] = {"op": op, "fluent": fluent, "args": args}
    if value is not None:
        out["value"] = value
    return out


@pytest.mark.trio
async def test_a_refused_batch_names_the_update_and_the_reason(kb: KnowledgeBase) -> None:
    with trio.fail_after(TIMEOUT):
        async with serving(kb) as port, connect(port) as client, connect(port) as watcher:
            await watcher.call("kb.subscribe")
            for updates, code, says in (
                (  # the batch: battery was written, the error was internal-error
                    [update("set", "battery", ["r1"], 50.0), update("set", "floor", ["r1"], 1e20)],
                    "out-of-range",
                    "kb.apply: update 2 (set floor(r1) = 1e+20): 'floor' (int) takes a 64-bit integer",
                ),
                (
                    [
                        update("set", "battery", ["r1"], 50.0),
                        update("add", "robot-at", ["r1", "lab"]),
                    ],
                    "invariant",
                    "kb.apply: the batch would break the state invariant at ",
                ),
                (
                    [
                        update("set", "battery", ["r1"], 50.0),
                        update("set", "battery", ["r2"], "nan"),
                    ],
                    "bad-value",
                    "kb.apply: update 2 (set battery(r2) = 'nan'): 'battery' (real) takes a number",
                ),
            ):
                with pytest.raises(RequestError) as err:
                    await client.call("kb.apply", {"updates": updates})
                assert err.value.code == code
                assert str(err.value).startswith(says), str(err.value)
            assert await client.call("kb.get", {"fluent": "battery", "args": ["r1"]}) == 100.0
            # nobody was told of anything: the next event is the next good batch
            await client.call("kb.apply", {"updates": [update("set", "battery", ["r1"], 42.0)]})
            event = await watcher.next_event()
            assert event["event"] == "kb.changed"
            assert event["changes"] == [
                {"fluent": "battery", "args": ["r1"], "old": 100.0, "new": 42.0}
            ]


@pytest.mark.trio
async def test_goals_at_run_time_over_the_socket(kb: KnowledgeBase) -> None:
    with trio.fail_after(TIMEOUT):
        async with serving(kb) as port, connect(port) as client, connect(port) as watcher:
            await watcher.call("kb.subscribe", {"fluents": ["holding"]})
            assert (await client.call("kb.goal"))["facts"] == [
                {"fluent": "delivered", "args": [], "value": True}
            ]
            goal = await client.call(
                "kb.set_goal",
                {
                    "goals": ["holding(r1)", {"fluent": "robot-at", "args": ["r2", "hall"]}],
                    "source": "ctl",
                },
            )
            assert goal["source"] == "runtime" and goal["version"] == 1
            assert goal["formula"] == "holding(r1) ^ robot-at(r2, hall)"
            event = await watcher.next_event()
            assert event == {"event": "kb.goal_changed", "source": "ctl", "goal": goal}
            assert await client.call("kb.goal_holds") is False
            with pytest.raises(RequestError) as err:
                await client.call("kb.remove_goal", {"goals": ["holding(r2)"]})
            assert err.value.code == "not-in-goal"
            with pytest.raises(RequestError) as err:
                await client.call("kb.add_goal", {"goals": ["holding(r9)"]})
            assert err.value.code == "unknown-object" and "goal fact 1 (holding(r9))" in str(
                err.value
            )
            with pytest.raises(RequestError) as err:
                await client.call("kb.set_goal", {"goals": [3]})
            assert err.value.code == "bad-params"
            goal = await client.call("kb.remove_goal", {"goals": ["robot-at(r2, hall)"]})
            assert goal["facts"] == [{"fluent": "holding", "args": ["r1"], "value": True}]
            assert (await watcher.next_event())["goal"] == goal  # no event for the refusals
            await client.call("kb.apply", {"updates": [update("add", "holding", ["r1"])]})
            assert (await watcher.next_event())["event"] == "kb.changed"
            assert await client.call("kb.goal_holds") is True
            reset = await client.call("kb.reset_goal", {"source": "ctl"})
            assert reset["source"] == "cpf" and reset["version"] == 3
            assert (await watcher.next_event())["goal"] == reset
            # a subscription without goal events
            await watcher.call("kb.subscribe", {"goal": False})
            await client.call("kb.set_goal", {"goals": []})
            assert await client.call("kb.goal") is None
            await client.call("kb.apply", {"updates": [update("remove", "holding", ["r1"])]})
            assert (await watcher.next_event())["event"] == "kb.changed"


@pytest.mark.trio
async def test_snapshot_and_restore_over_the_socket(kb: KnowledgeBase) -> None:
    other = KnowledgeBase.from_files(SENSORS, SENSORS)
    with trio.fail_after(TIMEOUT):
        async with serving(kb) as port, serving(other) as port2:
            async with connect(port) as a, connect(port2) as b:
                await a.call(
                    "kb.apply",
                    {
                        "updates": [
                            update("remove", "robot-at", ["r1", "hall"]),
                            update("add", "robot-at", ["r1", "office"]),
                            update("set", "floor", ["r2"], 3),
                        ]
                    },
                )
                await a.call("kb.set_goal", {"goals": ["holding(r2)"]})
                saved = await a.call("kb.snapshot")
                with pytest.raises(RequestError) as err:
                    await b.call(
                        "kb.restore",
                        {
                            "facts": [
                                {"fluent": "robot-at", "args": ["r2", "office"], "value": True}
                            ]
                        },
                    )
                assert err.value.code == "invariant"
                reply = await b.call("kb.restore", saved)
                assert len(reply["changes"]) == 3
                assert await b.call("kb.snapshot") == saved
