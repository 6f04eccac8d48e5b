"""Start-up and memory budgets of the built-in planners (issue 37): a planner
on an instance too big for its memory budget sizes its batches, candidates,
tree and tables down instead of allocating past it; a start-up allowance too
short for some start-up work skips it with a WARNING naming it; exact refuses
an instance whose table would exceed its budget, with a clear message."""

from __future__ import annotations

import logging
import resource
import threading
import time
from pathlib import Path

import pytest
from ippc.planners import PlannerError
from ippc.planners import basic as basic_module
from ippc.planners.base import Observation, SessionInfo
from ippc.planners.basic import UniformPlanner
from ippc.planners.budget import (
    MIB,
    OneAtATime,
    Startup,
    StartupOverrun,
    memory_budget,
    rows_within,
    run_within,
    state_bytes,
    step_cost,
)
from ippc.planners.exact import ExactPlanner, ExactUnsupported, solve, table_bytes
from ippc.planners.mcts import MCTSPlanner
from ippc.planners.replan import ReplanPlanner
from ippc.rddl import load
from ippc.rddl.model import Model
from ippc.rddl.simulator import Simulator

TINY = Path(__file__).resolve().parent / "tiny_domains"

# A state of N x N reals (N = 120: 115 KB a state): a batch of 1024 of them
# alone is 118 MB, far past a budget of a few MiB.
WIDE = """
domain wide {
    requirements = { concurrent, reward-deterministic };
    types { item : object; };
    pvariables {
        level(item, item) : { state-fluent, real, default = 0.0 };
        push(item) : { action-fluent, bool, default = false };
    };
    cpfs {
        level'(?a, ?b) = level(?a, ?b) + (if (push(?a)) then Normal(1.0, 1.0) else 0.0);
    };
    reward = [sum_{?a : item, ?b : item} level(?a, ?b)] / 1000.0;
}
non-fluents wide_nf {
    domain = wide;
    objects { item : {%s}; };
}
instance wide_inst {
    domain = wide;
    non-fluents = wide_nf;
    max-nondef-actions = 1;
    horizon = 10;
    discount = 1.0;
}
"""

# Sixteen independent bits, each set by its own action: 65,536 reachable
# states, a table far past a budget of 1 MiB.
BITS = """
domain bits {
    requirements = { concurrent };
    types { bit : object; };
    pvariables {
        on(bit) : { state-fluent, bool, default = false };
        set(bit) : { action-fluent, bool, default = false };
    };
    cpfs { on'(?b) = on(?b) | (set(?b) ^ Bernoulli(0.5)); };
    reward = [sum_{?b : bit} on(?b)];
}
non-fluents bits_nf { domain = bits; objects { bit : {%s}; }; }
instance bits_inst {
    domain = bits;
    non-fluents = bits_nf;
    max-nondef-actions = 2;
    horizon = 20;
    discount = 1.0;
}
"""


def model_of(tmp_path: Path, text: str, name: str) -> Model:
    f = tmp_path / f"{name}.rddl"
    f.write_text(text)
    return load(f)[name]


def wide(tmp_path: Path, n: int = 120) -> Model:
    return model_of(tmp_path, WIDE % ", ".join(f"i{k}" for k in range(n)), "wide_inst")


def bits(tmp_path: Path, n: int = 16) -> Model:
    return model_of(tmp_path, BITS % ", ".join(f"b{k}" for k in range(n)), "bits_inst")


def tiny(name: str) -> Model:
    return load(TINY / f"{name}.rddl")[f"tiny_{name}_inst"]


def session_of(model: Model, sim: Simulator | None = None) -> SessionInfo:
    return SessionInfo(
        model.name, model, sim or Simulator(model), rounds=1, time_allowed=60.0, seed=1
    )


def first_turn(sim: Simulator, deadline: float = 0.2) -> Observation:
    horizon = sim.model.horizon or 10
    return Observation(
        None, sim.initial_state(1), 1, horizon, 60.0, 0.0, time.monotonic() + deadline
    )


# ------------------------------------------------------------------ the budget


