"""A watchdog for the dispatcher's event loop.

Everything of a dispatcher (the planner's socket, sensing, the knowledge
base's socket, the action timeouts) runs in one trio loop, so a handler
that makes a blocking call in its coroutine freezes all of it. The loop
cannot see that itself while it is frozen; a thread can. `LoopWatchdog`
runs a task in the loop that stamps a heartbeat every `period` seconds and
a thread that reads the stamp: when it is older than `threshold`, the
thread logs one warning naming what runs in the loop (the action handlers
in progress, and the line of Python the loop's thread is executing), and
one more line when the loop is back, with how long it was blocked. It
cannot unblock the loop (nothing can, from outside); the action's timeout
still holds, as the handler's time is measured around the call (see
`ippc.dispatch.actions`).
"""

from __future__ import annotations

import logging
import sys
import threading
import time
import traceback
from collections.abc import Callable

import trio

__all__ = ["LoopWatchdog"]

log = logging.getLogger(__name__)


class LoopWatchdog:
    """Warns when the trio loop it runs in is blocked for longer than
    `threshold` seconds. `describe()` says what may be blocking it (the
    dispatcher passes the handlers in progress); it is called from the
    watchdog's thread, so it must only read."""

    def __init__(
        self,
        threshold: float = 1.0,
        describe: Callable[[], str] | None = None,
        *,
        period: float | None = None,
    ):
        if threshold <= 0:
            raise ValueError("the watchdog's threshold must be positive")
        self.threshold = threshold
        self.period = period if period is not None else min(0.25, threshold / 4)
        self.describe = describe or (lambda: "")
        self.blocked = 0  # how many times the loop was seen blocked
        self.longest = 0.0  # seconds, the longest block seen
        self._beat = time.monotonic()
        self._loop_thread: int | None = None
        self._stop = threading.Event()

    async def run(self, *, task_status: trio.TaskStatus[None] = trio.TASK_STATUS_IGNORED) -> None:
        """Beat until cancelled, with the watching thread alongside."""
        self._loop_thread = threading.get_ident()
        self._beat = time.monotonic()
        self._stop.clear()
        thread = threading.Thread(target=self._watch, name="ippc-loop-watchdog", daemon=True)
        thread.start()
        task_status.started()
        try:
            while True:
                self._beat = time.monotonic()
                await trio.sleep(self.period)
        finally:
            self._stop.set()
            # the thread wakes at once on the event; no join needed, it is a daemon

    def _where(self) -> str:
        """The innermost frame of the loop's thread: file:line in function."""
        frame = sys._current_frames().get(self._loop_thread or -1)
        if frame is None:
            return "?"
        last = traceback.extract_stack(frame, limit=1)
        if not last:
            return "?"
        f = last[-1]
        return f"{f.filename}:{f.lineno} in {f.name}"

    def _watch(self) -> None:
        warned_at: float | None = None  # the beat the current block started after
        while not self._stop.wait(self.period):
            beat = self._beat
            silent = time.monotonic() - beat
            if silent > self.threshold:
                if warned_at != beat:
                    warned_at = beat
                    self.blocked += 1
                    what = self.describe() or "no action handler is running"
                    log.warning(
                        "the event loop has been blocked for %.1f s (threshold %g s): %s; "
                        "it is executing %s. A handler must not make blocking calls in its "
                        "coroutine: use ippc.dispatch.run_blocking",
                        silent,
                        self.threshold,
                        what,
                        self._where(),
                    )
            elif warned_at is not None and beat != warned_at:
                blocked_for = beat - warned_at
                self.longest = max(self.longest, blocked_for)
                log.warning("the event loop is running again after %.1f s blocked", blocked_for)
                warned_at = None
