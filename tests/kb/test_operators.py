"""ROSPlan's domain queries: operators (preconditions, effects, probabilistic
effects, exogenous), the metric, types, predicates and functions, against a
hand-written domain and against ROSPlan's own translation of its
print-fetching domain (ROSPLAN.md 6.1)."""

from __future__ import annotations

from pathlib import Path

import pytest
from ippc.kb import EXOGENOUS, KBError, KnowledgeBase, Operator, parameter_names
from ippc.kb.operators import translate
from ippc.rddl import load_pair

from ..conftest import corpus_pairs
from .conftest import WAREHOUSE


def effects(op: Operator) -> list[str]:
    return [str(e) for e in op.effects]


def outcomes(op: Operator) -> list[tuple[str, str | None, list[tuple[str, list[str]]]]]:
    return [
        (
            p.draw,
            p.condition,
            [(o.probability, [str(e) for e in o.effects]) for o in p.outcomes],
        )
        for p in op.probabilistic
    ]


def test_parameter_names_are_rosplans() -> None:
    assert parameter_names(("robot", "waypoint", "waypoint")) == ("r", "w", "w1")
    assert parameter_names(("robot", "room", "robot", "room")) == ("r", "r1", "r2", "r3")
    assert parameter_names(()) == ()


# ------------------------------------------------------- print-fetching


def test_rosplans_translation_of_the_print_domain(turtlebot: KnowledgeBase) -> None:
    """ROSPLAN.md 6.1, 'How ROSPlan translates it', and where ippc does better."""
    names = [o.name for o in turtlebot.operators()]
    assert names == [
        "goto_waypoint",
        "localise",
        "dock",
        "undock",
        "ask_load",
        "ask_unload",
        "wait_load",
        "wait_unload",
        EXOGENOUS,
    ]
    goto = turtlebot.operator("goto_waypoint")
    assert [(p.name, p.type) for p in goto.parameters] == [
        ("r", "robot"),
        ("w", "waypoint"),
        ("w1", "waypoint"),
    ]
    assert [str(a) for a in goto.positive] == ["robot_at(?r, ?w)", "localised(?r)", "undocked(?r)"]
    assert goto.negative == ()
    assert goto.other == ("?w ~= ?w1",)  # ROSPlan dropped the inequality
    assert effects(goto) == [
        "add robot_at(?r, ?w1)",
        "delete robot_at(?r, ?w)",
        "add visited(?w1)",
        "delete asked_load(?r)",
        "delete asked_unload(?r)",
    ]
    ask = turtlebot.operator("ask_load")
    assert ask.positive == ()
    assert [str(a) for a in ask.negative] == ["asked_load(?r)", "carrying_papers(?r)"]
    # ROSPlan dropped the exists-printer condition; it is kept as a formula
    assert ask.other == ("exists_{?w : waypoint} (robot_at(?r, ?w) ^ PRINTER_AT(?w))",)
    wait = turtlebot.operator("wait_load")
    # ROSPlan: add carrying_papers(r); here with the condition the cpf puts on it
    assert effects(wait) == [
        "add carrying_papers(?r) when exists_{?w : waypoint} (robot_at(?r, ?w) ^ somebody_at(?w))"
    ]
    dock = turtlebot.operator("dock")
    assert [str(a) for a in dock.positive] == ["undocked(?r)", "DOCK_AT(?w)", "robot_at(?r, ?w)"]
    assert effects(dock) == ["delete undocked(?r)", "add docked(?r)"]
    exo = turtlebot.operator(EXOGENOUS)
    assert exo.parameters == () and exo.positive == ()
    # ROSPlan: probabilistic somebody_at(w) and is_busy(w), deterministic goal
    # and got_papers_reward
    assert outcomes(exo) == [
        (
            "Bernoulli",
            "PRINTER_AT(?w) ^ somebody_at(?w)",
            [
                ("BUSY_RATE(?w)", ["add is_busy(?w)"]),
                ("1.0 - BUSY_RATE(?w)", ["delete is_busy(?w)"]),
            ],
        ),
        (
            "Bernoulli",
            None,
            [
                ("OCCUPATION_RATE(?w)", ["add somebody_at(?w)"]),
                ("1.0 - OCCUPATION_RATE(?w)", ["delete somebody_at(?w)"]),
            ],
        ),
    ]
    assert [p.name for p in exo.probabilistic[1].forall] == ["w"]
    assert effects(exo) == [
        "forall ?w: delete is_busy(?w) when ~(PRINTER_AT(?w) ^ somebody_at(?w))",
        "forall ?r: add got_papers_reward(?r) when carrying_papers(?r)",
        "add goal when forall_{?w : waypoint} (~DELIVERY_DESTINATION(?w) "
        "| (exists_{?r : robot} papers_delivered(?r, ?w)))",
    ]