def test_memory_budget_is_the_option_else_a_quarter_of_what_is_available() -> None:
    assert memory_budget(3.0) == 3 * MIB
    with open("/proc/meminfo", encoding="ascii") as fh:
        avail = next(int(line.split()[1]) * 1024 for line in fh if line.startswith("MemAvailable"))
    # (MemAvailable moves between the two reads: 5% either way; an address-space
    # limit, as `ulimit -v` sets, may lower the budget further)
    assert memory_budget(None) <= 0.3 * avail
    if resource.getrlimit(resource.RLIMIT_AS)[0] == resource.RLIM_INFINITY:
        assert memory_budget(None) >= 0.2 * avail


def test_step_cost_counts_the_temporaries_of_a_wide_state(tmp_path: Path) -> None:
    sim = Simulator(wide(tmp_path))
    cost = step_cost(sim)
    one = state_bytes(sim)
    assert one == 120 * 120 * 8
    # the next state at least, besides the state the batch holds
    assert cost.per_row >= one
    assert cost.bytes_for(1024) > 100 * MIB
    assert rows_within(4 * MIB, cost, 1024) == (4 * MIB - cost.fixed) // cost.per_row
    assert rows_within(1, cost, 1024) == 1  # never below one row


def test_run_within_abandons_work_past_its_deadline() -> None:
    stop = threading.Event()

    def forever() -> None:
        while not stop.is_set():
            sum(range(1000))

    before = threading.active_count()
    with pytest.raises(StartupOverrun, match="looping did not end within 0.1 s"):
        run_within(forever, 0.1, "looping")
    # the worker was asked to stop at its next instruction, and did
    for _ in range(200):
        if threading.active_count() == before:
            break
        time.sleep(0.01)
    stop.set()
    assert threading.active_count() == before
    assert run_within(lambda: 7, 5.0, "adding") == 7
    with pytest.raises(ZeroDivisionError):
        run_within(lambda: 1 / 0, 5.0, "dividing")


def test_one_at_a_time_lets_a_late_piece_finish_and_starts_none_meanwhile() -> None:
    release = threading.Event()
    runner = OneAtATime("test")
    assert runner.call(lambda: release.wait(10.0) and 1, 0.05) == (False, None)
    assert runner.busy()
    assert runner.call(lambda: 2, 5.0) == (False, None)  # the late piece still runs
    release.set()
    for _ in range(200):
        if not runner.busy():
            break
        time.sleep(0.01)
    assert runner.call(lambda: 3, 5.0) == (True, 3)
    assert runner.late == 2


def test_startup_skip_logs_what_and_why(caplog: pytest.LogCaptureFixture) -> None:
    clock = iter([0.0, 4.0, 4.0]).__next__
    startup = Startup("mcts", "x_inst", 3.0, clock=clock)
    with caplog.at_level(logging.WARNING):
        assert not startup.fits(0.0)
        startup.skip("compiling", "no time")
    assert startup.skipped == ["compiling"]
    assert "mcts: x_inst: start-up: compiling skipped (no time); 4.00 s of the 3.00 s" in (
        caplog.text
    )


# ------------------------------------------------------------------ mcts


