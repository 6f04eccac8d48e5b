"""SIGTERM and SIGINT end rddl-dispatch cleanly: the running action is
cancelled, the session is closed `interrupted` (none left `open`), the
report and --json-out are written, and the exit status says which signal."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from ippc.server.store import ResultStore

from .conftest import DOMAIN, ONE

ROBOT = """
import trio
from pathlib import Path

def setup(robot):
    @robot.handler("*")
    async def hang(d):
        Path({marker!r}).write_text(str(d.action))
        await trio.sleep_forever()  # an action in progress when the signal comes
"""


@pytest.mark.alone
@pytest.mark.parametrize(("sig", "code"), [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_signal_interrupts_the_session_and_writes_the_report(
    tmp_path: Path, sig: signal.Signals, code: int
) -> None:
    marker = tmp_path / "started"
    robot = tmp_path / "robot.py"
    robot.write_text(ROBOT.format(marker=str(marker)))
    db, out = tmp_path / "r.db", tmp_path / "run.json"
    cmd = [sys.executable, "-m", "ippc.dispatch.cli", str(DOMAIN), str(ONE)]
    cmd += ["--robot", str(robot), "--planner", "exact", "--port", "0", "--db", str(db)]
    cmd += ["--json-out", str(out), "--action-timeout", "60", "-q"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not marker.exists():
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "no action was dispatched within 60 s"
            time.sleep(0.05)
        assert marker.read_text() == "move(r1,hall,office)"
        t0 = time.monotonic()
        proc.send_signal(sig)
        stdout, stderr = proc.communicate(timeout=20)
        took = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == code, stderr
    assert took < 10  # the hanging action did not hold the exit (its timeout is 60 s)
    assert f"interrupted by {sig.name}" in stderr
    assert "move(r1,hall,office)" in stdout  # the report, with the cancelled action
    report = json.loads(out.read_text())
    assert report["session_status"] == "interrupted" and report["interrupted"] == sig.name
    assert ["robot-at", ["r1", "hall"], True] in report["facts"]
    with ResultStore(db) as store:
        (session,) = store.sessions()
        assert session["status"] == "interrupted"
        assert all(r["status"] != "open" for r in store.rounds(session["id"]))
        assert store.kb_facts("courier_one")  # the journal is there for the next start


if os.name != "posix":  # pragma: no cover
    pytest.skip("signals are POSIX", allow_module_level=True)
