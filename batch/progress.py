"""A live progress line on stderr: sessions done, running, failed, and time left.

Plain text redrawn with a carriage return, at most a few times a second; quiet (nothing
at all) when the stream is not a terminal, so logs and CI output stay clean.
"""

from __future__ import annotations

import time
from typing import TextIO

__all__ = ["Progress", "format_duration"]


def format_duration(seconds: float) -> str:
    """``1h02m``, ``3m05s`` or ``42s``."""
    s = int(round(max(0.0, seconds)))
    if s >= 3600:
        return f"{s // 3600}h{s % 3600 // 60:02d}m"
    if s >= 60:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s}s"


class Progress:
    """Counts of a batch and the line that shows them.

    ``time left`` is the time this run has taken per session ended (which already
    counts the sessions played at once) times the sessions still to play.
    """

    def __init__(
        self,
        total: int = 0,
        done: int = 0,
        *,
        stream: TextIO | None = None,
        enabled: bool | None = None,
    ) -> None:
        self.total = total
        self.done = done
        self.running = 0
        self.failed = 0
        self.stream = stream
        tty = bool(stream is not None and getattr(stream, "isatty", lambda: False)())
        self.enabled = tty if enabled is None else enabled and stream is not None
        self._t0 = time.monotonic()
        self._ended_here = 0
        self._last_draw = 0.0
        self._width = 0

    def start(self, total: int, done: int, failed: int = 0) -> None:
        """Counts at the start of a run: `done` jobs ended before it (`failed` of them
        failed)."""
        self.total, self.done, self.failed = total, done, failed
        self._t0 = time.monotonic()
        self.draw(force=True)

    def started(self) -> None:
        self.running += 1
        self.draw()

    def ended(self, failed: bool = False) -> None:
        self.running = max(0, self.running - 1)
        self.done += 1
        self._ended_here += 1
        if failed:
            self.failed += 1
        self.draw()

    def time_left(self) -> float | None:
        if self._ended_here == 0:
            return None
        elapsed = time.monotonic() - self._t0
        remaining = self.total - self.done
        return elapsed / self._ended_here * remaining

    def line(self) -> str:
        left = self.time_left()
        width = 24
        filled = int(width * self.done / self.total) if self.total else width
        bar = "#" * filled + "." * (width - filled)
        eta = "?" if left is None else format_duration(left)
        return (
            f"[{bar}] {self.done}/{self.total} sessions done, {self.running} running, "
            f"{self.failed} failed, {eta} left"
        )

    def draw(self, force: bool = False) -> None:
        if not self.enabled or self.stream is None:
            return
        now = time.monotonic()
        if not force and now - self._last_draw < 0.2:
            return
        self._last_draw = now
        text = self.line()
        pad = max(0, self._width - len(text))
        self._width = len(text)
        self.stream.write("\r" + text + " " * pad)
        self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.stream is not None:
            self.draw(force=True)
            self.stream.write("\n")
            self.stream.flush()
