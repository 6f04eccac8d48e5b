"""Action handlers: outcomes, timeouts, and whatever a handler does wrong."""

from __future__ import annotations

import logging
import threading
import time

import pytest
import trio
from ippc.dispatch.actions import (
    Dispatch,
    GroundAction,
    Handlers,
    Result,
    Status,
    parameter_keys,
    run_blocking,
)
from ippc.dispatch.watchdog import LoopWatchdog
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
    assert result.status is Status.TIMED_OUT
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


@pytest.mark.trio
async def test_a_handler_that_blocks_the_loop_past_its_timeout_is_timed_out() -> None:
    handlers = Handlers()

    async def blocking(d: Dispatch) -> Status:
        time.sleep(0.3)  # a blocking driver call in the coroutine: not cancellable
        return Status.SUCCEEDED

    handlers.register("pickup", blocking)
    result = await handlers.run(dispatch(timeout=0.1))
    assert result.status is Status.TIMED_OUT  # never succeeded, though it said so
    assert "answered after 0.3" in result.message and "past its 0.1 s timeout" in result.message


@pytest.mark.trio
async def test_a_shielded_handler_past_its_timeout_is_timed_out() -> None:
    handlers = Handlers()

    async def shielded(d: Dispatch) -> Status:
        with trio.CancelScope(shield=True):
            await trio.sleep(0.3)
        return Status.SUCCEEDED

    handlers.register("pickup", shielded)
    with trio.fail_after(5):
        result = await handlers.run(dispatch(timeout=0.1))
    assert result.status is Status.TIMED_OUT
    assert "past its 0.1 s timeout" in result.message


@pytest.mark.trio
async def test_run_blocking_holds_the_timeout_and_keeps_the_loop_running() -> None:
    handlers = Handlers()
    release = threading.Event()
    ticks: list[float] = []

    def driver(room: str) -> str:
        release.wait(5.0)  # a driver call that hangs until released
        return room

    async def move(d: Dispatch) -> Status:
        await run_blocking(driver, "lab")
        return Status.SUCCEEDED

    async def ticker() -> None:
        while True:
            ticks.append(time.monotonic())
            await trio.sleep(0.01)

    handlers.register("pickup", move)
    async with trio.open_nursery() as nursery:
        nursery.start_soon(ticker)
        t0 = time.monotonic()
        result = await handlers.run(dispatch(timeout=0.2))
        elapsed = time.monotonic() - t0
        nursery.cancel_scope.cancel()
    release.set()  # the abandoned thread ends
    assert result.status is Status.TIMED_OUT and "did not answer within 0.2 s" in result.message
    assert elapsed < 2.0
    # the loop went on while the driver hung (a tick every 10 ms, not one)
    assert len(ticks) >= 5

    async def quick(d: Dispatch) -> Status:
        return Status.SUCCEEDED if await run_blocking(lambda x: x * 2, 21) == 42 else Status.FAILED

    handlers.register("pickup", quick)
    assert (await handlers.run(dispatch(timeout=2.0))).status is Status.SUCCEEDED


@pytest.mark.trio
async def test_the_watchdog_names_the_handler_that_blocks_the_loop(
    caplog: pytest.LogCaptureFixture,
) -> None:
    handlers = Handlers()

    async def blocking(d: Dispatch) -> Status:
        time.sleep(2.0)
        return Status.SUCCEEDED

    handlers.register("pickup", blocking)
    dog = LoopWatchdog(0.5, lambda: ", ".join(handlers.running.values()), period=0.05)
    with caplog.at_level(logging.WARNING, logger="ippc.dispatch.watchdog"):
        async with trio.open_nursery() as nursery:
            await nursery.start(dog.run)
            await trio.sleep(0.1)
            await handlers.run(dispatch(timeout=5.0))
            await trio.sleep(0.2)  # the loop runs again: the watchdog says so
            nursery.cancel_scope.cancel()
    blocked = [r.getMessage() for r in caplog.records if "has been blocked" in r.getMessage()]
    # one warning for the handler's block (a loaded machine may add a stall of its own)
    named = [m for m in blocked if "the handler of pickup(r1)" in m]
    assert len(named) == 1 and "test_handlers.py" in named[0] and dog.blocked >= 1
    assert any("running again" in r.getMessage() for r in caplog.records)


@pytest.mark.trio
async def test_the_watchdog_is_quiet_while_the_loop_runs(caplog: pytest.LogCaptureFixture) -> None:
    dog = LoopWatchdog(1.0, period=0.05)
    with caplog.at_level(logging.WARNING, logger="ippc.dispatch.watchdog"):
        async with trio.open_nursery() as nursery:
            await nursery.start(dog.run)
            for _ in range(20):
                await trio.sleep(0.02)
            nursery.cancel_scope.cancel()
    assert dog.blocked == 0 and not caplog.records
