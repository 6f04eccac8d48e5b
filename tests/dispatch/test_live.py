"""The dispatcher's live model (dispatch.live), without HTTP: a simulated run with an
injected failure, its snapshot and events against the run's report."""

from __future__ import annotations

import json
import threading
from typing import Any

import pytest
import trio
from ippc.dispatch.actions import Dispatch
from ippc.dispatch.live import DispatchLive
from ippc.dispatch.run import PlannerSpec, build_simulation, dispatch_session, server_config
from ippc.dispatch.world import SimulatedWorld
from ippc.kb import KnowledgeBase, Update

from .conftest import DOMAIN, ONE


class Recorder:
    def __init__(self) -> None:
        self.events: list[dict[str, Any]] = []

    def __call__(self, event: dict[str, Any]) -> None:
        json.dumps(event)  # every event is JSON-able
        self.events.append(event)

    def of(self, kind: str) -> list[dict[str, Any]]:
        return [e for e in self.events if e["type"] == kind]


def fail_first_pickup(d: Dispatch, world: SimulatedWorld) -> bool:
    return d.action.name == "pickup" and world.steps == 1


def test_a_simulated_run_seen_live() -> None:
    kb = KnowledgeBase.from_files(DOMAIN, ONE)
    world, dispatcher = build_simulation(kb, 1, failures=fail_first_pickup)
    live = DispatchLive(dispatcher)
    rec = Recorder()
    live.subscribe(rec)
    first = live.snapshot()
    json.dumps(first)
    assert first["session"]["state"] == "waiting"
    assert [f["key"] for f in first["facts"] if f["fluent"] == "robot-at"] == ["robot-at(r1,hall)"]
    assert not any(f["changed"] for f in first["facts"])
    assert first["goal"]["holds"] is False

    report = trio.run(
        lambda: dispatch_session(
            dispatcher, PlannerSpec("exact"), server_config(rounds=1), planner_in_loop=True
        )
    )
    assert report.goal_reached and report.turns == 6 and report.replans == 1
    snap = live.snapshot()
    json.dumps(snap)
    # the session, the turns and their rewards, as the report has them
    assert snap["session"]["state"] == "closed" and snap["session"]["sessions"] == 1
    assert [t["turn"] for t in snap["turns"]] == [1, 2, 3, 4, 5, 6]
    assert snap["stats"]["reward"] == report.dispatcher_reward
    assert sum(t["reward"] for t in snap["turns"]) == pytest.approx(report.dispatcher_reward)
    assert snap["stats"]["replans"] == 1 and snap["stats"]["failed_actions"] == 1
    assert [(a["action"], a["status"]) for a in snap["ended"]] == [
        (e["action"], e["outcome"]) for e in report.executed
    ]
    assert snap["running"] == []
    # the failure and the replan after it are notes
    kinds = [(n["kind"], n["turn"]) for n in snap["notes"]]
    assert kinds == [("failure", 2), ("replan", 3)]
    assert "pickup(r1) failed: injected failure" in snap["notes"][0]["text"]
    # the facts as the knowledge base holds them, changed ones with their source
    facts = {f["key"]: f for f in snap["facts"]}
    assert facts["robot-at(r1,lab)"]["value"] is True
    assert facts["robot-at(r1,hall)"]["value"] is False  # changed: shown though false
    assert facts["robot-at(r1,lab)"]["source"] == "dispatcher"
    assert facts["robot-at(r1,lab)"]["changed"] is True  # moved in the last turns
    assert facts["robot-at(r1,hall)"]["changed"] is True  # left in turn 5 of 6
    assert facts["robot-at(r1,office)"]["value"] is False
    assert facts["robot-at(r1,office)"]["changed"] is False  # left in turn 4: two turns ago
    assert snap["goal"]["holds"] is True
    for key, fact in facts.items():
        assert kb.get(fact["fluent"], fact["args"]) == fact["value"], key
    # the events tell it as it happened
    types = [e["type"] for e in rec.events]
    assert types.index("session") < types.index("turn-sent") < types.index("action")
    actions = rec.of("action")
    assert [a["action"]["status"] for a in actions[:2]] == ["running", "succeeded"]
    assert actions[0]["action"]["action"] == "move(r1,hall,office)"
    assert len(rec.of("turn")) == 6
    assert rec.of("goal")[-1]["goal"]["holds"] is True
    fact_events = [f["key"] for e in rec.of("facts") for f in e["facts"]]
    assert "robot-at(r1,office)" in fact_events
    seqs = [e["seq"] for e in rec.events]
    assert seqs == sorted(seqs) and snap["seq"] == seqs[-1]
    live.close()


