"""One dispatcher turn, played directly on its episode: the actions of a turn run
at once, and preconditions are checked per action before the set."""

from __future__ import annotations

import pytest
import trio
from ippc.dispatch.actions import Dispatch, Handlers, Status
from ippc.dispatch.dispatcher import Dispatcher
from ippc.kb import KnowledgeBase
from ippc.protocol import Actions, Fluent

from .conftest import DOMAIN, TWO

pytestmark = pytest.mark.trio


async def play_turn(dispatcher: Dispatcher, *actions: Fluent) -> dict[str, object]:
    """Send one turn and answer it with `actions`; the turn's record."""
    episode = await dispatcher.open(0)
    episode.start_round()
    episode.turn()
    episode.thinking()
    with trio.fail_after(10):
        outcome = await episode.act(Actions(actions))
    return outcome.record  # type: ignore[no-any-return]


def recording(kb: KnowledgeBase) -> tuple[Dispatcher, list[str]]:
    """A dispatcher whose one handler takes every action, succeeds, and notes it."""
    handlers = Handlers(timeout=5.0)
    ran: list[str] = []

    async def any_action(d: Dispatch) -> Status:
        ran.append(str(d.action))
        return Status.SUCCEEDED

    handlers.register("*", any_action)
    return Dispatcher(kb, handlers, settle_limit=0.0), ran


def outcomes(record: dict[str, object]) -> list[tuple[str, str]]:
    return [(a["action"], a["outcome"]) for a in record["actions"]]  # type: ignore[attr-defined, index]


async def test_the_actions_of_a_turn_run_at_once() -> None:
    kb = KnowledgeBase.from_files(DOMAIN, TWO)  # two robots, max-nondef-actions 2
    handlers = Handlers(timeout=5.0)
    started: dict[str, trio.Event] = {"r1": trio.Event(), "r2": trio.Event()}
    saw_other: dict[str, bool] = {}

    async def move(d: Dispatch) -> Status:
        me, other = d.params["r"], "r2" if d.params["r"] == "r1" else "r1"
        started[me].set()
        # each move waits for the other to have started: only concurrent dispatch passes
        with trio.move_on_after(1.0):
            await started[other].wait()
        saw_other[me] = started[other].is_set()
        return Status.SUCCEEDED

    handlers.register("move", move)
    dispatcher = Dispatcher(kb, handlers, settle_limit=0.0)
    record = await play_turn(
        dispatcher,
        Fluent("move", ("r1", "hall", "office")),
        Fluent("move", ("r2", "lab", "hall")),
    )
    assert outcomes(record) == [
        ("move(r1,hall,office)", "succeeded"),
        ("move(r2,lab,hall)", "succeeded"),
    ]
    assert saw_other == {"r1": True, "r2": True}
    assert record["turn"] == 1 and record["applied"] == 4  # both robots moved, in the KB
    assert kb.get("robot-at", ("r1", "office")) and kb.get("robot-at", ("r2", "hall"))


async def test_one_action_that_fails_its_precondition_leaves_the_others_dispatched() -> None:
    kb = KnowledgeBase.from_files(DOMAIN, TWO)
    dispatcher, ran = recording(kb)
    # r2 holds nothing: its drop is refused on its own; r1's move goes ahead
    record = await play_turn(
        dispatcher, Fluent("move", ("r1", "hall", "office")), Fluent("drop", ("r2",))
    )
    assert outcomes(record) == [
        ("move(r1,hall,office)", "succeeded"),
        ("drop(r2)", "precondition-false"),
    ]
    assert ran == ["move(r1,hall,office)"]
    drop = record["actions"][1]  # type: ignore[index]
    assert "(drop(?r) => holding(?r)); actions: drop(r2) = true" in drop["message"]


async def test_actions_fine_alone_but_not_together_are_all_refused() -> None:
    kb = KnowledgeBase.from_files(DOMAIN, TWO)
    dispatcher, ran = recording(kb)
    # one robot, two moves in one turn: each is legal, the pair breaks the
    # domain's one-action-per-robot constraint
    record = await play_turn(
        dispatcher,
        Fluent("move", ("r1", "hall", "office")),
        Fluent("move", ("r1", "hall", "lab")),
    )
    assert outcomes(record) == [
        ("move(r1,hall,office)", "precondition-false"),
        ("move(r1,hall,lab)", "precondition-false"),
    ]
    assert ran == []
    assert kb.get("robot-at", ("r1", "hall")) is True  # nothing applied


async def test_a_turn_whose_actions_are_all_refused_is_a_noop_turn_in_the_world() -> None:
    from ippc.dispatch.run import build_simulation

    kb = KnowledgeBase.from_files(DOMAIN, TWO)
    world, dispatcher = build_simulation(kb, 1, durations={"noop": 2.0})
    start = dispatcher.clock.now()
    record = await play_turn(dispatcher, Fluent("drop", ("r2",)))  # r2 holds nothing
    assert outcomes(record) == [("drop(r2)", "precondition-false")]
    # the world's step passed as on a noop turn (its exogenous fluents moved on)
    assert world.steps == 1
    assert dispatcher.clock.now() - start == pytest.approx(2.0 + 0.1)  # noop, then settling
