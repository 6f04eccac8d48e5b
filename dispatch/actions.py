"""Action handlers: what executes one grounded action on the robot.

A handler is an async callable that takes a `Dispatch` (the grounded
action, its parameters by name, the turn, the other actions of the turn)
and reports how it went: a `Result`, or just a `Status`, or True/False
(succeeded/failed). ROSPlan's action interfaces report the same three
outcomes (succeeded, failed, precondition-false).

`Handlers` keeps the handlers by action name (one for "noop" is called on
turns without actions, one for "*" for every action without its own) and
runs one dispatch with a timeout: a handler that raises or answers nonsense
is reported as failed, one that overruns its timeout as timed out, with a
message saying which; nothing of it reaches the dispatcher.

The timeout holds whatever the handler does. A handler that awaits is
cancelled at its deadline. One that blocks the event loop (a blocking
driver call in the coroutine) or shields its wait from cancellation cannot
be stopped there, but its time is measured around the call: an answer that
comes after the deadline is recorded `timed-out`, never `succeeded`. A
blocking driver call belongs in `run_blocking(fn, *args)`, which runs it in
a thread under the action's timeout (the thread is abandoned at the
deadline: the call goes on in the background, its result is dropped), and
`ippc.dispatch.watchdog` warns, naming the handler, when the loop stays
blocked. What a success changes in the knowledge base is the
dispatcher's business (the deterministic effects on fluents that are not
sensed); a handler may also write to the knowledge base itself.
"""

from __future__ import annotations

import enum
import logging
import math
import time
from collections.abc import Awaitable, Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import trio

from ..kb.operators import parameter_names
from ..rddl.model import Model, Value
from .clock import Clock, WallClock

__all__ = [
    "ActionHandler",
    "Dispatch",
    "GroundAction",
    "Handlers",
    "Result",
    "Status",
    "parameter_keys",
    "run_blocking",
]

log = logging.getLogger(__name__)


class Status(enum.StrEnum):
    """How a dispatched action ended."""

    SUCCEEDED = "succeeded"
    FAILED = "failed"
    PRECONDITION_FALSE = "precondition-false"
    #: the handler did not answer within the action's timeout (it was
    #: cancelled, or it answered late because it blocked or shielded itself)
    TIMED_OUT = "timed-out"


@dataclass(frozen=True)
class GroundAction:
    """One action fluent grounding with the value sent (True for PROST)."""

    name: str
    args: tuple[str, ...] = ()
    value: Value = True

    def __str__(self) -> str:
        text = f"{self.name}({','.join(self.args)})"
        return text if self.value is True else f"{text}={self.value}"


@dataclass(frozen=True)
class Dispatch:
    """What a handler is asked to do."""

    id: int  # increasing over the dispatcher's life
    turn: int  # the turn (counted over the session) it belongs to
    action: GroundAction
    params: Mapping[str, str]  # parameter key (ROSPlan's names: r, w, w1) -> object
    started: float  # on the dispatcher's clock
    timeout: float | None  # seconds the handler has
    concurrent: tuple[GroundAction, ...] = ()  # every action dispatched this turn (this one too)

    @property
    def name(self) -> str:
        return self.action.name

    @property
    def args(self) -> tuple[str, ...]:
        return self.action.args


@dataclass(frozen=True)
class Result:
    """A handler's report. `cost` is whatever the handler measures for the
    action (metres driven, seconds waited); `duration` the seconds it took
    (filled in from the clock when the handler leaves it out)."""

    status: Status
    message: str = ""
    cost: float | None = None
    duration: float | None = None
    data: Mapping[str, Any] = field(default_factory=dict)

    @property
    def succeeded(self) -> bool:
        return self.status is Status.SUCCEEDED


ActionHandler = Callable[[Dispatch], Awaitable[Any]]


