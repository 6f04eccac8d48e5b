"""What sensing does with values a fluent cannot hold and with contradicting
sensors (issue 27, items 1 and 7): the value is refused with a warning that
names the stream, the fluent and the value; the rest of the message and the
next messages go on; warnings about one stream are rate-limited into a
summary; a batch that would break a state invariant is refused whole."""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trio
from ippc.dispatch.clock import SimulatedClock
from ippc.dispatch.config import SensingConfig, SensingConfigError
from ippc.dispatch.run import PlannerSpec, simulate
from ippc.dispatch.sensing import WARNING_PERIOD, Sensing, SensingError, coerce_value
from ippc.kb import KnowledgeBase

DATA = Path(__file__).resolve().parents[1] / "data" / "dispatch"
SENSORS = DATA / "courier_sensors.rddl"
SENSORS_ONE = DATA / "courier_sensors_one.rddl"  # one robot
ROOMS = ("hall", "office", "lab")

CONFIG: dict[str, Any] = {
    "rate": 10,
    "sensors": {
        "battery": {"stream": "power", "params": ["*"], "value": "msg.percent"},
        "floor": {"stream": "lift", "params": ["r1"], "value": "msg.floor"},
        "distance": {"stream": "range", "params": ["r1"], "value": "msg.metres", "infinite": True},
        "robot-at": {
            "stream": "odometry",
            "params": ["r1", "*"],
            "value": "msg.at",
        },
    },
}


@pytest.fixture
def kb() -> KnowledgeBase:
    return KnowledgeBase.from_files(SENSORS, SENSORS)


def make(kb: KnowledgeBase, clock: SimulatedClock | None = None) -> Sensing:
    return Sensing(kb, SensingConfig.from_dict(CONFIG, kb.model), clock=clock or SimulatedClock())


def warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [
        r.getMessage()
        for r in caplog.records
        if r.name == "ippc.dispatch.sensing" and r.levelno == logging.WARNING
    ]


@pytest.mark.trio
async def test_nan_and_huge_ints_never_stop_sensing(kb: KnowledgeBase) -> None:
    # Before: NaN reached the knowledge base, whose refusal ended `run` (and the
    # dispatcher's nursery with it); 1e20 gave OverflowError after battery was written.
    sensing = make(kb)
    with trio.fail_after(10):
        async with trio.open_nursery() as nursery:
            await nursery.start(sensing.run)
            assert sensing.feed("power", {"percent": {"r1": math.nan}}) == 0
            assert sensing.feed("lift", {"floor": 1e20}) == 0
            assert sensing.feed("lift", {"floor": 10**30}) == 0
            assert sensing.feed("power", {"percent": {"r1": 55.0}}) == 1
            assert sensing.feed("lift", {"floor": 3}) == 1
            while kb.get("floor", ("r1",)) != 3:
                await trio.sleep(0)
            nursery.cancel_scope.cancel()
    assert kb.get("battery", ("r1",)) == 55.0
    assert sensing.refused == {"power": 1, "lift": 2}
    errors = list(sensing.errors)
    assert "battery from stream 'power': battery(r1) cannot hold NaN" in errors[0]
    assert (
        "floor from stream 'lift': floor(r1) is a 64-bit int, the value 1e+20 is out of range"
        in errors[1]
    )
    assert "the value 1000000000000000000000000000000 is out of range" in errors[2]


def test_one_bad_value_of_a_message_leaves_the_rest(kb: KnowledgeBase) -> None:
    sensing = make(kb)
    assert sensing.feed("power", {"percent": {"r1": math.nan, "r2": 50.0}}) == 1
    assert sensing.feed("power", {"percent": [("r1", "full"), ("r9", 3.0), ("r2", 40.0)]}) == 1
    sensing.flush()
    assert kb.get("battery", ("r2",)) == 40.0 and kb.get("battery", ("r1",)) == 100.0
    errors = list(sensing.errors)
    assert len(errors) == 3
    assert "battery(r1) is a real, the value is 'full'" in errors[1]
    assert "'r9' is not an object of type robot" in errors[2]


def test_infinity_only_where_the_config_allows_it(kb: KnowledgeBase) -> None:
    sensing = make(kb)
    assert sensing.feed("power", {"percent": {"r1": math.inf}}) == 0
    assert sensing.feed("lift", {"floor": -math.inf}) == 0
    assert sensing.feed("range", {"metres": math.inf}) == 1  # infinite: true
    assert sensing.feed("range", {"metres": math.nan}) == 0  # NaN never
    sensing.flush()
    assert kb.get("distance", ("r1",)) == math.inf
    assert kb.get("battery", ("r1",)) == 100.0 and kb.get("floor", ("r1",)) == 0
    assert (
        "battery(r1) is given inf (an infinity; the sensor allows it with infinite: true)"
        in (sensing.errors[0])
    )
    assert sensing.refused == {"power": 1, "lift": 1, "range": 1}


def test_infinite_is_for_real_fluents_only(kb: KnowledgeBase) -> None:
    bad = {
        "sensors": {"floor": {"stream": "s", "params": ["r1"], "value": "msg", "infinite": True}}
    }
    with pytest.raises(SensingConfigError, match="only a real fluent holds infinity"):
        SensingConfig.from_dict(bad, kb.model)
    bad["sensors"]["floor"]["infinite"] = "yes"
    with pytest.raises(SensingConfigError, match="infinite is true or false"):
        SensingConfig.from_dict(bad, kb.model)