def test_changes_from_another_thread_and_a_goal_set_at_run_time() -> None:
    kb = KnowledgeBase.from_files(DOMAIN, ONE)
    _, dispatcher = build_simulation(kb, 1)
    live = DispatchLive(dispatcher)
    rec = Recorder()
    live.subscribe(rec)

    def robot_driver() -> None:  # a driver thread writes the knowledge base
        kb.apply(
            [
                Update("set", "robot-at", ("r1", "hall"), False),
                Update("set", "robot-at", ("r1", "office"), True),
            ],
            "driver",
        )

    t = threading.Thread(target=robot_driver)
    t.start()
    t.join()
    kb.set_goal("robot-at(r1,lab)")
    snap = live.snapshot()
    facts = {f["key"]: f for f in snap["facts"]}
    assert facts["robot-at(r1,office)"]["source"] == "driver"
    assert facts["robot-at(r1,office)"]["changed"] is True  # no turn yet: changed since the start
    assert [e["source"] for e in rec.of("facts")] == ["driver"]
    assert {f["key"]: f["value"] for f in rec.of("facts")[0]["facts"]} == {
        "robot-at(r1,hall)": False,
        "robot-at(r1,office)": True,
    }
    assert snap["goal"]["facts"] == ["robot-at(r1, lab)"]
    assert snap["goal"]["holds"] is False and rec.of("goal")[-1]["source"] == "api"
    live.close()
    kb.apply(
        [
            Update("set", "robot-at", ("r1", "office"), False),
            Update("set", "robot-at", ("r1", "lab"), True),
        ],
        "driver",
    )
    assert len(rec.of("facts")) == 1  # closed: no longer listening


def test_sensing_counts_are_told_on_tick_when_they_move() -> None:
    kb = KnowledgeBase.from_files(DOMAIN, ONE)
    world, dispatcher = build_simulation(kb, 1)
    live = DispatchLive(dispatcher)
    rec = Recorder()
    live.subscribe(rec)
    live.tick()
    live.tick()
    assert len(rec.of("sensing")) == 1  # told once: nothing moved in between
    sensing = dispatcher.sensing
    assert sensing is not None
    stream = sorted(sensing.streams())[0]
    sensing.feed(stream, {"nonsense": True})
    live.tick()
    (first, second) = rec.of("sensing")
    assert second["sensing"]["messages"] == first["sensing"]["messages"] + 1
    assert second["sensing"]["refused"].get(stream) == 1
    assert second["sensing"]["errors"]


def test_a_listener_that_fails_never_stops_the_dispatcher() -> None:
    kb = KnowledgeBase.from_files(DOMAIN, ONE)
    _, dispatcher = build_simulation(kb, 1)
    live = DispatchLive(dispatcher)

    def broken(event: dict[str, Any]) -> None:
        raise RuntimeError("boom")

    live.subscribe(broken)
    report = trio.run(
        lambda: dispatch_session(
            dispatcher, PlannerSpec("exact"), server_config(rounds=1), planner_in_loop=True
        )
    )
    assert report.goal_reached and live.snapshot()["stats"]["turns"] == report.turns