def test_what_the_print_domain_cannot_put_into_operators(turtlebot: KnowledgeBase) -> None:
    got = [(u.where, u.reason, u.loc.line) for u in turtlebot.unsupported()]
    assert got == [
        (
            "action-precondition at line 151",
            "constrains states, not an action (checked by the simulator)",
            151,
        ),
        (
            "action-precondition at line 175",
            "about several actions (ask_load, ask_unload, dock, goto_waypoint, localise, "
            "undock, wait_load, wait_unload), not one",
            175,
        ),
    ]


# -------------------------------------------------------- hand-written


def test_deterministic_numeric_and_enum_effects(warehouse: KnowledgeBase) -> None:
    move = warehouse.operator("move")
    assert [(p.name, p.type) for p in move.parameters] == [("c", "cell"), ("c1", "cell")]
    assert [str(a) for a in move.positive] == ["robot-at(?c)", "ADJACENT(?c, ?c1)"]
    assert move.other == ("?c ~= ?c1", "battery > 0")
    assert effects(move) == [
        "add robot-at(?c1)",
        "delete robot-at(?c)",
        "decrease battery 1",
        "increase driven MOVE-COST",
        "assign status @busy",
    ]
    assert [e.kind for e in move.numeric_effects] == ["decrease", "increase", "assign"]
    assert [str(e.atom) for e in move.add_effects] == ["robot-at(?c1)"]
    assert [str(e.atom) for e in move.delete_effects] == ["robot-at(?c)"]


def test_probabilistic_effects_bernoulli_negated_and_discrete(warehouse: KnowledgeBase) -> None:
    pick = warehouse.operator("pick")
    assert [str(a) for a in pick.positive] == ["robot-at(?c)", "box-at(?b, ?c)"]
    assert [str(a) for a in pick.negative] == ["holding(?b)"]
    assert pick.other == ("~(exists_{?o : box} holding(?o))",)
    assert pick.effects == ()
    assert outcomes(pick) == [
        (
            "Bernoulli",
            None,
            [("GRIP-PROB", ["add holding(?b)"]), ("1.0 - GRIP-PROB", ["delete holding(?b)"])],
        ),
        (  # ~Bernoulli(p): negation swaps add and delete
            "Bernoulli",
            None,
            [("GRIP-PROB", ["delete box-at(?b, ?c)"]), ("1.0 - GRIP-PROB", ["add box-at(?b, ?c)"])],
        ),
    ]
    charge = warehouse.operator("charge")
    assert charge.parameters == ()
    assert charge.other == ("~(status == @charging) | battery < 10",)
    assert effects(charge) == ["assign battery 10"]
    assert outcomes(charge) == [
        ("Discrete", None, [("0.7", ["assign status @charging"]), ("0.3", ["assign status @idle"])])
    ]


def test_exogenous_operator_of_the_hand_written_domain(warehouse: KnowledgeBase) -> None:
    exo = warehouse.operator(EXOGENOUS)
    # a constant true cpf is an add effect only (ROSPlan listed it as add and delete);
    # dirt that stays dirty is no effect, new dirt is a draw where it is clean
    assert effects(exo) == [
        "add powered",
        "add goal when forall_{?b : box, ?c : cell} (~TARGET(?b, ?c) | box-at(?b, ?c))",
    ]
    assert outcomes(exo) == [
        (
            "Bernoulli",
            "~dirty(?c)",
            [("DIRT-PROB(?c)", ["add dirty(?c)"]), ("1.0 - DIRT-PROB(?c)", ["delete dirty(?c)"])],
        )
    ]
    assert exo.delete_effects == ()


def test_unsupported_parts_are_reported_by_name_and_line(warehouse: KnowledgeBase) -> None:
    got = {(u.where, u.loc.line): u.reason for u in warehouse.unsupported()}
    assert got[("cpf noise", 79)] == "a draw of another kind (Normal(0.0, 1.0))"
    assert got[("cpf seen-box", 80)].startswith(
        "a value that is a formula, not a constant or a draw"
    )
    assert "the value @idle when no action case applies" in got[("cpf status", 69)]
    assert got[("action-precondition at line 98", 98)].startswith("about several actions")
    assert len(got) == 4


