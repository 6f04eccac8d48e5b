"""What rddl-batch tells people while it runs, on one stream (the CLI's stderr).

On a terminal: a progress bar (tqdm) with the jobs done, running and failed and the
time left, each failure printed above it as it happens. Anywhere else (a pipe, a file,
nohup, CI, a cluster job's log): one line per job as it ends, flushed at once::

    [3/12] finished  mcts  sysadmin_inst_mdp__1  mean reward 312.5000  8.2 s  9 jobs left

and a heartbeat line whenever nothing was written for `heartbeat` seconds (one minute
by default), naming the jobs running and for how long. Without a stream: nothing.
"""

from __future__ import annotations

import threading
import time
from typing import Any, TextIO

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
    """Counts of a batch, shown as a bar (`bar` True; default: when `stream` is a
    terminal) or as lines (see the module doc).

    ``time left`` is the time this run has taken per job ended (which already counts
    the jobs played at once) times the jobs still to play.
    """

    def __init__(
        self,
        total: int = 0,
        done: int = 0,
        *,
        stream: TextIO | None = None,
        bar: bool | None = None,
        heartbeat: float = 60.0,
    ) -> None:
        self.total = total
        self.done = done
        self.failed = 0
        self.stream = stream
        tty = bool(stream is not None and getattr(stream, "isatty", lambda: False)())
        self.bar = tty if bar is None else bar and stream is not None
        self.heartbeat = heartbeat
        self._running: dict[str, float] = {}  # job key -> when it was handed out
        self._t0 = time.monotonic()
        self._ended_here = 0
        self._lock = threading.Lock()
        self._last_write = time.monotonic()
        self._stop = threading.Event()
        self._beat: threading.Thread | None = None
        self._tqdm: Any = None

    @property
    def running(self) -> int:
        return len(self._running)

    # ------------------------------------------------------------ the run's hooks

    def start(self, total: int, done: int, failed: int = 0) -> None:
        """Counts at the start of a run: `done` jobs ended before it (`failed` of them
        failed)."""
        self.total, self.done, self.failed = total, done, failed
        self._t0 = self._last_write = time.monotonic()
        if self.stream is None:
            return
        if self.bar:
            from tqdm import tqdm

            self._tqdm = tqdm(
                total=total,
                initial=done,
                file=self.stream,
                unit="job",
                dynamic_ncols=True,
                smoothing=0.0,  # the mean over the run: jobs differ too much for more
            )
            self._postfix()
        else:
            self._write(f"{total - done} of {total} jobs to play")
            if self.heartbeat > 0:
                self._beat = threading.Thread(target=self._beating, name="batch-heartbeat")
                self._beat.daemon = True
                self._beat.start()

    def started(self, key: str = "") -> None:
        with self._lock:
            self._running[key] = time.monotonic()
        if self._tqdm is not None:
            self._postfix()

    def ended(
        self,
        key: str = "",
        status: str = "finished",
        *,
        planner: str = "",
        instance: str = "",
        mean: float | None = None,
        seconds: float = 0.0,
        reason: str | None = None,
    ) -> None:
        """A job's result is in: count it and say so."""
        with self._lock:
            self._running.pop(key, None)
            self.done += 1
            self._ended_here += 1
            if status not in ("finished", "timeout"):
                self.failed += 1
        left = self.total - self.done
        reward = "mean reward -" if mean is None else f"mean reward {mean:.4f}"
        text = (
            f"[{self.done}/{self.total}] {status:<8}  {planner}  {instance}  {reward}  "
            f"{seconds:.1f} s  {left} job{'' if left == 1 else 's'} left"
        )
        if reason and status != "finished":
            text += f": {reason}"
        if self._tqdm is not None:
            if status != "finished":
                self._tqdm.write(text, file=self.stream)
            self._tqdm.update(1)
            self._postfix()
        elif self.stream is not None:
            self._write(text)

    def close(self) -> None:
        self._stop.set()
        if self._beat is not None:
            self._beat.join(5)
        if self._tqdm is not None:
            self._tqdm.close()
            self._tqdm = None

    # ------------------------------------------------------------------ reading

    def time_left(self) -> float | None:
        if self._ended_here == 0:
            return None
        elapsed = time.monotonic() - self._t0
        remaining = self.total - self.done
        return elapsed / self._ended_here * remaining

    def line(self) -> str:
        """The counts in one line (the heartbeat's)."""
        now = time.monotonic()
        with self._lock:
            running = sorted(self._running.items(), key=lambda kv: kv[1])
        left = self.time_left()
        eta = "?" if left is None else format_duration(left)
        shown = ", ".join(f"{k} {format_duration(now - t)}" for k, t in running[:3])
        if len(running) > 3:
            shown += f", {len(running) - 3} more"
        return (
            f"... {self.done}/{self.total} jobs done, {len(running)} running"
            f"{f' ({shown})' if shown else ''}, {self.failed} failed, "
            f"{format_duration(now - self._t0)} elapsed, {eta} left"
        )

    # ----------------------------------------------------------------- writing

    def _postfix(self) -> None:
        if self._tqdm is not None:
            self._tqdm.set_postfix_str(f"{self.running} running, {self.failed} failed")

    def _write(self, text: str) -> None:
        assert self.stream is not None
        with self._lock:
            self.stream.write(text + "\n")
            self.stream.flush()
            self._last_write = time.monotonic()

    def _beating(self) -> None:
        step = min(1.0, self.heartbeat / 4)
        while not self._stop.wait(step):
            if time.monotonic() - self._last_write >= self.heartbeat:
                self._write(self.line())
