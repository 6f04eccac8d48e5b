"""Start-up and memory budgets of the built-in planners.

A planner's start-up (compiling, analyses, enumerations, the first search)
is part of the session's time, and its memory is the machine's: a planner
that takes either without bound stops a client, a batch or a robot. This
module gives the planners what they need to stay within both.

Time: `Startup` is the start-up allowance of one session (option
`startup`, default `DEFAULT_STARTUP` seconds). A planner asks it before
each piece of start-up work whether there is time left (`Startup.fits`),
and skips what does not fit with a WARNING naming what it skipped and why
(`Startup.skip`). Work that cannot be sized beforehand runs in a worker
thread with a deadline (`Startup.run`): when the deadline passes, the
caller goes on without the result and the worker is asked to stop (an
exception raised in it at its next Python instruction; work inside one long
C call finishes first and is then dropped). Work that need not hold up the
session runs in the background instead (`Background`: mcts's C compile,
waited for a while, then taken up at the first turn after it has ended).

Memory: `memory_budget` is the bytes a planner's working memory may take
(option `memory`, in MiB; default `DEFAULT_MEMORY_FRACTION` of the memory
available when the session starts: MemAvailable of /proc/meminfo, and no
more than that fraction of what an address-space limit (RLIMIT_AS) leaves).
`step_cost` measures what one simulator step costs per state of a batch
(every array the step allocates, temporaries included, traced with
`tracemalloc` on a batch of 1 and of 3 states), so that a planner sizes its
batches, trees and tables from the instance before it allocates them
(`rows_within`, `count_within`).
"""

from __future__ import annotations

import ctypes
import logging
import os
import resource
import threading
import time
import tracemalloc
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

import numpy as np

from ..rddl.simulator import Simulator, State

log = logging.getLogger(__name__)

T = TypeVar("T")


def _default_startup() -> float:
    text = os.environ.get("IPPC_STARTUP", "").strip()
    if not text:
        return 10.0
    try:
        seconds = float(text)
    except ValueError:
        raise ValueError(f"IPPC_STARTUP={text!r}: expected seconds, a number >= 0") from None
    if not seconds >= 0:
        raise ValueError(f"IPPC_STARTUP={text!r}: expected seconds, a number >= 0")
    return seconds


DEFAULT_STARTUP = _default_startup()
"""Seconds of start-up a session is allowed by default (option `startup`),
on top of the first turn's own time: 10, or `$IPPC_STARTUP` where it is set
(a machine whose compiles are slow; the test suite, whose cold compiles
share two cores)."""

DEFAULT_MEMORY_FRACTION = 0.25
"""Share of the memory available at the start of a session (MemAvailable)
a planner takes by default (option `memory` overrides it), so that several
planners, and the machine's other programs, still fit beside it."""

FALLBACK_MEMORY = 2 << 30
"""Bytes taken as available where /proc/meminfo cannot be read."""

MARGIN = 0.5
"""Seconds a start-up piece of work may overrun its deadline: the time for a
worker thread to notice that it was abandoned, or for the step in progress
to end (stated in docs/planners-budgets.md)."""

MIB = 1 << 20

STARTUP_HELP = (
    "seconds of start-up allowed before the first turn's search (compiling the C step, "
    "analyses, enumerations, learning IDS); what does not fit is skipped with a warning "
    f"(default {DEFAULT_STARTUP:g})"
)
MEMORY_HELP = (
    "MiB the planner's working memory may take (batches, search tree, tables); batches "
    "shrink and the tree stops growing to stay within it (default: "
    f"{DEFAULT_MEMORY_FRACTION:g} of MemAvailable at the start of the session)"
)


class StartupOverrun(Exception):
    """A piece of start-up work did not end within the start-up allowance."""


class _Abandoned(BaseException):
    """Raised inside an abandoned worker thread to end it (a BaseException,
    so that the worker's own `except Exception` does not swallow it)."""


# ------------------------------------------------------------------ memory


