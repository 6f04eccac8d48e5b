"""The turn's deadline under load: `mcts` with `time_per_step` never
returns much later than that, also while another process keeps a core
busy. Timing, so `alone` (run with the machine to itself)."""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest
from ippc.planners import Observation, SessionInfo
from ippc.planners.mcts import MCTSPlanner
from ippc.rddl import load_pair
from ippc.rddl.simulator import Simulator
from ippc.rddl.wire import WireCodec

from ..conftest import ippc_files

pytestmark = pytest.mark.alone

BUDGET = 0.1
# What a turn may overrun its budget by: the search checks the clock between
# batched simulator calls and stops when the slowest recent one would end
# late, so the overrun is what is left after the last check. (On the shared
# machine at load 10-17 the worst of 20 turns was 0.116-0.156 s; this test
# is meant for a machine to itself but for the busy loop. In a fresh-clone
# `make test` at load 2-3 the worst was 0.128 s, so 20 ms was too tight; the
# mcts before the deadline work overran by 180-680 ms, which 50 ms still catches.)
SLACK = 0.05


@pytest.mark.parametrize(
    ("engine", "year", "domain", "n"),
    [
        ("wave", "IPPC2011", "Elevators", 1),
        ("wave", "IPPC2011", "CooperativeRecon", 2),
        ("thts", "IPPC2011", "Elevators", 1),
        ("thts", "IPPC2011", "CooperativeRecon", 2),
        # 813 candidate joint actions a state before pruning (thts probes them
        # all). The wave search is not held to it: it samples 128 candidates
        # for every new node there, 30-80 ms each (issue 21's missed deadlines).
        ("thts", "IPPC2014", "TriangleTireworld", 5),
    ],
)
def test_turns_keep_time_per_step_under_a_busy_loop(
    engine: str, year: str, domain: str, n: int
) -> None:
    model = load_pair(*ippc_files(year, domain, n))
    sim = Simulator(model)
    codec = WireCodec(sim)
    planner = MCTSPlanner(time_per_step=str(BUDGET), seed="1", engine=engine)
    planner.start_session(
        SessionInfo(model.name, model, sim, rounds=1, time_allowed=600.0, seed=None)
    )
    planner.start_round(1)
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    took: list[float] = []
    solved: list[bool] = []  # whether the turn's root was solved (thts)
    try:
        time.sleep(0.5)  # the busy loop is running before the first turn
        rng = np.random.default_rng(5)
        state = sim.initial_state(1)
        horizon = model.horizon or 40
        for turn in range(1, 21):
            obs = Observation(
                fluents={(n_, a): v for n_, a, v in codec.state(state)},
                state=state,
                turn=turn,
                steps_left=horizon - turn + 1,
                time_left=600.0,
                immediate_reward=0.0,
                deadline=time.monotonic() + 60.0,
            )
            t0 = time.monotonic()
            planner.act(obs)
            took.append(time.monotonic() - t0)
            search = planner._thts
            if search is not None:
                root = search.root(search.fast.encode_state(state), horizon - turn + 1)
                solved.append(root.solved)
            assert planner._last_action is not None
            state = sim.step(state, planner._last_action, rng).next_state
    finally:
        busy.kill()
        busy.wait(timeout=10)
    # every turn within the slack but two, which may meet scheduling hiccups of the
    # machine (fresh-clone CI runs on 2 cores, one taken by the busy loop, saw one 0.31 s
    # turn among nineteen of 0.1 s, and once a 0.28 s and a 0.19 s turn among eighteen
    # of 0.1 s for the wave engine); the overruns before the deadline work were most
    # turns, of 180-680 ms, which this still catches
    ordered = sorted(took)
    assert ordered[-3] <= BUDGET + SLACK and ordered[-1] <= 4 * BUDGET + SLACK, (
        f"turn times {[round(t, 3) for t in took]} s for a {BUDGET} s budget"
    )
    # and the budget is used, not given away (thts keeps a margin for its last trial,
    # which the busy loop's share of the CPU widens: medians of 0.077 s were seen in CI),
    # but where the root was solved: the turn then ends at once (the compiled thts engine
    # solves TriangleTireworld #5's root from the second turn on along this walk)
    searched = [t for t, done in zip(took, solved or [False] * len(took), strict=True) if not done]
    assert searched, (took, solved)
    assert float(np.median(searched)) >= 0.6 * BUDGET, (took, solved)
