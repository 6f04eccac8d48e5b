"""The paper's print-fetching domain (domains/print_fetch): its instances are
generated from the office's numbers, each action does what the docs say and
costs what the docs say, the exogenous fluents follow the paper's rates, the
goal latches, and it plays over the wire with PROST's framing."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trio
from click.testing import CliRunner
from ippc.experiments.print_fetch.office import (
    EXPERIMENTS,
    PRINTERS,
    ROBOT,
    WAYPOINTS,
    distance,
    instance_path,
    instance_text,
)
from ippc.planners import ProstPlanner
from ippc.rddl import load
from ippc.rddl.cli import main as rddl_main
from ippc.rddl.model import Model
from ippc.rddl.simulator import SimulationError, Simulator, State

from ..client.loopback import our_server, settled
from ..planners.conftest import FAKE_PARSER, FAKE_PROST

REPO = Path(__file__).resolve().parents[2]
FOLDER = REPO / "domains" / "print_fetch"
R = ROBOT


@pytest.fixture(scope="module")
def models() -> dict[str, Model]:
    return load(FOLDER)


@pytest.fixture(scope="module")
def sim(models: dict[str, Model]) -> Simulator:
    # experiment 1: start at prof_office, deliver to phd_area
    return Simulator(models["print_fetch_exp1"])


def state(
    sim: Simulator,
    at: str,
    carrying: bool = False,
    somebody: tuple[str, ...] = (),
    busy: tuple[str, ...] = (),
    delivered: bool = False,
) -> State:
    """A state of one robot, by names (`delivered`: the destination has its
    papers and the goal holds)."""
    points = sim.model.objects("waypoint")
    s = sim.initial_state()
    v = {k: np.zeros_like(a) for k, a in s.values.items()}
    v["robot_at"][0, 0, points.index(at)] = True
    v["carrying"][0, 0] = carrying
    for w in somebody:
        v["somebody_at"][0, points.index(w)] = True
    for w in busy:
        v["is_busy"][0, points.index(w)] = True
    if delivered:
        for (name, args), value in sim.model.non_fluent_values.items():
            if name == "DELIVERY_DESTINATION" and value:
                v["delivered"][0, points.index(args[0])] = True
        v["goal"][0] = True
    return State(v)


def step(sim: Simulator, s: State, *actions: tuple[str, tuple[str, ...]], seed: int = 0):
    acts = sim.actions_from_names({a: True for a in actions})
    out = sim.step(s, acts, np.random.default_rng(seed))
    return sim.state_to_names(out.next_state), float(out.reward[0])


def where(names: dict[str, object]) -> list[str]:
    return [k for k, v in names.items() if k.startswith("robot_at(") and v]


# ------------------------------------------------------------ the files


def test_instances_are_generated_from_the_office() -> None:
    for experiment in EXPERIMENTS.values():
        path = instance_path(FOLDER, experiment)
        assert path.read_text(encoding="utf-8") == instance_text(experiment), (
            f"{path.name} differs from its generator: "
            "python -m ippc.experiments.print_fetch instances"
        )


def test_rddl_check_accepts_every_instance() -> None:
    result = CliRunner().invoke(rddl_main, ["check", str(FOLDER)])
    assert result.exit_code == 0, result.output
    assert "4 checked (4 instances): 4 ok, 0 failed" in result.output


def test_distances_are_euclidean_and_rates_are_table_1(models: dict[str, Model]) -> None:
    m = models["print_fetch_exp4"]
    nf = m.non_fluent_values
    assert nf[("DISTANCE", ("prof_office", "p2"))] == pytest.approx(math.hypot(11, 3), abs=1e-4)
    assert nf[("DISTANCE", ("dock", "p1"))] == pytest.approx(3.0)
    for a in WAYPOINTS:
        for b in WAYPOINTS:
            if a != b:
                assert nf[("DISTANCE", (a, b))] == pytest.approx(distance(a, b), abs=1e-4)
    for p, (busy, person) in PRINTERS.items():
        assert nf[("BUSY_RATE", (p,))] == busy
        assert nf[("PERSON_RATE", (p,))] == person
    assert PRINTERS == {"p1": (0.5, 0.9), "p2": (0.2, 0.4), "p3": (0.8, 0.5)}


@pytest.mark.parametrize(
    "number,start,destination",
    [(1, "prof_office", "phd_area"), (2, "phd_area", "kitchen"), (3, "dock", "prof_office"),
     (4, "phd_area", "prof_office")],
)  # fmt: skip
def test_each_experiment_starts_and_delivers_where_table_2_says(
    models: dict[str, Model], number: int, start: str, destination: str
) -> None:
    m = models[f"print_fetch_exp{number}"]
    assert m.init_state[("robot_at", (R, start))] is True
    dests = [a for (n, a), v in m.non_fluent_values.items() if n == "DELIVERY_DESTINATION" and v]
    assert dests == [(destination,)]
    assert (m.horizon, m.discount, m.max_nondef_actions) == (20, 1.0, 1)


# ------------------------------------------------------------ actions


PENDING = 60.0  # PENDING_SECONDS: every step before the delivery


def test_goto_moves_and_costs_two_seconds_a_metre(sim: Simulator) -> None:
    names, reward = step(
        sim, state(sim, "prof_office"), ("goto_waypoint", (R, "prof_office", "p2"))
    )
    assert where(names) == [f"robot_at({R},p2)"]
    assert reward == pytest.approx(-2.0 * math.hypot(11, 3) - PENDING, abs=1e-3)
    assert names[f"carrying({R})"] is False and names["goal"] is False


def test_goto_needs_the_robot_there_and_another_place(sim: Simulator) -> None:
    with pytest.raises(SimulationError):
        step(sim, state(sim, "prof_office"), ("goto_waypoint", (R, "dock", "p2")))
    with pytest.raises(SimulationError):
        step(sim, state(sim, "p2"), ("goto_waypoint", (R, "p2", "p2")))


def test_wait_load_with_somebody_at_a_free_printer_loads_the_papers(sim: Simulator) -> None:
    names, reward = step(sim, state(sim, "p1", somebody=("p1",)), ("wait_load", (R, "p1")))
    assert names[f"carrying({R})"] is True
    assert reward == pytest.approx(-20.0 - PENDING)  # LOAD_SECONDS
    assert where(names) == [f"robot_at({R},p1)"]


def test_wait_load_with_nobody_there_fails_after_the_timeout(sim: Simulator) -> None:
    names, reward = step(sim, state(sim, "p2"), ("wait_load", (R, "p2")))
    assert names[f"carrying({R})"] is False
    assert reward == pytest.approx(-60.0 - PENDING)  # NOBODY_SECONDS


def test_wait_load_at_a_busy_printer_fails_after_the_longer_timeout(sim: Simulator) -> None:
    s = state(sim, "p3", somebody=("p3",), busy=("p3",))
    names, reward = step(sim, s, ("wait_load", (R, "p3")))
    assert names[f"carrying({R})"] is False
    assert reward == pytest.approx(-75.0 - PENDING)  # BUSY_SECONDS
    # busy and nobody: nobody to help is what the robot waits for
    names, reward = step(sim, state(sim, "p3", busy=("p3",)), ("wait_load", (R, "p3")))
    assert names[f"carrying({R})"] is False and reward == pytest.approx(-60.0 - PENDING)


def test_wait_load_only_at_a_printer_with_an_empty_tray_before_the_goal(sim: Simulator) -> None:
    for s, at in [
        (state(sim, "kitchen", somebody=("kitchen",)), "kitchen"),
        (state(sim, "p1", carrying=True, somebody=("p1",)), "p1"),
        (state(sim, "p1", somebody=("p1",), delivered=True), "p1"),
        (state(sim, "p2", somebody=("p1",)), "p1"),
    ]:
        with pytest.raises(SimulationError):
            step(sim, s, ("wait_load", (R, at)))


def test_wait_unload_at_the_destination_delivers_and_reaches_the_goal(sim: Simulator) -> None:
    s = state(sim, "phd_area", carrying=True)
    names, reward = step(sim, s, ("wait_unload", (R, "phd_area")))
    assert names[f"carrying({R})"] is False and names["delivered(phd_area)"] is True
    assert reward == pytest.approx(-5.0 - PENDING)  # UNLOAD_SECONDS; the last step pending
    # the goal fluent follows from the state, one step later, and stays
    assert names["goal"] is False
    s = sim.step(s, sim.actions_from_names({("wait_unload", (R, "phd_area")): True}),
                 np.random.default_rng(0)).next_state  # fmt: skip
    for _ in range(3):
        out = sim.step(s, None, np.random.default_rng(0))
        s = out.next_state
        assert sim.state_to_names(s)["goal"] is True and float(out.reward[0]) == 0.0


def test_wait_unload_only_with_papers_at_a_destination(sim: Simulator) -> None:
    with pytest.raises(SimulationError):
        step(sim, state(sim, "phd_area"), ("wait_unload", (R, "phd_area")))
    with pytest.raises(SimulationError):
        step(sim, state(sim, "kitchen", carrying=True), ("wait_unload", (R, "kitchen")))


def test_standing_still_costs_a_minute_before_the_goal_and_nothing_after(sim: Simulator) -> None:
    names, reward = step(sim, state(sim, "p1", carrying=True))
    assert reward == pytest.approx(-60.0 - PENDING)  # IDLE_SECONDS
    assert names[f"carrying({R})"] is True
    names, reward = step(sim, state(sim, "phd_area", delivered=True))
    assert reward == 0.0 and names["goal"] is True
    move = ("goto_waypoint", (R, "phd_area", "p2"))
    names, reward = step(sim, state(sim, "phd_area", delivered=True), move)
    assert names["goal"] is True and reward == pytest.approx(-2.0 * math.hypot(11, 3), abs=1e-3)


def test_one_action_per_step(sim: Simulator) -> None:
    with pytest.raises(SimulationError):
        step(
            sim,
            state(sim, "p1", somebody=("p1",)),
            ("wait_load", (R, "p1")),
            ("goto_waypoint", (R, "p1", "p2")),
        )


# ------------------------------------------------------------ the rates


def test_exogenous_fluents_follow_the_rates_whatever_the_robot_does(sim: Simulator) -> None:
    n = 20_000
    points = sim.model.objects("waypoint")
    rng = np.random.default_rng(7)
    for act in (None, ("goto_waypoint", (R, "prof_office", "p1"))):
        s = sim.initial_state(n)
        acts = None if act is None else sim.actions_from_names([{act: True}] * n)
        nxt = sim.step(s, acts, rng).next_state.values
        for w in points:
            busy_rate, person_rate = PRINTERS.get(w, (0.0, 0.0))
            for fluent, rate in (("is_busy", busy_rate), ("somebody_at", person_rate)):
                seen = float(nxt[fluent][:, points.index(w)].mean())
                sigma = math.sqrt(rate * (1 - rate) / n)
                # 4.5 sigma: a false alarm about once in 150000 checks
                assert abs(seen - rate) <= 4.5 * sigma + 1e-12, (fluent, w, seen, rate)
        # busy does not depend on somebody being there (it did in the paper's model)
        p = points.index("p1")
        both = float((nxt["is_busy"][:, p] & nxt["somebody_at"][:, p]).mean())
        assert abs(both - 0.45) <= 4.5 * math.sqrt(0.45 * 0.55 / n)


# ------------------------------------------------------------ over the wire

ROUTE = [  # experiment 1 through p2: deterministic costs only (moves, then standing)
    "goto_waypoint(turtlebot,prof_office,p2)",
    "goto_waypoint(turtlebot,p2,phd_area)",
]


@pytest.mark.trio
async def test_plays_through_rddl_server_with_prost_framing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The fake PROST (PROST's bytes: NUL framing, no-header, its own parser
    run on the task) plays two rounds of experiment 1 on our server."""
    folder = tmp_path / "prost"
    folder.mkdir()
    (folder / "search").symlink_to(FAKE_PROST)
    (folder / "rddl-parser-release").symlink_to(FAKE_PARSER)
    actions = tmp_path / "actions.txt"
    actions.write_text("\n".join(f"Submitted action: {a} " for a in ROUTE) + "\n")
    monkeypatch.setenv("FAKE_PROST_ACTIONS_FILE", str(actions))
    monkeypatch.setenv("FAKE_PROST_MAX_SECONDS", "30")
    monkeypatch.delenv("FAKE_PROST_MODE", raising=False)
    planner = ProstPlanner(binary=str(folder / "search"), grace="0.5")
    async with our_server(FOLDER, rounds=1) as (port, _, store):
        result = await trio.to_thread.run_sync(
            lambda: planner.run_session(
                host="127.0.0.1",
                port=port,
                instance="print_fetch_exp1",
                client_name=None,
                timeout=20.0,
                log_path=tmp_path / "prost.log",
            )
        )
        assert result.error is None and result.ok, (tmp_path / "prost.log").read_text()
        rows = [s for s in store.sessions() if s["client_name"] == "prost"]
        assert len(rows) == 1
        row = await settled(store, rows[0]["server_session_id"])
    metres = distance("prof_office", "p2") + distance("p2", "phd_area")
    expected = -2.0 * metres - 60.0 * 18 - PENDING * 20  # two moves, 18 steps standing
    assert result.rounds == [pytest.approx(expected, abs=0.01)]
    assert row["status"] == "finished"
    assert row["total_reward"] == pytest.approx(expected, abs=0.01)