def available_memory() -> int | None:
    """Bytes the kernel reports available now (MemAvailable of
    /proc/meminfo), else free physical pages; None when neither is known."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (OSError, ValueError, AttributeError):
        return None


def _address_space_left() -> int | None:
    """Bytes an address-space limit (RLIMIT_AS) leaves this process, if set."""
    try:
        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    except (OSError, ValueError):
        return None
    if soft == resource.RLIM_INFINITY:
        return None
    try:
        with open("/proc/self/statm", encoding="ascii") as fh:
            used = int(fh.read().split()[0]) * int(os.sysconf("SC_PAGE_SIZE"))
    except (OSError, ValueError, IndexError):
        used = 0
    return max(0, soft - used)


def memory_budget(mib: float | None) -> int:
    """The bytes a planner may take: `mib` MiB when given, else
    `DEFAULT_MEMORY_FRACTION` of the memory available now (and of what an
    address-space limit leaves)."""
    if mib is not None:
        return max(1, int(mib * MIB))
    avail = available_memory()
    budget = int(DEFAULT_MEMORY_FRACTION * (FALLBACK_MEMORY if avail is None else avail))
    left = _address_space_left()
    if left is not None:
        budget = min(budget, int(DEFAULT_MEMORY_FRACTION * left))
    return max(MIB, budget)


@dataclass(frozen=True)
class StepCost:
    """What one simulator step costs: `fixed` bytes, plus `per_row` bytes
    for every state of the batch (all the arrays the step allocates, the
    largest temporaries included); `state` is the bytes one state holds."""

    per_row: int
    fixed: int
    state: int

    def bytes_for(self, rows: int) -> int:
        """Peak bytes of a step of `rows` states."""
        return self.fixed + rows * self.per_row


def state_bytes(sim: Simulator) -> int:
    """Bytes of one state's arrays."""
    return int(sum(v.nbytes for v in sim.initial_state(1).values.values()))