def parameter_keys(model: Model, action: str) -> tuple[str, ...]:
    """The keys the knowledge base gives an action's parameters, as ROSPlan
    names them (`ippc.kb.operators.parameter_names`: the type's first
    letter, with a counter from the second use on; goto_waypoint(robot,
    waypoint, waypoint) -> r, w, w1)."""
    return parameter_names(model.pvariables[action].params)


def as_result(answer: Any, where: str) -> Result:
    """A handler's answer as a `Result` (refusing what is none)."""
    if isinstance(answer, Result):
        return answer
    if isinstance(answer, Status):
        return Result(answer)
    if isinstance(answer, bool):
        return Result(Status.SUCCEEDED if answer else Status.FAILED)
    if isinstance(answer, str):
        try:
            return Result(Status(answer))
        except ValueError:
            pass
    return Result(
        Status.FAILED,
        f"{where} answered {answer!r}, not succeeded, failed or precondition-false",
    )


class Handlers:
    """Action handlers by action name, and running one dispatch."""

    NOOP = "noop"
    ANY = "*"

    def __init__(self, *, clock: Clock | None = None, timeout: float | None = 60.0):
        self.clock = clock or WallClock()
        self.timeout = timeout
        self._handlers: dict[str, ActionHandler] = {}
        self._warned: set[str] = set()
        #: what runs now, by dispatch id ("the handler of move(r1,hall,lab)"):
        #: the watchdog names it when the event loop is blocked
        self.running: dict[int, str] = {}
        self._watchers: list[Callable[[str, dict[str, Any]], None]] = []

    def watch(self, watcher: Callable[[str, dict[str, Any]], None]) -> Callable[[], None]:
        """Call `watcher(kind, data)` when a dispatch starts ("action-started":
        id, turn, action, timeout) and ends ("action-ended": id, turn,
        action, status, message, duration, cost), as plain data; returns the
        function that stops it. One that raises is logged, never the
        action's business."""
        self._watchers.append(watcher)

        def unwatch() -> None:
            if watcher in self._watchers:
                self._watchers.remove(watcher)

        return unwatch

    def _tell(self, kind: str, data: dict[str, Any]) -> None:
        for watcher in list(self._watchers):
            try:
                watcher(kind, data)
            except Exception:
                log.exception("a handlers watcher failed on %s", kind)

    def register(self, action: str, handler: ActionHandler) -> Callable[[], None]:
        """Handle `action` (an action fluent's name, "noop" or "*") with
        `handler`, replacing any other; returns the function that removes it."""
        self._handlers[action] = handler

        def unregister() -> None:
            if self._handlers.get(action) is handler:
                del self._handlers[action]

        return unregister

    def handler(self, action: str) -> ActionHandler | None:
        return self._handlers.get(action) or (
            None if action == self.NOOP else self._handlers.get(self.ANY)
        )

    def names(self) -> list[str]:
        return sorted(self._handlers)

    def __contains__(self, action: str) -> bool:
        return self.handler(action) is not None

    def __iter__(self) -> Iterator[str]:
        return iter(sorted(self._handlers))

    async def run(self, dispatch: Dispatch) -> Result:
        """`_run`, told to the watchers (see `watch`)."""
        if self._watchers:
            self._tell(
                "action-started",
                {
                    "id": dispatch.id,
                    "turn": dispatch.turn,
                    "action": str(dispatch.action),
                    "timeout": dispatch.timeout,
                },
            )
        result = await self._run(dispatch)
        if self._watchers:
            self._tell(
                "action-ended",
                {
                    "id": dispatch.id,
                    "turn": dispatch.turn,
                    "action": str(dispatch.action),
                    "status": result.status.value,
                    "message": result.message,
                    "duration": result.duration,
                    "cost": result.cost,
                },
            )
        return result

    async def _run(self, dispatch: Dispatch) -> Result:
        """Run the handler of `dispatch` within its timeout (wall-clock
        seconds: a hung handler is a real hang); every way it can go wrong
        becomes a failed or timed-out `Result` that says what happened. The
        time is measured around the call, so a handler that blocked the
        event loop or shielded itself past its deadline is timed out too."""
        handler = self.handler(dispatch.name)
        where = f"the handler of {dispatch.action}"
        if handler is None:
            if dispatch.name not in self._warned:
                self._warned.add(dispatch.name)
                log.warning("no handler for action %s: it fails", dispatch.name)
            return Result(Status.FAILED, f"no handler for action {dispatch.name!r}", duration=0.0)
        timeout = dispatch.timeout
        self.running[dispatch.id] = where
        t0 = time.monotonic()
        try:
            with trio.move_on_after(math.inf if timeout is None else timeout) as scope:
                answer = await handler(dispatch)
        except Exception as err:  # noqa: BLE001 - a handler's bug fails its action only
            elapsed = time.monotonic() - t0
            if timeout is not None and elapsed > timeout:
                return self._late(where, timeout, elapsed, dispatch, f"raised {type(err).__name__}")
            log.warning("%s raised %s: %s", where, type(err).__name__, err)
            return self._timed(
                Result(Status.FAILED, f"{where} raised {type(err).__name__}: {err}"), dispatch
            )
        finally:
            self.running.pop(dispatch.id, None)
        elapsed = time.monotonic() - t0
        if scope.cancelled_caught:
            log.warning("%s did not answer within %g s", where, timeout)
            return self._timed(
                Result(Status.TIMED_OUT, f"{where} did not answer within {timeout:g} s (timeout)"),
                dispatch,
            )
        if timeout is not None and elapsed > timeout:
            # it answered, but after its deadline: it blocked the event loop
            # or shielded itself from the cancellation
            return self._late(where, timeout, elapsed, dispatch, "answered")
        return self._timed(as_result(answer, where), dispatch)

    def _late(
        self, where: str, timeout: float, elapsed: float, dispatch: Dispatch, what: str
    ) -> Result:
        log.warning(
            "%s %s after %.2f s, past its %g s timeout (it blocked the event loop or "
            "shielded itself from cancellation): timed out",
            where,
            what,
            elapsed,
            timeout,
        )
        return self._timed(
            Result(
                Status.TIMED_OUT,
                f"{where} {what} after {elapsed:.2f} s, past its {timeout:g} s timeout "
                "(it blocked or shielded itself; see run_blocking) (timeout)",
            ),
            dispatch,
        )

    def _timed(self, result: Result, dispatch: Dispatch) -> Result:
        if result.duration is not None:
            return result
        return Result(
            result.status,
            result.message,
            result.cost,
            max(0.0, self.clock.now() - dispatch.started),
            result.data,
        )