@pytest.mark.parametrize(
    ("fluent", "value", "kind"),
    [
        ("battery", np.float64("nan"), "NaN"),
        ("battery", np.float32("inf"), "infinity"),
        ("battery", 10**400, "out of range"),
        ("floor", np.int64(7), None),
        ("floor", 7.0, None),
        ("floor", 7.5, "wrong type"),
        ("floor", True, "wrong type"),
        ("floor", 2**63, "out of range"),
        ("floor", math.nan, "NaN"),
        ("robot-at", 1, "wrong type"),
        ("battery", np.array([1.0, 2.0]), "wrong type"),
    ],
)
def test_coerce_value_refuses_what_a_fluent_cannot_hold(
    kb: KnowledgeBase, fluent: str, value: Any, kind: str | None
) -> None:
    if kind is None:
        assert coerce_value(kb.model, fluent, value) == 7
        return
    with pytest.raises(SensingError) as err:
        coerce_value(kb.model, fluent, value)
    assert err.value.kind == kind


def test_warnings_about_a_stream_are_one_line_per_period(
    kb: KnowledgeBase, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, logger="ippc.dispatch.sensing")
    clock = SimulatedClock()
    sensing = make(kb, clock)
    step = 1 / 16  # 16 bad messages a second for 30 s (exact in binary)
    for _ in range(480):
        sensing.feed("power", {"percent": {"r1": math.nan}})
        sensing.feed("lift", {"floor": "third"})
        clock.advance(step)
    lines = warnings(caplog)
    power = [line for line in lines if "'power'" in line]
    assert len(lines) == 6 and len(power) == 3  # was 960 lines
    assert "battery(r1) cannot hold NaN" in power[0]
    assert power[1] == (
        "sensing: stream 'power': 159 more value(s) refused in the last 10 s "
        "(NaN for battery(r1): 159)"
    )
    assert power[2].startswith(
        "sensing: stream 'power': 160 more value(s) refused in the last 10 s"
    )
    assert "(wrong type for floor(r1): 159)" in lines[3]
    assert sensing.refused == {"power": 480, "lift": 480}
    sensing.flush()  # (the run loop's tick) at 30 s: the third period's summaries
    assert len(warnings(caplog)) == 8
    clock.advance(WARNING_PERIOD)
    sensing.flush()  # a quiet period: nothing to say, and the stream is forgotten
    sensing.feed("power", {"percent": {"r2": math.inf}})
    lines = warnings(caplog)
    assert len(lines) == 9 and "battery(r2) is given inf" in lines[-1]


def test_contradicting_odometry_is_refused_and_the_robot_stays_in_one_room(
    kb: KnowledgeBase, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, logger="ippc.dispatch.sensing")
    sensing = make(kb)
    sensing.feed("odometry", {"at": {"hall": True, "office": True, "lab": True}})
    sensing.feed("power", {"percent": {"r1": 80.0}})  # another stream, same batch
    changes = sensing.flush()
    assert [(c.fluent, c.args, c.new) for c in changes] == [("battery", ("r1",), 80.0)]
    assert [r for r in ROOMS if kb.get("robot-at", ("r1", r))] == ["hall"]
    assert sensing.refused == {"odometry": 1}
    (line,) = warnings(caplog)
    assert line.startswith("sensing: stream 'odometry': 3 value(s) refused by the knowledge base: ")
    assert "courier_sensors.rddl:" in line and "for ?r=r1" in line
    # the next consistent reading goes through, whole
    sensing.feed("odometry", {"at": {"hall": False, "office": True, "lab": False}})
    sensing.flush()
    assert [r for r in ROOMS if kb.get("robot-at", ("r1", r))] == ["office"]
    # out of the battery's 0-100 bounds (an invariant of this domain)
    sensing.feed("power", {"percent": {"r2": 180.0}})
    assert sensing.flush() == [] and kb.get("battery", ("r2",)) == 100.0


def test_a_dispatcher_fed_bad_numbers_and_contradictions_reaches_its_goal() -> None:
    # The soak: a NaN real or an int of 1e20 dropped the session.
    def observe(world: Any, state: Any) -> dict[str, dict[tuple[str, ...], Any]]:
        at = np.asarray(state.values["robot-at"][0])
        here = {("r1", r): bool(at[0, i]) for i, r in enumerate(ROOMS)}
        everywhere = {("r1", r): True for r in ROOMS}  # refused whole
        return {
            "battery": {("r1",): math.nan},
            "floor": {("r1",): 1e20},
            "distance": {("r1",): -math.inf},
            "robot-at": everywhere if world.steps % 3 == 1 else here,
        }

    report = simulate(
        SENSORS,
        SENSORS_ONE,
        seed=1,
        planner=PlannerSpec("replan"),
        sensed=["battery", "floor", "distance", "robot-at"],
        observe=observe,
    )
    # (a refused reading leaves the knowledge base a step behind: an action or two
    # may fail and be replanned; the session goes on)
    assert report.session_status == "finished" and report.goal_reached
