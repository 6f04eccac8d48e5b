"""What rddl-batch tells people: a line per job and a heartbeat without a terminal, a
tqdm bar on one."""

from __future__ import annotations

import io
import threading
import time

from ippc.batch.progress import Progress, format_duration


class Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


class Lines(io.StringIO):
    """A stream that several threads write (the heartbeat's and the run's)."""

    def __init__(self) -> None:
        super().__init__()
        self.lock = threading.Lock()

    def write(self, text: str) -> int:
        with self.lock:
            return super().write(text)


def test_one_line_per_job_without_a_terminal() -> None:
    out = Lines()
    p = Progress(stream=out, heartbeat=0)
    p.start(total=4, done=1)
    p.started("mcts@a")
    p.started("noop@a")
    p.ended(
        "mcts@a", "finished", planner="mcts", instance="a", mean=-890.2500000000006, seconds=12.34
    )
    p.ended(
        "noop@a", "failed", planner="noop", instance="a", mean=None, seconds=0.5, reason="it broke"
    )
    p.close()
    assert out.getvalue().splitlines() == [
        "3 of 4 jobs to play",
        "[2/4] finished  mcts  a  mean reward -890.2500  12.3 s  2 jobs left",
        "[3/4] failed    noop  a  mean reward -  0.5 s  1 job left: it broke",
    ]
    assert "3/4 jobs done, 0 running, 1 failed" in p.line()
    assert p.time_left() is not None and p.time_left() >= 0.0


def test_a_heartbeat_when_nothing_was_said_for_a_while() -> None:
    out = Lines()
    p = Progress(stream=out, heartbeat=0.2)
    p.start(total=2, done=0)
    p.started("mcts@a")
    deadline = time.monotonic() + 30
    try:
        while "..." not in out.getvalue():
            assert time.monotonic() < deadline, out.getvalue()
            time.sleep(0.05)
    finally:
        p.close()
    beat = out.getvalue().splitlines()[1]
    assert beat.startswith("... 0/2 jobs done, 1 running (mcts@a 0s), 0 failed, 0s elapsed")
    assert beat.endswith(", ? left")


def test_a_bar_on_a_terminal() -> None:
    tty = Tty()
    p = Progress(stream=tty)
    p.start(total=2, done=0)
    p.started("x@a")
    p.started("y@a")
    p.ended("x@a", "timeout", planner="x", instance="a", mean=1.0, seconds=3, reason="too long")
    p.close()
    text = tty.getvalue()
    assert "\r" in text and "1/2" in text and "1 running, 0 failed" in text
    # what did not finish is printed above the bar
    assert "[1/2] timeout   x  a  mean reward 1.0000  3.0 s  1 job left: too long\n" in text


def test_silent_without_a_stream() -> None:
    p = Progress(stream=None)
    p.start(total=1, done=0)
    p.started("x@a")
    p.ended("x@a", "finished", planner="x", instance="a")
    p.close()
    assert p.done == 1


def test_format_duration() -> None:
    assert [format_duration(s) for s in (5, 65, 3725)] == ["5s", "1m05s", "1h02m"]
