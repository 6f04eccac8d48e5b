"""The simulated world's hooks for experiments: a forced world (exogenous),
local sensors (observe), durations that read how the step went."""

from __future__ import annotations

import numpy as np
import trio
from ippc.dispatch.actions import GroundAction, Status
from ippc.dispatch.run import PlannerSpec, build_simulation, dispatch_session, server_config
from ippc.dispatch.world import SimulatedWorld
from ippc.kb import KnowledgeBase
from ippc.rddl.simulator import State

from .conftest import DOMAIN, ONE

OFFICE = 1  # index of office among the rooms (hall, office, lab)


def run(**world: object):  # type: ignore[no-untyped-def]
    kb = KnowledgeBase.from_files(DOMAIN, ONE)
    the_world, dispatcher = build_simulation(kb, 1, **world)  # type: ignore[arg-type]
    report = trio.run(
        lambda: dispatch_session(dispatcher, PlannerSpec("exact"), server_config(rounds=1))
    )
    return report, the_world, dispatcher, kb


def test_an_exogenous_hook_forces_the_true_state() -> None:
    seen: list[tuple[bool, int]] = []

    def nobody_at_the_desk(
        world: SimulatedWorld, before: State | None, after: State, actions: list[GroundAction]
    ) -> State:
        seen.append((before is None, len(actions)))
        after.values["present"][0, OFFICE] = False
        return after

    report, world, _, kb = run(exogenous=nobody_at_the_desk)
    assert seen[0] == (True, 0)  # the initial state first
    assert len(seen) == world.steps + 1
    assert not report.goal_reached and report.turns == 12
    assert world.value("present", ("office",)) is False and world.value("holding", ("r1",)) is False
    assert kb.get("present", ("office",)) is False
    pickups = [e for e in report.executed if e["action"] == "pickup(r1)"]
    assert all(e["outcome"] != "succeeded" for e in pickups)


def test_observe_reports_every_step_even_unchanged_values() -> None:
    def always_there(world, before, after, actions):  # type: ignore[no-untyped-def]
        after.values["present"][0, OFFICE] = True
        return after

    calls: list[int] = []
    last: dict[str, bool] = {}

    def local_camera(world: SimulatedWorld, state: State) -> dict[str, dict[tuple[str, ...], bool]]:
        calls.append(world.steps)
        where = int(np.argmax(state.values["robot-at"][0, 0]))
        room = ("hall", "office", "lab")[where]
        last[room] = bool(state.values["present"][0, where])
        return {"present": {(room,): bool(state.values["present"][0, where])}}

    report, world, dispatcher, kb = run(exogenous=always_there, observe=local_camera)
    assert report.goal_reached
    assert calls == list(range(world.steps + 1))  # the initial state, then every step
    assert dispatcher.sensing is not None and dispatcher.sensing.messages == world.steps + 1
    # the knowledge base holds what the camera last saw in each room, nothing else
    assert last["office"] is True
    for room in ("hall", "office", "lab"):
        assert kb.get("present", (room,)) is last.get(room, False)


def test_durations_read_the_step_they_follow() -> None:
    def seconds(action: GroundAction, world: SimulatedWorld) -> float:
        assert world.previous_state is not None
        if action.name == "noop":
            return 60.0
        return 20.0 if world.outcomes[action] is Status.SUCCEEDED else 75.0

    def fail_first_pickup(d, world):  # type: ignore[no-untyped-def]
        return d.action.name == "pickup" and world.steps == 1

    report, world, _, _ = run(durations=seconds, failures=fail_first_pickup)
    assert report.goal_reached
    by = [(e["action"], e["outcome"], e["seconds"]) for e in report.executed]
    assert by[1] == ("pickup(r1)", "failed", 75.0)
    assert all(s == 20.0 for _, outcome, s in by if outcome == "succeeded")


def test_the_dispatcher_checks_preconditions_on_the_knowledge_bases_non_fluents() -> None:
    from ippc.kb import Update

    kb = KnowledgeBase.from_files(DOMAIN, ONE)
    # a client learns at start-up that the hall-office door is locked (the
    # planner's task still has it open)
    kb.apply([Update("set", "CONNECTED", ("hall", "office"), False)], "setup")
    _, dispatcher = build_simulation(kb, 1)
    report = trio.run(
        lambda: dispatch_session(dispatcher, PlannerSpec("exact"), server_config(rounds=1))
    )
    first = report.executed[0]
    assert (first["action"], first["outcome"]) == ("move(r1,hall,office)", "precondition-false")
    assert "move(?r, ?x, ?y) => (robot-at(?r, ?x) ^ CONNECTED(?x, ?y))" in first["message"]
    assert not report.goal_reached
    assert all(e["outcome"] == "precondition-false" for e in report.executed)
