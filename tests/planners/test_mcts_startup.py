"""mcts's C build does not hold up the first action (issue 37): a build
that is late (here held on an event) leaves the session on the wave engine
with a WARNING, and the first turn after it has ended switches to the
compiled engine with an INFO line; a build that fails keeps the wave
engine, which goes on playing legal actions; with `iterations` a late
build means the wave engine for the whole session. `Background` and the
compile cache's one-build-at-a-time rule underneath. No timed assertions:
the build is released by the test, and every wait is bounded."""

from __future__ import annotations

import logging
import os
import stat
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from ippc.planners.base import Observation, SessionInfo
from ippc.planners.budget import Background
from ippc.planners.mcts import MCTSPlanner
from ippc.planners.mcts import startup as startup_module
from ippc.rddl import load
from ippc.rddl.model import Model
from ippc.rddl.sim import cbuild
from ippc.rddl.sim.cstep import CUnavailable, find_compiler
from ippc.rddl.simulator import Simulator

TINY = Path(__file__).resolve().parent / "tiny_domains"
LEGAL = {"safe", "risky"}

needs_cc = pytest.mark.skipif(find_compiler() is None, reason="no C compiler")


def trap() -> Model:
    return load(TINY / "trap.rddl")["tiny_trap_inst"]


def session_of(model: Model, sim: Simulator) -> SessionInfo:
    return SessionInfo(model.name, model, sim, rounds=1, time_allowed=60.0, seed=1)


def turn(sim: Simulator, n: int, seconds: float = 0.1) -> Observation:
    steps = (sim.model.horizon or 10) - n + 1
    return Observation(None, sim.initial_state(1), n, steps, 60.0, 0.0, time.monotonic() + seconds)


def held_build(monkeypatch: pytest.MonkeyPatch, then: Callable[[Any], Any]) -> threading.Event:
    """The C build waits for the returned event, then does `then(scalar)`;
    the session waits a hundredth of its allowance for it, so that the
    scalar step's translation before it still has the time it needs."""
    release = threading.Event()

    def build(scalar: Any) -> Any:
        release.wait(600.0)
        return then(scalar)

    monkeypatch.setattr(startup_module, "_c_builder", lambda: build)
    monkeypatch.setattr(startup_module, "COMPILE_SHARE", 0.01)
    return release


def settle(planner: MCTSPlanner) -> None:
    """Wait (bounded) until the background set-up and any late wave turn have ended."""
    assert planner._pending is not None
    assert planner._pending.wait(600.0)
    assert planner.budgets is not None
    for _ in range(6000):
        if not planner.budgets.turns.busy():
            return
        time.sleep(0.01)


def names(actions: list[Any]) -> set[str]:
    return {name for name, _, _ in actions}


