"""The knowledge base's state: values, atomic batches, subscribers, sensed
flags, the bridges to the simulator, the goal check and R(s, a)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ippc.kb import Change, KBError, KnowledgeBase, Update
from ippc.rddl import RDDLError
from ippc.rddl.simulator import Simulator
from ippc.rddl.writer import write

from .conftest import KB_DATA, TURTLEBOT_DOMAIN

# ------------------------------------------------------------------ values


def test_initial_values_of_every_kind(warehouse: KnowledgeBase) -> None:
    kb = warehouse
    assert kb.get("robot-at", ["c1"]) is True
    assert kb.get("robot-at", ["c2"]) is False  # closed world: stored false
    assert kb.get("battery") == 5 and isinstance(kb.get("battery"), int)
    assert kb.get("driven") == 0.0 and isinstance(kb.get("driven"), float)
    assert kb.get("status") == "@busy"
    assert kb.get("ADJACENT", ("c1", "c2")) is True
    assert kb.get("DIRT-PROB", ("c2",)) == 0.3
    assert kb.get("DIRT-PROB", ("c1",)) == 0.1  # the declared default


def test_facts_list_every_grounding_false_ones_included(warehouse: KnowledgeBase) -> None:
    facts = warehouse.facts("box-at")
    assert len(facts) == 6
    assert facts[("box-at", ("b1", "c1"))] is True
    assert facts[("box-at", ("b1", "c3"))] is False
    every = warehouse.facts()
    assert ("battery", ()) in every and ("ADJACENT", ("c1", "c2")) not in every
    with_nf = warehouse.facts(non_fluents=True)
    assert with_nf[("ADJACENT", ("c1", "c2"))] is True
    # 3 + 6 + 2 + 1 + 1 + 1 + 3 + 1 + 1 + 2 + 1 groundings of the state fluents
    assert len(every) == 22


@pytest.mark.parametrize(
    ("fluent", "args", "code", "words"),
    [
        ("robot_at", ("c1",), "unknown-fluent", "did you mean 'robot-at'"),
        ("move", ("c1", "c2"), "not-stored", "action-fluent"),
        ("robot-at", (), "arity", "takes 1 argument"),
        ("robot-at", ("c9",), "unknown-object", "'c9' is not an object of type 'cell'"),
        ("robot-at", ("b1",), "unknown-object", "members: c1, c2, c3"),
    ],
)
def test_bad_queries_name_the_problem(
    warehouse: KnowledgeBase, fluent: str, args: tuple[str, ...], code: str, words: str
) -> None:
    with pytest.raises(KBError) as err:
        warehouse.get(fluent, args)
    assert err.value.code == code
    assert words in str(err.value)


# ----------------------------------------------------------------- updates


def test_apply_reports_only_real_changes(warehouse: KnowledgeBase) -> None:
    changes = warehouse.apply(
        [
            Update.remove("robot-at", "c1"),
            Update.add("robot-at", "c2"),
            Update.add("box-at", "b1", "c1"),  # already true: no change
            Update.set("battery", (), 4),
            Update.set("status", (), "charging"),  # an enum value without its '@'
            Update.set("driven", (), 2),  # an int for a real fluent
        ],
        source="test",
    )
    assert changes == [
        Change("robot-at", ("c1",), True, False),
        Change("robot-at", ("c2",), False, True),
        Change("battery", (), 5, 4),
        Change("status", (), "@busy", "@charging"),
        Change("driven", (), 0.0, 2.0),
    ]
    assert warehouse.get("status") == "@charging"
    assert isinstance(warehouse.get("driven"), float)


def test_last_update_of_a_grounding_wins_and_no_net_change_is_none(
    warehouse: KnowledgeBase,
) -> None:
    changes = warehouse.apply(
        [Update.set("battery", (), 1), Update.set("battery", (), 5)], source="test"
    )
    assert changes == [] and warehouse.get("battery") == 5


@pytest.mark.parametrize(
    ("bad", "code", "words"),
    [
        (Update.add("battery"), "bad-op", "'add' needs a bool fluent"),
        (Update("set", "robot-at", ("c1",)), "bad-value", "'set' needs a value"),
        (Update.set("robot-at", ("c1",), 1), "bad-value", "takes true or false"),
        (Update.set("battery", (), 2.5), "bad-value", "takes an integer"),
        (Update.set("status", (), "@flying"), "bad-value", "one of @idle, @busy, @charging"),
        (Update.set("driven", (), float("nan")), "bad-value", "NaN"),
        (Update("toggle", "robot-at", ("c1",)), "bad-op", "unknown op 'toggle'"),  # type: ignore[arg-type]
        (Update.add("robot-at", "c1", "c2"), "arity", "takes 1 argument"),
        (Update.add("holding", "c1"), "unknown-object", "not an object of type 'box'"),
    ],
)
def test_a_bad_update_changes_nothing(
    warehouse: KnowledgeBase, bad: Update, code: str, words: str
) -> None:
    heard: list[object] = []
    warehouse.subscribe(lambda changes, source: heard.append(changes))
    before = warehouse.facts(non_fluents=True)
    with pytest.raises(KBError) as err:
        warehouse.apply([Update.add("robot-at", "c3"), bad], source="test")
    assert err.value.code == code
    assert words in str(err.value)
    assert str(err.value).startswith("update 2 (")  # names the update in the batch
    assert warehouse.facts(non_fluents=True) == before
    assert heard == []


def test_subscribers_hear_each_batch_once_with_its_source(warehouse: KnowledgeBase) -> None:
    heard: list[tuple[list[Change], str]] = []
    other: list[str] = []

    def broken(changes: list[Change], source: str) -> None:
        raise RuntimeError("a subscriber that fails")

    warehouse.subscribe(broken)
    unsubscribe = warehouse.subscribe(lambda changes, source: heard.append((changes, source)))
    warehouse.subscribe(lambda changes, source: other.append(source))
    warehouse.apply([Update.add("dirty", "c1"), Update.add("dirty", "c2")], source="sensing")
    warehouse.apply([Update.add("dirty", "c1")], source="sensing")  # no change: not heard
    unsubscribe()
    warehouse.apply([Update.remove("dirty", "c1")], source="handler")
    assert heard == [
        ([Change("dirty", ("c1",), False, True), Change("dirty", ("c2",), False, True)], "sensing")
    ]
    assert other == ["sensing", "handler"]  # the failing subscriber stopped nobody


def test_sensed_flags(warehouse: KnowledgeBase) -> None:
    assert warehouse.sensed_fluents() == frozenset()
    warehouse.set_sensed("dirty")
    warehouse.set_sensed("holding")
    assert warehouse.is_sensed("dirty") and not warehouse.is_sensed("robot-at")
    warehouse.set_sensed("holding", False)
    assert warehouse.sensed_fluents() == frozenset({"dirty"})
    with pytest.raises(KBError, match="unknown fluent 'dirt'"):
        warehouse.set_sensed("dirt")


def test_changing_a_non_fluent_is_an_update_like_any_other(turtlebot: KnowledgeBase) -> None:
    # ROSPlan's start-up script wrote the distances into the knowledge base.
    changes = turtlebot.apply(
        [Update.set("distance", ("dan-office", "phdarea"), 16.61)], source="setup"
    )
    assert changes == [Change("distance", ("dan-office", "phdarea"), 10.0, 16.61)]
    assert not turtlebot.is_state_fluent("distance") and turtlebot.is_state_fluent("robot_at")
    assert turtlebot.to_model().non_fluent_values[("distance", ("dan-office", "phdarea"))] == 16.61


# ------------------------------------------------------- simulator bridges


def test_to_state_and_load_state_round_trip(warehouse: KnowledgeBase) -> None:
    sim = Simulator(warehouse.model)
    start = sim.initial_state()
    state = warehouse.to_state()
    assert set(state.values) == set(start.values)
    for name in start.values:
        np.testing.assert_array_equal(state.values[name], start.values[name])
    heard: list[str] = []
    warehouse.subscribe(lambda changes, source: heard.append(source))
    actions = sim.actions_from_names({("move", ("c1", "c2")): True})
    nxt = sim.step(state, actions, np.random.default_rng(3)).next_state
    changes = warehouse.load_state(nxt, source="world")
    got = {(c.fluent, c.args): (c.old, c.new) for c in changes}
    assert got[("robot-at", ("c1",))] == (True, False)
    assert got[("robot-at", ("c2",))] == (False, True)
    assert got[("battery", ())] == (5, 4)
    assert got[("driven", ())] == (0.0, 1.0)
    assert heard == ["world"]
    assert warehouse.load_state(warehouse.to_state(), source="world") == []
    assert heard == ["world"]


def test_load_state_refuses_a_batch(warehouse: KnowledgeBase) -> None:
    sim = Simulator(warehouse.model)
    with pytest.raises(KBError, match="a batch of one state, not 2"):
        warehouse.load_state(sim.initial_state(batch=2), source="world")


def test_to_model_starts_a_simulator_at_the_current_state(warehouse: KnowledgeBase) -> None:
    warehouse.apply([Update.set("battery", (), 7), Update.add("dirty", "c3")], source="test")
    warehouse.horizon = 5
    model = warehouse.to_model()
    assert model.horizon == 5
    sim = Simulator(model)
    state = sim.initial_state()
    assert int(state.values["battery"][0]) == 7
    assert bool(state.values["dirty"][0][2])


# ------------------------------------------------------------ parameters


def test_rddl_parameters_get_and_set(turtlebot: KnowledgeBase) -> None:
    assert (turtlebot.horizon, turtlebot.discount, turtlebot.max_nondef_actions) == (15, 1.0, 1)
    turtlebot.horizon = 30
    turtlebot.discount = 0.9
    turtlebot.max_nondef_actions = None
    assert (turtlebot.horizon, turtlebot.discount, turtlebot.max_nondef_actions) == (30, 0.9, None)
    for attr, value in (("horizon", 0), ("discount", 1.5), ("max_nondef_actions", True)):
        with pytest.raises(KBError):
            setattr(turtlebot, attr, value)


def test_a_file_that_does_not_parse_raises_with_its_position(tmp_path: Path) -> None:
    bad = tmp_path / "bad.rddl"
    bad.write_text(TURTLEBOT_DOMAIN.read_text().replace("cpfs {", "cpfs {{", 1))
    with pytest.raises(RDDLError) as err:
        KnowledgeBase.from_files(bad, KB_DATA / "turtlebot_printing_instance.rddl")
    assert f"{bad}:" in str(err.value)


# -------------------------------------------------------------------- goal


def test_goal_facts_read_the_implication_not_the_first_disjunct(turtlebot: KnowledgeBase) -> None:
    goal = turtlebot.goal()
    assert goal is not None and goal.source == "cpf" and goal.fluent == "goal"
    # ROSPlan made this "not DELIVERY_DESTINATION(w)" for every waypoint.
    assert [str(f) for f in goal.facts] == ["papers_delivered(kenny, phdarea)"]
    assert goal.unsupported == ()


def test_goal_follows_the_non_fluents(turtlebot: KnowledgeBase) -> None:
    turtlebot.apply([Update.add("DELIVERY_DESTINATION", "coffee")], source="setup")
    goal = turtlebot.goal()
    assert goal is not None
    assert [str(f) for f in goal.facts] == [
        "papers_delivered(kenny, phdarea)",
        "papers_delivered(kenny, coffee)",
    ]


def test_goal_holds(turtlebot: KnowledgeBase) -> None:
    assert turtlebot.goal_holds() is False
    turtlebot.apply([Update.add("papers_delivered", "kenny", "phdarea")], source="test")
    assert turtlebot.goal_holds() is True  # the condition holds before `goal` latches
    turtlebot.apply([Update.remove("papers_delivered", "kenny", "phdarea")], source="test")
    assert turtlebot.goal_holds() is False
    turtlebot.apply([Update.add("goal")], source="test")
    assert turtlebot.goal_holds() is True


def test_a_choice_is_reported_and_still_decided(tmp_path: Path) -> None:
    # Two robots: "some robot delivered" is a choice, not a conjunction of facts.
    inst = tmp_path / "two.rddl"
    text = (KB_DATA / "turtlebot_printing_instance.rddl").read_text()
    inst.write_text(text.replace("robot : {kenny};", "robot : {kenny, lenny};"))
    kb = KnowledgeBase.from_files(TURTLEBOT_DOMAIN, inst)
    goal = kb.goal()
    assert goal is not None and goal.facts == ()
    assert len(goal.unsupported) == 1
    assert "a choice between 2 alternatives" in goal.unsupported[0].reason
    assert goal.unsupported[0].loc.line == 115  # the goal's condition in the domain file
    kb.apply([Update.add("papers_delivered", "lenny", "phdarea")], source="test")
    assert kb.goal_holds() is True


def test_no_goal_is_none() -> None:
    from ippc.rddl import load

    model = load(KB_DATA.parents[1].parent / "domains" / "corridor_enum")
    kb = KnowledgeBase.from_model(next(iter(model.values())))
    assert kb.goal() is None and kb.goal_holds() is None


# ------------------------------------------------------------------ reward


def test_immediate_reward_is_r_of_the_state_before_the_action(warehouse: KnowledgeBase) -> None:
    # Holding b1 at its target c3: dropping it there earns nothing this step
    # (the box is not at c3 yet); ROSPlan's post-action reading gave 10.
    warehouse.apply(
        [
            Update.remove("robot-at", "c1"),
            Update.add("robot-at", "c3"),
            Update.remove("box-at", "b1", "c1"),
            Update.add("holding", "b1"),
        ],
        source="test",
    )
    assert warehouse.immediate_reward(["drop(b1, c3)"]) == 0.0
    warehouse.apply([Update.remove("holding", "b1"), Update.add("box-at", "b1", "c3")], "test")
    assert warehouse.immediate_reward(["noop"]) == 10.0
    assert warehouse.immediate_reward([("move", ("c3", "c2"), True)]) == 9.0


def test_immediate_reward_of_the_print_domain(turtlebot: KnowledgeBase) -> None:
    assert turtlebot.immediate_reward([]) == -10000.0  # the anti-noop term
    assert turtlebot.immediate_reward(["goto_waypoint(kenny, dan-office, phdarea)"]) == -100.5
    with pytest.raises(KBError, match="'fly' is not an action fluent"):
        turtlebot.immediate_reward(["fly(kenny)"])


def test_rosplan_parser_defects_are_not_here(tmp_path: Path) -> None:
    # ROSPlan's parser refused `discount = 1` and read `a <=> b` as `a | a`.
    inst = tmp_path / "one.rddl"
    inst.write_text(
        (KB_DATA / "turtlebot_printing_instance.rddl").read_text().replace("1.0;", "1;")
    )
    kb = KnowledgeBase.from_files(TURTLEBOT_DOMAIN, inst)
    assert kb.discount == 1.0
    (invariant,) = kb.model.domain.state_invariants
    assert "docked(?r) <=> ~undocked(?r)" in write(invariant)