def test_mcts_wave_shrinks_batch_candidates_and_tree_to_a_tiny_budget(tmp_path: Path) -> None:
    model = wide(tmp_path)
    sim = Simulator(model)
    planner = MCTSPlanner(engine="wave", memory="4", iterations="2", seed="1")
    planner.start_session(session_of(model, sim))
    sizing = planner.budgets.sizing  # type: ignore[union-attr]
    assert sizing is not None and sizing.budget == 4 * MIB and sizing.cost is not None
    # a batch's step fits in half the budget; the asked-for 1024 would not
    assert sizing.cost.bytes_for(1024) > 2 * MIB
    assert 1 <= planner.settings.batch < 1024
    assert sizing.cost.bytes_for(planner.settings.batch) <= 2 * MIB or planner.settings.batch == 1
    # a leaf's candidates x 2 roll-out modes fit in a batch (but a choice of two is kept)
    assert planner.settings.max_actions <= max(2, planner.settings.batch // 2)
    # the tree's nodes (each its state twice) fit in the other half
    assert planner.settings.max_nodes * 2 * state_bytes(sim) <= 2 * MIB
    assert planner.settings.max_nodes < 200_000
    # what was asked stays as asked, for the next session
    assert planner._asked.batch == 1024 and planner._asked.max_nodes == 200_000
    planner.start_round(1)
    actions = planner.act(first_turn(sim))
    assert len(actions) <= 1  # max-nondef-actions = 1: one push at most


def test_mcts_wave_stops_growing_the_tree_at_max_nodes(
    caplog: pytest.LogCaptureFixture,
) -> None:
    model = tiny("bandit")
    sim = Simulator(model)
    planner = MCTSPlanner(engine="wave", max_nodes="3", iterations="40", batch="16", seed="2")
    planner.start_session(session_of(model, sim))
    planner.start_round(1)
    with caplog.at_level(logging.WARNING):
        planner.act(first_turn(sim))
    assert planner.last_turn.waves < 40  # stopped before the 40 asked for
    assert "as many as the memory budget allows (max_nodes)" in caplog.text
    # without the bound, the 40 waves run
    free = MCTSPlanner(engine="wave", iterations="40", batch="16", seed="2")
    free.start_session(session_of(model, sim))
    free.start_round(1)
    free.act(first_turn(sim))
    assert free.last_turn.waves == 40


def test_mcts_thts_sizes_its_tree_to_the_budget() -> None:
    model = tiny("bandit")
    planner = MCTSPlanner(memory="1", compiled="no", seed="1")
    planner.start_session(session_of(model))
    sizing = planner.budgets.sizing  # type: ignore[union-attr]
    assert sizing is not None
    assert planner.settings.max_nodes == (MIB // 2) // sizing.node_bytes < 200_000


def test_mcts_startup_of_zero_runs_the_wave_engine_and_still_acts(
    caplog: pytest.LogCaptureFixture,
) -> None:
    model = tiny("trap")
    sim = Simulator(model)
    planner = MCTSPlanner(startup="0", seed="1")
    with caplog.at_level(logging.WARNING):
        planner.start_session(session_of(model, sim))
    assert planner.budgets is not None
    assert planner.budgets.startup.skipped[0] == "translating the instance into the scalar step"
    assert "start-up: translating the instance into the scalar step skipped (no start-up time " in (
        caplog.text
    )
    assert "the wave engine" in caplog.text
    assert planner.engine == "wave" and not planner.compiled
    planner.start_round(1)
    names = {name for name, _, _ in planner.act(first_turn(sim))}
    assert names <= {"safe", "risky"}


def test_mcts_thts_startup_fallbacks_warn_what_they_skip(
    caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    from ippc.planners.mcts import planner as planner_module

    def late(scalar: object) -> list[tuple[str, tuple[int, ...]]]:
        raise StartupOverrun("the relevance analysis did not end within 0.0 s")

    # the analysis late, and less time left than IDS's learning needs
    monkeypatch.setattr(planner_module, "useless_actions", late)
    monkeypatch.setattr(planner_module, "IDS_SECONDS", 1e9)
    monkeypatch.setattr(planner_module, "ENUM_SECONDS", 1e9)
    model = tiny("trap")
    sim = Simulator(model)
    planner = MCTSPlanner(seed="1")
    with caplog.at_level(logging.WARNING):
        planner.start_session(session_of(model, sim))
    if planner.engine != "thts":
        pytest.skip("no C compiler here: the thts engine does not run")
    skipped = planner.budgets.startup.skipped  # type: ignore[union-attr]
    assert "the relevance analysis (prune_useless)" in skipped
    assert "learning IDS's depth" in skipped
    assert "start-up: the relevance analysis (prune_useless) skipped" in caplog.text
    assert "every action grounding kept" in caplog.text
    assert "start-up: learning IDS's depth skipped (less than 1e+09 s of the start-up " in (
        caplog.text
    )
    assert "roll-outs, no IDS" in caplog.text
    assert planner._thts is not None and planner._thts.ids_depth == 0  # roll-outs
    planner.start_round(1)
    names = {name for name, _, _ in planner.act(first_turn(sim))}
    assert names <= {"safe", "risky"}


def test_mcts_wave_startup_skips_ids(caplog: pytest.LogCaptureFixture) -> None:
    model = tiny("bandit")
    planner = MCTSPlanner(engine="wave", heuristic="ids", startup="0", seed="1")
    with caplog.at_level(logging.WARNING):
        planner.start_session(session_of(model))
    assert planner._expander is not None and planner._expander.ids is None
    assert "start-up: IDS and the reward-lock check" in caplog.text
    assert "roll-outs instead" in caplog.text


def test_mcts_wave_turn_past_its_deadline_sends_noop(
    caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    model = tiny("bandit")
    sim = Simulator(model)
    planner = MCTSPlanner(engine="wave", time_per_step="0.05", seed="1")
    planner.start_session(session_of(model, sim))
    planner.start_round(1)
    release = threading.Event()
    real = planner._act
    monkeypatch.setattr(planner, "_act", lambda obs: release.wait(10.0) and real(obs))
    with caplog.at_level(logging.WARNING):
        assert planner.act(first_turn(sim, 0.05)) == []
        assert planner.act(first_turn(sim, 0.05)) == []  # the late turn still runs
    assert "mcts: turn 1: no action by the turn's deadline" in caplog.text
    release.set()
    monkeypatch.setattr(planner, "_act", real)
    for _ in range(500):
        if not planner.budgets.turns.busy():  # type: ignore[union-attr]
            break
        time.sleep(0.01)
    assert {n for n, _, _ in planner.act(first_turn(sim, 0.5))} <= {"pull"}


# ------------------------------------------------------------------ exact


def test_exact_refuses_a_table_past_its_budget_before_allocating_it(tmp_path: Path) -> None:
    model = bits(tmp_path)
    with pytest.raises(ExactUnsupported, match=r"memory budget of 1 MiB \(option memory\)"):
        solve(model, max_states=100_000, memory=MIB)
    planner = ExactPlanner(memory="1", max_states="100000")
    with pytest.raises(PlannerError) as err:
        planner.start_session(session_of(model))
    message = str(err.value)
    assert message.startswith("cannot solve bits_inst: its table needs more than the memory")
    assert "found so far" in message
    assert planner.solution is None


def test_exact_table_bytes_and_a_table_within_budget(tmp_path: Path) -> None:
    # 16 states x 137 joint actions (at most 2 of 16 set) x 21 values, one bit each
    assert table_bytes(2, 3, 4, 5, 6) == 2 * (4 + 3 * (1 + 8 + 8 * 6) + 8 * 6) + 6 * 75
    model = bits(tmp_path, 4)
    sol = solve(model, memory=64 * MIB)
    assert len(sol.bits) == 16


def test_exact_refuses_a_solve_past_its_startup(tmp_path: Path) -> None:
    planner = ExactPlanner(startup="0")
    with pytest.raises(PlannerError, match=r"not solved within the start-up allowance of 0 s"):
        planner.start_session(session_of(bits(tmp_path, 12)))


# ------------------------------------------------------------------ replan


def test_replan_sizes_its_expansions_and_tree_to_a_tiny_budget(tmp_path: Path) -> None:
    model = wide(tmp_path)
    planner = ReplanPlanner(memory="2", expand="8", max_actions="64")
    planner.start_session(session_of(model))
    problem = planner.problem
    assert problem is not None
    det_cost = step_cost(problem.sim)
    assert det_cost.bytes_for(8 * 64) > MIB
    assert problem.expand * problem.max_actions * det_cost.per_row <= MIB or problem.expand == 1
    assert problem.expand < 8 and problem.max_actions >= 2
    assert problem.max_nodes * 2 * state_bytes(problem.sim) <= MIB


def test_replan_sends_noop_while_a_late_startup_finishes(
    caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    model = tiny("bandit")
    sim = Simulator(model)
    planner = ReplanPlanner(startup="0")
    release = threading.Event()
    real = planner._build
    monkeypatch.setattr(planner, "_build", lambda s: release.wait(10.0) and real(s))
    with caplog.at_level(logging.WARNING):
        planner.start_session(session_of(model, sim))
        planner.start_round(1)
        assert planner.act(first_turn(sim)) == []
    assert "start-up: the determinised search is not built within the start-up allowance" in (
        caplog.text
    )
    assert "still being built; noop" in caplog.text
    release.set()
    assert planner._building is not None
    planner._building.join(10.0)
    actions = planner.act(first_turn(sim, 1.0))
    assert planner.problem is not None
    assert {n for n, _, _ in actions} <= {"pull"}


# ------------------------------------------------------------------ uniform


def test_uniform_sends_noop_when_a_draw_is_late(
    caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    model = tiny("bandit")
    sim = Simulator(model)
    planner = UniformPlanner(seed="3")
    planner.start_session(session_of(model, sim))
    release = threading.Event()
    real = basic_module._uniform_action
    monkeypatch.setattr(basic_module, "_uniform_action", lambda *a: release.wait(10.0) and real(*a))
    with caplog.at_level(logging.WARNING):
        assert planner.act(first_turn(sim, 0.05)) == []
        assert planner.act(first_turn(sim, 0.05)) == []
    assert "uniform: turn 1: no legal joint action drawn by the turn's deadline" in caplog.text
    release.set()
    drawn: list[list[tuple[str, tuple[str, ...], object]]] = []
    monkeypatch.setattr(
        basic_module, "_uniform_action", lambda *a: drawn.append(real(*a)) or drawn[-1]
    )
    for _ in range(500):
        if not planner._draws.busy():
            break
        time.sleep(0.01)
    got = planner.act(first_turn(sim, 5.0))
    assert drawn == [got]  # the draw's own action, in time
    assert {n for n, _, _ in got} <= {"pull"} and len(got) <= 1


def test_mcts_late_compile_goes_on_without_the_c_step(
    caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    from ippc.planners.mcts import startup as startup_module

    release = threading.Event()
    monkeypatch.setattr(startup_module, "_c_builder", lambda: lambda scalar: release.wait(10.0))
    model = tiny("trap")
    planner = MCTSPlanner(startup="0.2", seed="1")
    with caplog.at_level(logging.WARNING):
        planner.start_session(session_of(model))
    assert "start-up: waiting for the C step's build skipped (not built after" in caplog.text
    assert "the wave engine until it is, then the compiled engine (thts)" in caplog.text
    assert not planner.compiled and planner._pending is not None
    assert planner._asked.compiled == "auto"
    planner.end_session(0.0)  # (tests/planners/test_mcts_startup.py: the switch)
    release.set()
    strict = MCTSPlanner(startup="0.2", compiled="yes", seed="1")
    release.clear()
    with pytest.raises(PlannerError, match="compiled=yes, but the C step is not built within"):
        strict.start_session(session_of(model))
    release.set()


def test_mcts_thts_late_ids_learning_goes_on_with_roll_outs(
    caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    from ippc.planners.mcts.thts import THTS

    release = threading.Event()
    monkeypatch.setattr(THTS, "learn_ids", lambda self, *a: release.wait(10.0) and 7)
    model = tiny("trap")
    planner = MCTSPlanner(startup="3", seed="1")
    with caplog.at_level(logging.WARNING):
        planner.start_session(session_of(model))
    release.set()
    if planner.engine != "thts":
        pytest.skip("no C compiler here: the thts engine does not run")
    assert "start-up: learning IDS's depth skipped (learning IDS's depth did not end within" in (
        caplog.text
    )
    assert planner._thts is not None and planner._thts.ids_depth == 0


def test_a_late_turn_waits_for_its_search_where_noop_is_illegal(
    caplog: pytest.LogCaptureFixture,
) -> None:
    from ippc.planners.budget import guarded_turn

    runner = OneAtATime("test")
    release = threading.Timer(1.0, lambda: None)
    release.start()

    def search() -> list[str]:
        release.join()
        return ["move"]

    with caplog.at_level(logging.WARNING):
        got = guarded_turn(runner, "test", 1, time.monotonic() - 1.0, search, lambda: False)
    assert got == ["move"]  # the late search's own action, not an illegal noop
    assert "noop is illegal here: waiting for the search" in caplog.text
    assert not runner.busy()
    late = threading.Timer(1.5, lambda: None)
    late.start()
    assert guarded_turn(runner, "test", 2, 0.0, lambda: late.join() or ["x"], lambda: True) == []
    late.join()
