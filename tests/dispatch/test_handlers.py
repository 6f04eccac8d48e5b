"""Action handlers: outcomes, timeouts, and whatever a handler does wrong."""

from __future__ import annotations

import pytest
import trio
from ippc.dispatch.actions import (
    Dispatch,
    GroundAction,
    Handlers,
    Result,
    Status,
    parameter_keys,
)
from ippc.kb import KnowledgeBase


def dispatch(name: str = "pickup", timeout: float | None = 0.2) -> Dispatch:
    action = GroundAction(name, ("r1",))
    return Dispatch(1, 1, action, {"r": "r1"}, trio.current_time(), timeout, (action,))


@pytest.mark.trio
@pytest.mark.parametrize(
    ("answer", "status", "message"),
    [
        (Result(Status.SUCCEEDED, cost=2.5), Status.SUCCEEDED, ""),
        (Status.PRECONDITION_FALSE, Status.PRECONDITION_FALSE, ""),
        (True, Status.SUCCEEDED, ""),
        (False, Status.FAILED, ""),
        ("failed", Status.FAILED, ""),
        (42, Status.FAILED, "answered 42, not succeeded, failed or precondition-false"),
    ],
)
async def test_answers_become_results(answer: object, status: Status, message: str) -> None:
    handlers = Handlers()

    async def handler(d: Dispatch) -> object:
        assert d.params == {"r": "r1"} and d.concurrent == (d.action,)
        return answer

    handlers.register("pickup", handler)
    result = await handlers.run(dispatch())
    assert result.status is status
    assert message in result.message
    assert result.duration is not None and result.duration >= 0.0


@pytest.mark.trio
async def test_a_hanging_handler_fails_at_its_timeout() -> None:
    handlers = Handlers()

    async def hang(d: Dispatch) -> None:
        await trio.sleep_forever()

    handlers.register("pickup", hang)
    with trio.fail_after(5):
        result = await handlers.run(dispatch(timeout=0.05))
    assert result.status is Status.FAILED
    assert "did not answer within 0.05 s (timeout)" in result.message


@pytest.mark.trio
async def test_a_raising_or_missing_handler_fails_its_action_only() -> None:
    handlers = Handlers()

    async def broken(d: Dispatch) -> None:
        raise RuntimeError("gripper offline")

    handlers.register("pickup", broken)
    result = await handlers.run(dispatch())
    assert result.status is Status.FAILED
    assert result.message == "the handler of pickup(r1) raised RuntimeError: gripper offline"
    missing = await handlers.run(dispatch("drop"))
    assert missing.status is Status.FAILED and "no handler for action 'drop'" in missing.message


@pytest.mark.trio
async def test_the_catch_all_handler_and_unregistering() -> None:
    handlers = Handlers()

    async def any_action(d: Dispatch) -> Status:
        return Status.SUCCEEDED

    remove = handlers.register("*", any_action)
    assert "drop" in handlers and "noop" not in handlers  # noop never falls to "*"
    assert (await handlers.run(dispatch("drop"))).succeeded
    remove()
    assert "drop" not in handlers


def test_parameter_keys_follow_rosplan(kb: KnowledgeBase) -> None:
    # move(robot, room, room): r, r1, r2 -- first letters, a counter from the second on
    assert parameter_keys(kb.model, "move") == ("r", "r1", "r2")
    assert parameter_keys(kb.model, "pickup") == ("r",)