def step_cost(sim: Simulator) -> StepCost:
    """`StepCost` of `sim`, measured on noop steps from the initial state
    (batches of 1 and 3 states), with its own generator. A step that fails
    (a noop that is illegal, a model the simulator rejects) is measured as
    far as it got."""
    one = state_bytes(sim)
    peaks = []
    was_tracing = tracemalloc.is_tracing()
    if not was_tracing:
        tracemalloc.start()
    try:
        for rows in (1, 3):
            state = sim.initial_state(rows)
            noop = sim.noop(rows)
            base, _ = tracemalloc.get_traced_memory()
            tracemalloc.reset_peak()
            try:
                out = sim.step(state, noop, np.random.default_rng(0), check=False)
                del out
            except Exception as err:  # noqa: BLE001 - the search meets and reports it
                log.debug("budget: step of %d states failed while measured: %s", rows, err)
            _, peak = tracemalloc.get_traced_memory()
            peaks.append(max(0, peak - base))
            del state, noop
    finally:
        if not was_tracing:
            tracemalloc.stop()
    per_row = max(one, (peaks[1] - peaks[0]) // 2)
    fixed = max(0, peaks[0] - per_row)
    return StepCost(per_row=per_row, fixed=fixed, state=one)


def rows_within(budget: int, cost: StepCost, want: int, minimum: int = 1) -> int:
    """The most rows (at most `want`, at least `minimum`) whose step fits in
    `budget` bytes."""
    room = (budget - cost.fixed) // max(1, cost.per_row)
    return int(max(minimum, min(want, room)))


def count_within(budget: int, each: int, want: int, minimum: int = 1) -> int:
    """The most items of `each` bytes (at most `want`, at least `minimum`)
    that fit in `budget` bytes."""
    return int(max(minimum, min(want, budget // max(1, each))))


def describe_bytes(n: float) -> str:
    """`n` bytes in MiB, for log lines."""
    return f"{n / MIB:.0f} MiB" if n >= MIB else f"{n / MIB:.2f} MiB"


# ------------------------------------------------------------------ time


def _raise_in(thread: threading.Thread) -> None:
    ident = thread.ident
    if ident is None or not thread.is_alive():
        return
    ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(ident), ctypes.py_object(_Abandoned))


def run_within(fn: Callable[[], T], seconds: float, what: str) -> T:
    """`fn()` run in a worker thread; its result, or `StartupOverrun` when
    it has not returned after `seconds` (the worker is then asked to stop
    and left behind). An exception of `fn` is raised here."""
    box: dict[str, object] = {}

    def work() -> None:
        try:
            box["value"] = fn()
        except _Abandoned:
            log.debug("budget: %s abandoned", what)
        except BaseException as err:  # noqa: BLE001 - handed to the caller
            box["error"] = err

    worker = threading.Thread(target=work, name=f"startup: {what}", daemon=True)
    worker.start()
    worker.join(max(0.0, seconds))
    if worker.is_alive():
        _raise_in(worker)
        raise StartupOverrun(f"{what} did not end within {max(0.0, seconds):.1f} s")
    if "error" in box:
        raise box["error"]  # type: ignore[misc]
    return box["value"]  # type: ignore[return-value]


class Startup:
    """The start-up allowance of one session: `seconds` from now.

    `fits(estimate)` says whether work expected to take `estimate` seconds
    ends in time; `skip(what, why)` logs a WARNING for work left out;
    `run(what, fn)` runs `fn` with the time left as its deadline."""

    def __init__(
        self,
        who: str,
        instance: str,
        seconds: float,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.who = who
        self.instance = instance
        self.seconds = seconds
        self.clock = clock
        self.started = clock()
        self.skipped: list[str] = []
        """What this start-up left out, in order (for tests and reports)."""

    def left(self) -> float:
        """Seconds of the allowance left (negative once it is spent)."""
        return self.seconds - (self.clock() - self.started)

    def spent(self) -> float:
        """Seconds since the start-up began."""
        return self.clock() - self.started

    def fits(self, estimate: float = 0.0) -> bool:
        """Whether work of about `estimate` seconds ends within the allowance."""
        return self.left() > estimate

    def skip(self, what: str, why: str) -> None:
        """Log that `what` was left out of the start-up, and why."""
        self.skipped.append(what)
        log.warning(
            "%s: %s: start-up: %s skipped (%s); %.2f s of the %.2f s start-up allowance "
            "spent (option startup)",
            self.who,
            self.instance,
            what,
            why,
            self.spent(),
            self.seconds,
        )

    def run(self, what: str, fn: Callable[[], T]) -> T:
        """`fn()` within the time left; `StartupOverrun` when it does not end
        in time (raised at once when no time is left)."""
        left = self.left()
        if left <= 0.0:
            raise StartupOverrun(f"no start-up time left for {what}")
        return run_within(fn, left, what)


class Background(Generic[T]):
    """`fn()` started now in a daemon thread of its own and never abandoned:
    the caller waits for it a while (`wait`), asks whether it has ended
    (`done`) and takes its result when it has (`result`). For work that
    need not hold up the session, such as a C compiler that runs while a
    cheaper engine plays."""

    def __init__(
        self, what: str, fn: Callable[[], T], clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.what = what
        self.clock = clock
        self.started = clock()
        self.ended: float | None = None
        self._box: dict[str, object] = {}
        self._worker = threading.Thread(target=self._work, args=(fn,), name=what, daemon=True)
        self._worker.start()

    def _work(self, fn: Callable[[], T]) -> None:
        try:
            self._box["value"] = fn()
        except BaseException as err:  # noqa: BLE001 - handed to the caller by `result`
            self._box["error"] = err
        finally:
            self.ended = self.clock()

    def done(self) -> bool:
        """Whether `fn` has ended (returned or raised)."""
        return not self._worker.is_alive()

    def wait(self, seconds: float) -> bool:
        """Wait up to `seconds` for `fn` to end; whether it has."""
        self._worker.join(max(0.0, seconds))
        return self.done()

    def seconds(self) -> float:
        """Seconds `fn` took, or has taken so far."""
        return (self.clock() if self.ended is None else self.ended) - self.started

    def result(self) -> T:
        """`fn()`'s value, once it has ended (waits for it); an exception of
        `fn` is raised here."""
        self._worker.join()
        if "error" in self._box:
            raise self._box["error"]  # type: ignore[misc]
        return self._box["value"]  # type: ignore[return-value]


class OneAtATime:
    """Runs work in a worker thread with a deadline, one piece at a time,
    and never abandons it: a piece that is late is left to finish by itself
    (its result dropped), and no new piece starts before it has. For work
    on shared objects that must not be stopped half-way (a solver's caches)."""

    def __init__(self, what: str) -> None:
        self.what = what
        self._worker: threading.Thread | None = None
        self._box: dict[str, object] = {}
        self.was_busy = False
        """Whether the last `call` found a late piece still running (else it
        started its own)."""
        self.late = 0
        """Pieces that did not end in time (or could not start: one was still running)."""

    def busy(self) -> bool:
        """Whether a late piece is still running."""
        return self._worker is not None and self._worker.is_alive()

    def finish(self) -> object:
        """Wait for the late piece to end; its result (an exception of it is
        raised here)."""
        box = self._box
        if self._worker is not None:
            self._worker.join()
            self._worker = None
        if "error" in box:
            raise box["error"]  # type: ignore[misc]
        return box.get("value")

    def call(self, fn: Callable[[], T], seconds: float) -> tuple[bool, T | None]:
        """(True, `fn()`) when it ends within `seconds`; (False, None) when it
        does not, or when an earlier late piece is still running. An
        exception of `fn` is raised here."""
        self.was_busy = self.busy()
        if self.was_busy:
            self.late += 1
            return False, None
        box: dict[str, object] = {}
        self._box = box

        def work() -> None:
            try:
                box["value"] = fn()
            except BaseException as err:  # noqa: BLE001 - handed to the caller
                box["error"] = err

        worker = threading.Thread(target=work, name=self.what, daemon=True)
        worker.start()
        worker.join(None if seconds == float("inf") else max(0.0, seconds))
        if worker.is_alive():
            self._worker = worker
            self.late += 1
            return False, None
        if "error" in box:
            raise box["error"]  # type: ignore[misc]
        return True, box.get("value")  # type: ignore[return-value]


TURN_MARGIN = 0.5
"""Seconds a turn may run past its deadline before `guarded_turn` sends
noop instead, or the turn's own time when that is longer (stated in
docs/planners-budgets.md)."""


def guarded_turn(
    runner: OneAtATime,
    who: str,
    turn: int,
    deadline: float,
    fn: Callable[[], list[T]],
    noop_legal: Callable[[], bool] | None = None,
) -> list[T]:
    """`fn()` (a turn's actions) if it ends by `deadline` (or now, when that
    has passed) plus a margin (`TURN_MARGIN`, or the turn's own time when
    that is longer), else noop (`[]`) with a warning; the late turn finishes in the
    background, and the turns meanwhile send noop too (`OneAtATime`). Where
    `noop_legal` says noop is illegal in this turn's state (ChromaticDice),
    an illegal noop would end the round: the turn waits for its search instead."""
    left = max(0.0, deadline - time.monotonic())
    margin = max(TURN_MARGIN, left)
    ok, actions = runner.call(fn, left + margin)
    if ok:
        assert actions is not None
        return actions
    if noop_legal is not None and not noop_legal():
        log.warning(
            "%s: turn %d: no action by the turn's deadline (plus %.2f s), and noop is illegal "
            "here: waiting for the search",
            who,
            turn,
            margin,
        )
        if not runner.was_busy:
            return runner.finish()  # type: ignore[return-value]
        runner.finish()  # an earlier turn's, dropped
        ok, actions = runner.call(fn, float("inf"))
        assert ok and actions is not None
        return actions
    log.log(
        logging.WARNING if runner.late == 1 else logging.DEBUG,
        "%s: turn %d: no action by the turn's deadline (plus %.2f s); sending noop while the "
        "late search finishes (%d late turns this session; logged once)",
        who,
        turn,
        margin,
        runner.late,
    )
    return []


def noop_legal(sim: Simulator, state: State | None) -> Callable[[], bool]:
    """Whether noop is legal in `state` (asked only when a turn is late;
    True without a state, as in a POMDP's turn)."""

    def legal() -> bool:
        if state is None:
            return True
        try:
            return bool(sim.check_actions(state, sim.noop(1))[0])
        except Exception:  # noqa: BLE001 - a check that fails: noop is not known legal
            return False

    return legal
