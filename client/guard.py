"""Run a planner's work in a child process that can be stopped: a time limit and a
memory budget that hold whatever the planner does.

A planner that runs in the same process as its client cannot be stopped from inside
when it blocks (a start-up that never returns holds the event loop, so no ``fail_after``
fires) or allocates without bound. `run_guarded` runs a function in a fresh Python
process (``python -m ippc.client.guard``) and watches it from the calling thread:

* time: the child is ended once its deadline passes (SIGTERM, then SIGKILL to its
  process group after `TERM_GRACE` seconds); the child's messages may move the
  deadline (the caller's `on_message` returns the seconds the child may still run, for
  instance once a session's budget is known);
* memory: the child's resident memory is read from ``/proc`` every `poll` seconds and
  the child is killed (SIGKILL) as soon as it is over the budget; a ``MemoryError``
  inside the child is reported the same way;
* an orphan: a child whose caller died (killed with SIGKILL, or a Dask worker that
  was ended) ends itself within a second;
* the child's messages (progress, a session's budget) come back over a pipe of their
  own, length-prefixed pickles, so whatever the planner prints goes to `log_path`.

The outcome says which of these ended the child, with a sentence fit for a log or a
result database. Unix only (``/proc``, process groups).
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import os
import pickle
import select
import signal
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

__all__ = [
    "DEFAULT_MEMORY_FRACTION",
    "GuardOutcome",
    "default_memory_budget",
    "memory_available_mb",
    "run_guarded",
]

log = logging.getLogger(__name__)

#: Seconds between SIGTERM and SIGKILL when a child runs past its time.
TERM_GRACE = 2.0
#: Share of the memory available at start that a budget left to its default takes.
DEFAULT_MEMORY_FRACTION = 0.8

_HEADER = struct.Struct(">I")
_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


@dataclass
class GuardOutcome:
    """How the child ended.

    ``status``: ``ok`` (the function returned `value`), ``timeout`` (ended at its
    deadline), ``memory`` (over its budget, or a MemoryError), ``failed`` (it raised,
    or died on its own) or ``interrupted`` (the caller's `cancel` was set)."""

    status: str
    value: Any = None
    reason: str | None = None
    seconds: float = 0.0
    peak_mb: float = 0.0


def memory_available_mb() -> float | None:
    """MemAvailable of ``/proc/meminfo`` in MB (None where there is none)."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        return None
    return None


def default_memory_budget(parallel: int = 1) -> float | None:
    """`DEFAULT_MEMORY_FRACTION` of the memory available now, shared by `parallel`
    children (None: unknown, no budget)."""
    avail = memory_available_mb()
    if avail is None:
        return None
    return DEFAULT_MEMORY_FRACTION * avail / max(1, parallel)


def _rss_mb(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/statm", encoding="ascii") as f:
            return int(f.read().split()[1]) * _PAGE / 2**20
    except (OSError, ValueError, IndexError):
        return 0.0


class _Reader:
    """Length-prefixed pickles from a pipe, read without blocking."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.buf = b""
        self.eof = False

    def read(self) -> list[Any]:
        try:
            chunk = os.read(self.fd, 1 << 16)
        except BlockingIOError:
            return []
        except OSError:
            chunk = b""
        if not chunk:
            self.eof = True
            return []
        self.buf += chunk
        out = []
        while len(self.buf) >= _HEADER.size:
            (n,) = _HEADER.unpack_from(self.buf)
            if len(self.buf) < _HEADER.size + n:
                break
            out.append(pickle.loads(self.buf[_HEADER.size : _HEADER.size + n]))
            self.buf = self.buf[_HEADER.size + n :]
        return out


def _stop(proc: subprocess.Popen[bytes], term_first: bool) -> None:
    """End the child and its process group (SIGTERM first when asked)."""
    if term_first and proc.poll() is None:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, signal.SIGTERM)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(TERM_GRACE)
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(10)