@needs_cc
def test_a_late_build_plays_the_wave_engine_then_switches_to_the_compiled_one(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    release = held_build(monkeypatch, startup_module.Kernels)
    model = trap()
    sim = Simulator(model)
    planner = MCTSPlanner(startup="60", time_per_step="0.3", seed="1")
    with caplog.at_level(logging.INFO):
        planner.start_session(session_of(model, sim))
        planner.start_round(1)
        assert planner.engine == "wave" and not planner.compiled
        assert "start-up: waiting for the C step's build skipped (not built after " in caplog.text
        assert "the wave engine until it is, then the compiled engine (thts)" in caplog.text
        assert planner.budgets is not None
        assert planner.budgets.startup.skipped == ["waiting for the C step's build"]
        # turns while the build is held: the wave engine's
        for n in (1, 2):
            assert names(planner.act(turn(sim, n))) <= LEGAL
            assert planner.engine == "wave" and planner._thts is None
        assert "compiled engine (thts) from turn" not in caplog.text
        release.set()
        settle(planner)
        assert planner.stats.waves > 0  # (a late wave turn counts once it has ended)
        caplog.clear()
        got = planner.act(turn(sim, 3))
    assert names(got) <= LEGAL
    assert planner.engine == "thts" and planner.compiled
    assert planner._thts is not None and planner._thts.tree is not None
    assert planner._expander is None  # the wave engine's search is let go
    assert planner.last_turn.trials > 0 and planner.last_turn.waves == 0  # a thts turn
    switched = [r for r in caplog.records if "compiled engine (thts) from turn 3 on" in r.message]
    assert len(switched) == 1 and switched[0].levelno == logging.INFO
    assert "the C step is built (" in switched[0].message
    # the turns after stay on it, and a new round resets its tree
    planner.start_round(2)
    assert names(planner.act(turn(sim, 1))) <= LEGAL and planner.engine == "thts"
    planner.end_session(0.0)


def test_a_failed_build_keeps_the_wave_engine(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    def fail(scalar: Any) -> Any:
        raise CUnavailable("cc failed: held, then refused by the test")

    release = held_build(monkeypatch, fail)
    model = trap()
    sim = Simulator(model)
    planner = MCTSPlanner(startup="60", time_per_step="0.05", seed="1")
    with caplog.at_level(logging.WARNING):
        planner.start_session(session_of(model, sim))
        planner.start_round(1)
        assert names(planner.act(turn(sim, 1))) <= LEGAL
        release.set()
        settle(planner)
        for n in (2, 3, 4):
            assert names(planner.act(turn(sim, n))) <= LEGAL
    assert planner.engine == "wave" and not planner.compiled and planner._thts is None
    assert planner._pending is None
    assert planner.last_turn.waves > 0
    assert (
        "no compiled engine (CUnavailable: cc failed: held, then refused by the test); "
        "the wave engine for the session"
    ) in caplog.text
    assert caplog.text.count("no compiled engine") == 1


def test_a_session_that_ends_first_sets_nothing_up(monkeypatch: pytest.MonkeyPatch) -> None:
    release = held_build(monkeypatch, lambda scalar: "a C step")
    model = trap()
    sim = Simulator(model)
    planner = MCTSPlanner(startup="60", seed="1")
    set_up: list[object] = []
    monkeypatch.setattr(planner, "_setup_thts", lambda *a: set_up.append(a))
    planner.start_session(session_of(model, sim))
    pending = planner._pending
    assert pending is not None
    planner.end_session(0.0)
    release.set()
    assert pending.wait(600.0)
    assert pending.result() is None and set_up == []
    assert planner._pending is None and planner.engine == "wave"


def test_with_iterations_a_late_build_is_the_wave_engine_for_the_session(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    release = held_build(monkeypatch, startup_module.Kernels)
    model = trap()
    sim = Simulator(model)
    # (iterations: the whole allowance is waited for, so a short one)
    planner = MCTSPlanner(startup="2", iterations="3", seed="1")
    with caplog.at_level(logging.WARNING):
        planner.start_session(session_of(model, sim))
    release.set()
    assert "the wave engine for the session (iterations)" in caplog.text
    assert planner._pending is None and planner.engine == "wave"
    planner.start_round(1)
    assert names(planner.act(turn(sim, 1))) <= LEGAL
    assert planner.last_turn.waves == 3


# ------------------------------------------------------------------ underneath


def test_background_hands_over_its_value_or_its_error() -> None:
    gate = threading.Event()
    work = Background("test", lambda: gate.wait(600.0) and 42)
    assert not work.wait(0.01) and not work.done()
    gate.set()
    assert work.wait(600.0) and work.result() == 42 and work.seconds() >= 0.0

    def boom() -> int:
        raise ValueError("no")

    failed = Background("test", boom)
    with pytest.raises(ValueError, match="no"):
        failed.result()
    assert failed.done()


@needs_cc
def test_two_builds_of_one_text_at_once_compile_it_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A session's build still running in the background and the next
    session's build of the same instance: one compiler run, one library."""
    log = tmp_path / "runs"
    fake = tmp_path / "counting-cc"
    fake.write_text(f'#!/bin/sh\necho run >> "{log}"\nsleep 1\nexec {find_compiler()} "$@"\n')
    fake.chmod(fake.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("CC", str(fake))
    monkeypatch.setenv("IPPC_CACHE", str(tmp_path / "cache"))
    source = "double ippc_test_one(void) { return 1.0; }\n"
    builds = [Background("build", lambda: cbuild.build(source)) for _ in range(2)]
    paths = {b.result() for b in builds}
    assert len(paths) == 1 and log.read_text().count("run") == 1
    (path,) = paths
    assert path.parent == tmp_path / "cache" / "cstep"
    assert not os.stat(path).st_mode & (stat.S_IWGRP | stat.S_IWOTH)
