"""Two planner plug-ins that a client cannot stop from inside, registered the way a
third party registers one: a package with an ``ippc.planners`` entry point, written
into a folder that goes on ``PYTHONPATH`` (so child processes find them too).

* ``stuck``: its start-up never returns (it sleeps, a second at a time, forever);
* ``hog``: its start-up allocates 16 MB after 16 MB, written to, without end (a safety
  cap at 4 GB, where it sleeps, keeps a broken guard from taking the machine).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

MODULE = '''
"""Planners that never return from start-up (written by tests/client/runaway.py)."""

import time

import numpy as np

from ippc.planners.base import Planner


class Stuck(Planner):
    name = "stuck"

    def start_session(self, session):
        while True:
            time.sleep(1.0)

    def act(self, obs):
        return []


class Hog(Planner):
    name = "hog"

    def start_session(self, session):
        hoard = []
        while len(hoard) < 256:  # 4 GB: only reached if nothing stops us
            hoard.append(np.ones(2 << 20))  # 16 MB, every page written
        while True:
            time.sleep(1.0)

    def act(self, obs):
        return []


# targets for ippc.client.guard.run_guarded: function(arg, send)


def echo(arg, send):
    send(("note", arg))
    return {"got": arg}


def wait_forever(arg, send):
    send(("budget", arg))
    while True:
        time.sleep(1.0)


def report_pid(arg, send):
    import os

    send(("pid", os.getpid()))
    while True:
        time.sleep(1.0)


def allocate(arg, send):
    Hog().start_session(None)


def fail(arg, send):
    raise ValueError(f"bad {arg}")
'''

ENTRY_POINTS = """[ippc.planners]
stuck = ippc_runaway_planners:Stuck
hog = ippc_runaway_planners:Hog
"""


def install(folder: Path) -> Path:
    """Write the plug-in package and its metadata into `folder`; returns it."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "ippc_runaway_planners.py").write_text(MODULE)
    info = folder / "ippc_runaway_planners-1.0.dist-info"
    info.mkdir(exist_ok=True)
    (info / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: ippc-runaway-planners\nVersion: 1.0\n"
    )
    (info / "entry_points.txt").write_text(ENTRY_POINTS)
    return folder


def register(monkeypatch: pytest.MonkeyPatch, folder: Path) -> dict[str, str]:
    """Make the plug-ins visible to this process and to the processes it starts;
    returns the environment for a subprocess."""
    install(folder)
    monkeypatch.syspath_prepend(str(folder))
    path = os.environ.get("PYTHONPATH")
    value = str(folder) if not path else f"{folder}{os.pathsep}{path}"
    monkeypatch.setenv("PYTHONPATH", value)
    env = dict(os.environ)
    env["PYTHONPATH"] = value
    assert sys.path[0] == str(folder)
    return env
