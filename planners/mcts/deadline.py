"""`Deadline`: the end of a turn's search and what the next piece of it is
expected to cost, so that the search stops before the deadline rather
than after it.

The search ticks the clock at every point where it could stop (before
each level of a wave's descent, after each step of the leaf rollouts,
before a new wave); the time since the last tick is what one piece of
work costs. It starts another piece only when the slowest recent piece,
plus the time the last wave's backups took, would still end before the
deadline. Without a deadline (`iterations` mode) nothing ever expires, so
the search does not depend on the clock. No dependencies.
"""

from __future__ import annotations

import time


class Deadline:
    """A turn's deadline (a `time.monotonic()` value, or None for none),
    the recent cost of one piece of the search and of a wave's backups."""

    __slots__ = ("at", "piece", "reserve", "_last")

    def __init__(self, at: float | None) -> None:
        self.at = at
        self.piece = 0.0
        """Seconds of a piece of work between two ticks: the last one's, or
        more while the recent ones were slower (it decays by a fifth a tick)."""
        self.reserve = 0.0
        """Seconds the last wave's backups took (they run after the last tick)."""
        self._last = time.monotonic()

    def tick(self) -> None:
        """A piece of work has ended (the first tick only starts the clock)."""
        now = time.monotonic()
        self.piece = max(now - self._last, 0.8 * self.piece)
        self._last = now

    def restart(self) -> None:
        """Start timing the next piece from now (after work not to be counted)."""
        self._last = time.monotonic()

    def passed(self, pieces: float = 1.0) -> bool:
        """Whether `pieces` more pieces of work (and the backups) would end
        past the deadline."""
        return (
            self.at is not None and time.monotonic() + pieces * self.piece + self.reserve >= self.at
        )

    def stop_at(self) -> float | None:
        """When to start no more pieces: the deadline less two slow pieces
        and the backups (None without a deadline)."""
        return None if self.at is None else self.at - 2.0 * self.piece - self.reserve

    def left(self) -> float:
        """Seconds to the deadline (infinite without one)."""
        return float("inf") if self.at is None else self.at - time.monotonic()