#: Threads `run_blocking` may run at once; a driver call that hangs keeps its
#: thread (and its place here) until it returns, so a robot whose driver
#: hangs again and again gets timeouts here, never an unbounded number of
#: threads (and the planner's own threads are never starved).
BLOCKING_THREADS = 8
_blocking_limiter: trio.lowlevel.RunVar[trio.CapacityLimiter] = trio.lowlevel.RunVar(
    "ippc_dispatch_blocking"
)


async def run_blocking(fn: Callable[..., Any], *args: Any) -> Any:
    """Run the blocking call `fn(*args)` in a thread and return what it
    returns (or raise what it raises), without blocking the event loop.

    Inside a handler it runs under the action's timeout: at the deadline
    the handler is cancelled and the thread is *abandoned*: Python cannot
    stop a thread, so the call goes on in the background until it returns
    and its result is dropped. Give the driver call its own timeout too
    when it has one. At most `BLOCKING_THREADS` such calls run at once
    (more wait for a place, within their action's timeout)."""
    try:
        limiter = _blocking_limiter.get()
    except LookupError:  # the first call in this trio run
        limiter = trio.CapacityLimiter(BLOCKING_THREADS)
        _blocking_limiter.set(limiter)
    return await trio.to_thread.run_sync(lambda: fn(*args), abandon_on_cancel=True, limiter=limiter)
