"""The knowledge base as a long-running service's memory (issue 27): atomic
batches whatever the values, the domain's state invariants, goals at run
time, and the journal and restore a restarted dispatcher resumes from."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
from ippc.kb import Goal, GoalFact, InvariantError, KBError, KnowledgeBase, Update
from ippc.kb.journal import fold

DISPATCH_DATA = Path(__file__).resolve().parents[1] / "data" / "dispatch"
COURIER = DISPATCH_DATA / "courier_domain.rddl"
COURIER_TWO = DISPATCH_DATA / "courier_two.rddl"
SENSORS = DISPATCH_DATA / "courier_sensors.rddl"


@pytest.fixture
def courier() -> KnowledgeBase:
    """Two robots: r1 in the hall, r2 in the lab."""
    return KnowledgeBase.from_files(COURIER, COURIER_TWO)


@pytest.fixture
def sensors() -> KnowledgeBase:
    """The courier with battery (real), floor (int) and distance (real)."""
    return KnowledgeBase.from_files(SENSORS, SENSORS)


class Heard:
    """Every notification a knowledge base gives, in order."""

    def __init__(self, kb: KnowledgeBase) -> None:
        self.changes: list[tuple[str, list[Any]]] = []
        self.goals: list[tuple[str, Goal | None]] = []
        self.journal: list[dict[str, Any]] = []
        kb.subscribe(lambda ch, src: self.changes.append((src, ch)))
        kb.subscribe_goal(lambda g, src: self.goals.append((src, g)))
        kb.subscribe_journal(self.journal.append)


# -- atomic batches (issue 27, item 2)


@pytest.mark.parametrize(
    ("bad", "code", "says"),
    [
        (1e20, "out-of-range", "64-bit integer"),  # was OverflowError after battery was written
        (2**63, "out-of-range", "64-bit integer"),
        (-(2**63) - 1, "out-of-range", "64-bit integer"),
        (math.inf, "bad-value", "takes an integer"),
        (math.nan, "bad-value", "takes an integer"),
        (2.5, "bad-value", "takes an integer"),
        ("3", "bad-value", "takes an integer"),
    ],
)
def test_a_batch_with_one_bad_value_changes_nothing_and_tells_nobody(
    sensors: KnowledgeBase, bad: Any, code: str, says: str
) -> None:
    heard = Heard(sensors)
    with pytest.raises(KBError) as err:
        sensors.apply(
            [Update.set("battery", ("r1",), 50.0), Update.set("floor", ("r1",), bad)], "sensing"
        )
    assert err.value.code == code
    assert str(err.value).startswith("update 2 (set floor(r1) = ")
    assert says in str(err.value)
    assert sensors.get("battery", ("r1",)) == 100.0  # not 50.0
    assert heard.changes == [] and heard.journal == []


def test_the_int64_limits_themselves_are_values(sensors: KnowledgeBase) -> None:
    sensors.apply(
        [Update.set("floor", ("r1",), 2**63 - 1), Update.set("floor", ("r2",), -(2**63))], "t"
    )
    assert sensors.get("floor", ("r1",)) == 2**63 - 1
    assert sensors.get("floor", ("r2",)) == -(2**63)


def test_reals_refuse_nan_and_numbers_beyond_a_double(sensors: KnowledgeBase) -> None:
    for bad, code in ((math.nan, "bad-value"), (10**400, "out-of-range")):
        with pytest.raises(KBError) as err:
            sensors.apply(
                [Update.set("distance", ("r1",), 3.0), Update.set("battery", ("r1",), bad)], "t"
            )
        assert err.value.code == code and "update 2 (set battery(r1)" in str(err.value)
    assert sensors.get("distance", ("r1",)) == 0.0
    sensors.apply([Update.set("distance", ("r1",), math.inf)], "t")  # a real may be infinite
    assert sensors.get("distance", ("r1",)) == math.inf


# -- state invariants (issue 27, item 7)


def test_contradicting_odometry_is_refused_and_the_robot_stays_in_one_room(
    courier: KnowledgeBase,
) -> None:
    heard = Heard(courier)
    with pytest.raises(InvariantError) as err:
        courier.apply([Update.add("robot-at", "r1", "office")], "sensing")  # hall too
    assert err.value.code == "invariant"
    assert "courier_domain.rddl:" in str(err.value) and "for ?r=r1" in str(err.value)
    assert "(sum_{?x : room} robot-at(?r, ?x)) == 1" in str(err.value)
    (v,) = err.value.violations
    assert v.binding == (("?r", "r1"),)
    with pytest.raises(InvariantError):  # nowhere at all is no better
        courier.apply([Update.remove("robot-at", "r2", "lab")], "sensing")
    assert [r for r in ("hall", "office", "lab") if courier.get("robot-at", ("r1", r))] == ["hall"]
    assert [r for r in ("hall", "office", "lab") if courier.get("robot-at", ("r2", r))] == ["lab"]
    assert heard.changes == [] and heard.journal == []
    # a move, told whole, is a possible state
    courier.apply(
        [Update.remove("robot-at", "r1", "hall"), Update.add("robot-at", "r1", "office")], "s"
    )
    assert courier.get("robot-at", ("r1", "office")) is True
    assert courier.check_invariants() == []


def test_an_invariant_that_is_broken_already_does_not_block_other_batches(
    courier: KnowledgeBase,
) -> None:
    courier.apply([Update.add("robot-at", "r1", "office")], "tool", check_invariants=False)
    (v,) = courier.check_invariants()
    assert v.binding == (("?r", "r1"),)
    courier.apply([Update.add("holding", "r2")], "sensing")  # another fluent: fine
    courier.apply([Update.add("robot-at", "r1", "lab")], "sensing")  # r1 was broken already
    with pytest.raises(InvariantError, match=r"for \?r=r2"):  # r2 was fine: not any more
        courier.apply([Update.add("robot-at", "r2", "hall")], "sensing")
    courier.apply(  # repaired
        [Update.remove("robot-at", "r1", "office"), Update.remove("robot-at", "r1", "lab")], "s"
    )
    assert courier.check_invariants() == []


def test_bounds_written_as_invariants_are_kept(sensors: KnowledgeBase) -> None:
    with pytest.raises(InvariantError, match="battery"):
        sensors.apply([Update.set("battery", ("r2",), 120.0)], "sensing")
    sensors.apply([Update.set("battery", ("r2",), 99.5)], "sensing")
    assert sensors.get("battery", ("r2",)) == 99.5


# -- goals at run time


def test_set_add_remove_and_reset_the_goal(courier: KnowledgeBase) -> None:
    heard = Heard(courier)
    domain_goal = courier.goal()
    assert domain_goal is not None and domain_goal.source == "cpf" and domain_goal.version == 0
    assert [str(f) for f in domain_goal.facts] == ["delivered"]

    g = courier.set_goal(["holding(r1)", {"fluent": "robot-at", "args": ["r2", "office"]}], "ctl")
    assert g is not None and g.source == "runtime" and g.version == 1
    assert [str(f) for f in g.facts] == ["holding(r1)", "robot-at(r2, office)"]
    assert g.to_json()["formula"] == "holding(r1) ^ robot-at(r2, office)"
    assert courier.goal() == g and courier.goal_holds() is False
    courier.apply([Update.add("holding", "r1")], "s")
    g = courier.remove_goal("robot-at(r2, office)", "ctl")
    assert g is not None and [str(f) for f in g.facts] == ["holding(r1)"]
    assert courier.goal_holds() is True
    g = courier.add_goal([GoalFact("present", ("office",), False)], "ctl")
    assert g is not None and [str(f) for f in g.facts] == ["holding(r1)", "~present(office)"]
    assert courier.goal_holds() is True  # nobody at the desk
    assert courier.remove_goal(["holding(r1)", "~present(office)"], "ctl") is None  # no goal left
    assert courier.goal_holds() is None
    back = courier.reset_goal("ctl")
    assert back is not None and back.source == "cpf" and back.version == 5
    assert [s for s, _ in heard.goals] == ["ctl"] * 5
    assert [x.version if x else None for _, x in heard.goals] == [1, 2, 3, None, 5]


def test_add_goal_starts_from_the_domain_goal(courier: KnowledgeBase) -> None:
    g = courier.add_goal("holding(r2)")
    assert g is not None and [str(f) for f in g.facts] == ["delivered", "holding(r2)"]


@pytest.mark.parametrize(
    ("facts", "code", "says"),
    [
        (["holding(r9)"], "unknown-object", "goal fact 1 (holding(r9)): argument 1 of 'holding'"),
        (["delivered", "flying(r1)"], "unknown-fluent", "goal fact 2 (flying(r1))"),
        (["CONNECTED(hall, lab)"], "not-state", "a goal asks for state fluents"),
        (["holding(r1, r2)"], "arity", "takes 1 argument"),
        (["holding(r1) == 3"], "bad-value", "takes true or false"),
        (["holding(r1)", "~holding(r1)"], "bad-goal", "contradicts"),
        (["holding(r1"], "bad-goal", "is not a goal fact"),
        ([{"fluent": "holding", "agrs": ["r1"]}], "bad-goal", "unknown key(s) agrs"),
    ],
)
def test_a_bad_goal_changes_nothing(
    courier: KnowledgeBase, facts: list[Any], code: str, says: str
) -> None:
    heard = Heard(courier)
    before = courier.goal()
    with pytest.raises(KBError) as err:
        courier.set_goal(facts)
    assert err.value.code == code and says in str(err.value)
    with pytest.raises(KBError):
        courier.add_goal(facts)
    assert courier.goal() == before
    assert heard.goals == [] and heard.journal == []


def test_removing_a_fact_not_in_the_goal_is_an_error(courier: KnowledgeBase) -> None:
    courier.set_goal("holding(r1)")
    with pytest.raises(KBError, match="holding\\(r2\\) is not in the goal") as err:
        courier.remove_goal(["holding(r1)", "holding(r2)"])
    assert err.value.code == "not-in-goal"
    g = courier.goal()
    assert g is not None and [str(f) for f in g.facts] == ["holding(r1)"]


# -- journal and restore


def test_the_journal_sees_every_batch_and_goal_as_plain_data(courier: KnowledgeBase) -> None:
    heard = Heard(courier)
    courier.apply(
        [Update.remove("robot-at", "r1", "hall"), Update.add("robot-at", "r1", "office")],
        "odometry",
    )
    courier.apply([Update.add("robot-at", "r1", "office")], "odometry")  # no change: no entry
    courier.set_goal(["holding(r1)"], "ctl")
    courier.apply([Update.add("holding", "r1")], "dispatcher")
    json.dumps(heard.journal)  # plain data
    assert heard.journal == [
        {
            "seq": 1,
            "source": "odometry",
            "changes": [
                {"fluent": "robot-at", "args": ["r1", "hall"], "old": True, "new": False},
                {"fluent": "robot-at", "args": ["r1", "office"], "old": False, "new": True},
            ],
        },
        {
            "seq": 2,
            "source": "ctl",
            "goal": [{"fluent": "holding", "args": ["r1"], "value": True}],
            "version": 1,
        },
        {
            "seq": 3,
            "source": "dispatcher",
            "changes": [{"fluent": "holding", "args": ["r1"], "old": False, "new": True}],
        },
    ]


def test_a_restarted_knowledge_base_resumes_from_the_journal(courier: KnowledgeBase) -> None:
    saved: list[dict[str, Any]] = []
    courier.subscribe_journal(saved.append)
    courier.apply([Update.set("CONNECTED", ("office", "lab"), True)], "map")  # a non-fluent
    courier.apply(
        [Update.remove("robot-at", "r1", "hall"), Update.add("robot-at", "r1", "office")], "s"
    )
    courier.apply([Update.add("holding", "r1")], "dispatcher")
    courier.set_goal("robot-at(r1, lab)", "ctl")
    stored = json.loads(json.dumps(saved))  # as a store would keep it

    again = KnowledgeBase.from_files(COURIER, COURIER_TWO)  # the instance's initial state
    heard = Heard(again)
    changes = again.restore(fold(stored), source="resume")
    assert again.facts() == courier.facts()
    assert again.get("CONNECTED", ("office", "lab")) is True
    assert again.goal() is not None and [str(f) for f in again.goal().facts] == [
        "robot-at(r1, lab)"
    ]
    assert heard.changes == [("resume", changes)] and len(changes) == 4
    assert [s for s, _ in heard.goals] == ["resume"]
    # a snapshot says the same
    third = KnowledgeBase.from_files(COURIER, COURIER_TWO)
    third.restore(json.loads(json.dumps(courier.snapshot())))
    assert third.facts(non_fluents=True) == courier.facts(non_fluents=True)
    assert third.snapshot() == courier.snapshot()


def test_a_bad_restore_changes_nothing(courier: KnowledgeBase) -> None:
    heard = Heard(courier)
    for saved, code in (
        (
            [
                {"fluent": "holding", "args": ["r1"], "value": True},
                {"fluent": "holding", "args": ["r7"], "value": True},
            ],
            "unknown-object",
        ),
        ([("robot-at", ("r1", "lab"), True)], "invariant"),
        ({"facts": [], "goal": ["flying(r1)"]}, "unknown-fluent"),
        ({"facts": [], "goals": []}, "bad-params"),
        ([["holding"]], "bad-fact"),
    ):
        with pytest.raises(KBError) as err:
            courier.restore(saved)  # type: ignore[arg-type]
        assert err.value.code == code, saved
    assert courier.get("holding", ("r1",)) is False and courier.goal().source == "cpf"  # type: ignore[union-attr]
    assert heard.changes == [] and heard.goals == [] and heard.journal == []
