"""The progress line: counts, time left, and silence when stderr is not a terminal."""

from __future__ import annotations

import io

from ippc.batch.progress import Progress, format_duration


class Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_line_counts_and_quiet_without_a_terminal() -> None:
    quiet = io.StringIO()
    p = Progress(stream=quiet)
    p.start(total=4, done=1)
    p.started()
    p.ended(failed=True)
    p.close()
    assert quiet.getvalue() == ""  # not a TTY: nothing at all
    assert "2/4 sessions done, 0 running, 1 failed" in p.line()
    assert p.time_left() is not None and p.time_left() >= 0.0


def test_redraws_on_a_terminal() -> None:
    tty = Tty()
    p = Progress(stream=tty)
    p.start(total=2, done=0)
    p.started()
    p.started()
    p.close()
    text = tty.getvalue()
    assert text.startswith("\r[") and text.endswith("\n")
    assert "0/2 sessions done, 2 running, 0 failed, ? left" in text


def test_format_duration() -> None:
    assert [format_duration(s) for s in (5, 65, 3725)] == ["5s", "1m05s", "1h02m"]