def test_intermediate_fluents_are_inlined(tmp_path: Path) -> None:
    text = WAREHOUSE.read_text()
    text = text.replace(
        "goal : { state-fluent, bool, default = false };",
        "goal : { state-fluent, bool, default = false };\n"
        "        grabbed(box) : { interm-fluent, bool, level = 1 };",
    )
    text = text.replace(
        "        holding'(?b) =\n            if (exists_{?c : cell} [pick(?b, ?c)]) then Bernoulli(GRIP-PROB)",
        "        grabbed(?b) = exists_{?c : cell} [pick(?b, ?c)];\n"
        "        holding'(?b) =\n            if (grabbed(?b)) then Bernoulli(GRIP-PROB)",
    )
    path = tmp_path / "interm.rddl"
    path.write_text(text)
    ops, _ = translate(load_pair(path, path))
    pick = next(o for o in ops if o.name == "pick")
    assert outcomes(pick)[0][2][0] == ("GRIP-PROB", ["add holding(?b)"])


# --------------------------------------------------------------- queries


def test_domain_queries(warehouse: KnowledgeBase) -> None:
    kb = warehouse
    assert kb.domain_name() == "kb_warehouse"
    assert kb.types() == [
        {"name": "cell", "supertype": "object", "kind": "object"},
        {"name": "box", "supertype": "object", "kind": "object"},
        {
            "name": "mode",
            "supertype": "object",
            "kind": "enum",
            "values": ["@idle", "@busy", "@charging"],
        },
    ]
    preds = {p["name"]: p for p in kb.predicates()}
    assert set(preds) == {
        "ADJACENT",
        "TARGET",
        "robot-at",
        "box-at",
        "holding",
        "dirty",
        "powered",
        "seen-box",
        "goal",
    }
    assert preds["box-at"]["parameters"] == [
        {"name": "b", "type": "box"},
        {"name": "c", "type": "cell"},
    ]
    assert preds["ADJACENT"]["kind"] == "non-fluent" and preds["dirty"]["kind"] == "state-fluent"
    kb.set_sensed("dirty")
    assert {p["name"]: p for p in kb.predicates()}["dirty"]["is_sensed"] is True
    funcs = {f["name"]: f["type"] for f in kb.functions()}
    assert funcs == {
        "GRIP-PROB": "real",
        "DIRT-PROB": "real",
        "MOVE-COST": "real",
        "battery": "int",
        "driven": "real",
        "status": "mode",
        "noise": "real",
    }
    assert kb.fluent_type("status") == "mode" and kb.fluent_type("move") == "bool"
    assert kb.instances("cell") == ["c1", "c2", "c3"]
    assert kb.instances() == {"cell": ["c1", "c2", "c3"], "box": ["b1", "b2"]}
    assert kb.enum_values("mode") == ["@idle", "@busy", "@charging"]
    for bad in (
        lambda: kb.instances("mode"),
        lambda: kb.enum_values("cell"),
        lambda: kb.operator("fly"),
    ):
        with pytest.raises(KBError):
            bad()


def test_metric_is_the_reward_maximised_with_its_own_operators(warehouse: KnowledgeBase) -> None:
    metric = warehouse.metric()
    assert metric["optimization"] == "maximize"
    assert metric["expression"].startswith("-MOVE-COST * (sum_{?a : cell, ?b : cell} move(?a, ?b))")
    tree = metric["tree"]
    assert tree["op"] == "+"
    left, right = tree["args"]
    assert left["op"] == "*" and left["args"][0] == {
        "op": "neg",
        "args": [{"fluent": "MOVE-COST", "args": [], "primed": False}],
    }
    assert right["args"][1]["op"] == "sum"
    assert right["args"][1]["vars"] == [["?b", "box"], ["?c", "cell"]]
    # a conjunction stays a conjunction (ROSPlan made it a product)
    assert right["args"][1]["args"][0]["op"] == "^"


# ---------------------------------------------------------------- corpus


@pytest.mark.slow
def test_every_corpus_domain_translates_and_reports_with_positions() -> None:
    seen: set[Path] = set()
    domains = reported = 0
    for dom, inst in corpus_pairs():
        if dom in seen:
            continue
        seen.add(dom)
        try:
            model = load_pair(dom, inst)
        except Exception:
            continue  # the language tests cover what does not load
        ops, unsupported = translate(model)
        domains += 1
        assert ops[-1].name == EXOGENOUS
        assert len(ops) == 1 + sum(
            1 for p in model.pvariables.values() if p.kind == "action-fluent"
        )
        for u in unsupported:
            assert u.loc.line > 0 and u.loc.file == str(dom), u
        reported += len(unsupported)
    assert domains > 100
    assert reported > 0
