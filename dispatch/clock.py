"""Time for the robot side: the wall clock, or simulated time.

Handlers and sensing wait through a `Clock`, so that the same code runs on
a robot (`WallClock`: trio's clock, real sleeps) and in the simulated world
(`SimulatedClock`: time moves only when told, nothing sleeps). Actions of
one turn run concurrently, so a handler waits *until* a point in time
(`sleep_until(dispatch.started + duration)`): in simulated time the turn
then lasts as long as its longest action, not the sum of them.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import trio

__all__ = ["Clock", "SimulatedClock", "WallClock"]


class Clock(ABC):
    """Seconds on some clock, and waiting on it."""

    simulated = False

    @abstractmethod
    def now(self) -> float:
        """The current time, in this clock's seconds."""

    @abstractmethod
    async def sleep_until(self, when: float) -> None:
        """Return once the clock reads `when` or later."""

    async def sleep(self, seconds: float) -> None:
        await self.sleep_until(self.now() + max(0.0, seconds))


class WallClock(Clock):
    """trio's clock (monotonic seconds); sleeps are real."""

    def now(self) -> float:
        return trio.current_time()

    async def sleep_until(self, when: float) -> None:
        await trio.sleep_until(when)


class SimulatedClock(Clock):
    """Simulated seconds from `start`: `sleep_until` moves time forward at
    once (never back) and only yields to the scheduler."""

    simulated = True

    def __init__(self, start: float = 0.0):
        self._now = float(start)

    def now(self) -> float:
        return self._now

    async def sleep_until(self, when: float) -> None:
        if when > self._now:
            self._now = float(when)
        await trio.lowlevel.checkpoint()

    def advance(self, seconds: float) -> None:
        """Move time forward by `seconds` (from outside any task)."""
        self._now += max(0.0, float(seconds))