def _last_line(path: Path | None) -> str:
    if path is None:
        return ""
    try:
        with open(path, "rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - 2000))
            lines = [ln for ln in f.read().decode("utf-8", "replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    return f" (its last line: {lines[-1].strip()})" if lines else ""


def run_guarded(
    target: str,
    arg: Any,
    *,
    seconds: float,
    memory_mb: float | None,
    on_message: Callable[[Any], float | None] | None = None,
    log_path: Path | None = None,
    cancel: threading.Event | None = None,
    poll: float = 0.1,
    log_level: int = logging.INFO,
) -> GuardOutcome:
    """Call ``module:function`` (`target`) as ``function(arg, send)`` in a child Python
    process and wait for it, at most `seconds` (a message's `on_message` may set a new
    limit, counted from then) and at most `memory_mb` MB resident (None: no budget).

    ``send(obj)`` in the child hands a picklable object to `on_message` here; the
    function's return value comes back as the outcome's value. The child's stdout and
    stderr go to `log_path` (appended), else to our stderr; it logs at `log_level`.
    Never raises for what the child does; KeyboardInterrupt here ends the child before
    it propagates."""
    t0 = time.monotonic()
    deadline = t0 + seconds
    rfd, wfd = os.pipe()
    out: IO[bytes] | int = 2  # our stderr
    if log_path is not None:
        log_path.parent.mkdir(parents=True, exist_ok=True)
        out = open(log_path, "ab")  # noqa: SIM115 - closed below
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "ippc.client.guard", str(wfd), str(log_level)],
            stdin=subprocess.PIPE,
            stdout=out,
            stderr=subprocess.STDOUT,
            pass_fds=(wfd,),
            start_new_session=True,  # its own group: everything it starts ends with it
        )
    except OSError as err:
        os.close(rfd)
        os.close(wfd)
        if not isinstance(out, int):
            out.close()
        return GuardOutcome("failed", reason=f"cannot start a process for the planner: {err}")
    os.close(wfd)
    os.set_blocking(rfd, False)
    reader = _Reader(rfd)
    peak = 0.0
    try:
        assert proc.stdin is not None
        try:
            proc.stdin.write(pickle.dumps((target, arg)))
            proc.stdin.close()
        except OSError:
            pass  # it died at once: seen below
        result: tuple[Any, ...] | None = None
        while True:
            ready, _, _ = select.select([rfd], [], [], poll) if not reader.eof else ([], [], [])
            if ready:
                for msg in reader.read():
                    if msg[0] == "msg":
                        if on_message is not None:
                            more = on_message(msg[1])
                            if more is not None:
                                deadline = time.monotonic() + more
                    else:
                        result = msg
            elif reader.eof:
                time.sleep(poll)
            rss = _rss_mb(proc.pid)
            peak = max(peak, rss)
            now = time.monotonic()
            if result is not None or (reader.eof and proc.poll() is not None):
                break
            if memory_mb is not None and rss > memory_mb:
                _stop(proc, term_first=False)
                return GuardOutcome(
                    "memory",
                    reason=(
                        f"out of memory: the planner's process held {rss:.0f} MB, over its "
                        f"budget of {memory_mb:.0f} MB; killed"
                    ),
                    seconds=now - t0,
                    peak_mb=peak,
                )
            if now > deadline:
                _stop(proc, term_first=True)
                return GuardOutcome(
                    "timeout",
                    reason=f"still running after {now - t0:.1f} s, past its time limit; stopped",
                    seconds=now - t0,
                    peak_mb=peak,
                )
            if cancel is not None and cancel.is_set():
                _stop(proc, term_first=True)
                return GuardOutcome("interrupted", reason="stopped", seconds=now - t0)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(10)
        took = time.monotonic() - t0
        if result is None:
            code = proc.returncode
            how = (
                f"was killed by signal {-code}"
                if code is not None and code < 0
                else f"exited with status {code}"
            )
            if code == -signal.SIGKILL:
                how += " (the system's out-of-memory killer?)"
            return GuardOutcome(
                "failed",
                reason=f"the planner's process {how}{_last_line(log_path)}",
                seconds=took,
                peak_mb=peak,
            )
        if result[0] == "ok":
            return GuardOutcome("ok", value=result[1], seconds=took, peak_mb=peak)
        if result[0] == "memory":
            return GuardOutcome(
                "memory", reason=f"out of memory: {result[1]}", seconds=took, peak_mb=peak
            )
        return GuardOutcome("failed", reason=result[1], seconds=took, peak_mb=peak)
    finally:
        if proc.poll() is None:
            _stop(proc, term_first=False)
        os.close(rfd)
        if not isinstance(out, int):
            out.close()


# ------------------------------------------------------------------ in the child


def _child(fd: int) -> int:
    def send_raw(obj: Any) -> None:
        data = pickle.dumps(obj)
        view = memoryview(_HEADER.pack(len(data)) + data)
        while view:
            view = view[os.write(fd, view) :]

    def send(obj: Any) -> None:
        send_raw(("msg", obj))

    def terminated(signum: int, frame: Any) -> None:
        raise SystemExit(143)

    signal.signal(signal.SIGTERM, terminated)
    # a caller that dies (kill -9 of the batch, a Dask worker ended) cannot stop us:
    # we end ourselves once we are an orphan, whatever the planner is doing
    parent = os.getppid()

    def orphaned() -> None:
        while True:
            time.sleep(0.5)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=orphaned, name="guard-orphan", daemon=True).start()
    # the caller owns Ctrl-C (a terminal sends it to the whole group: ours is our own)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    target, arg = pickle.load(sys.stdin.buffer)
    module_name, _, name = target.partition(":")
    try:
        fn = getattr(importlib.import_module(module_name), name)
        value = fn(arg, send)
    except MemoryError as err:
        send_raw(("memory", f"the planner's process could not allocate: {err}"))
        return 1
    except Exception as err:  # the caller decides what a failure means
        log.debug("guarded %s raised", target, exc_info=True)
        send_raw(("error", f"{type(err).__name__}: {err}"))
        return 1
    send_raw(("ok", value))
    return 0


if __name__ == "__main__":
    logging.basicConfig(
        level=int(sys.argv[2]) if len(sys.argv) > 2 else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    raise SystemExit(_child(int(sys.argv[1])))
