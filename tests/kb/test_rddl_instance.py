"""RDDL problem generation: the generated non-fluents and instance blocks
parse through ippc.rddl into the same values, fluents and non-fluents go
where their declarations say, and IPPC instances round-trip."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ippc.kb import KnowledgeBase, Update
from ippc.rddl import load_pair, parse

from ..conftest import corpus_pairs
from .conftest import TURTLEBOT_DOMAIN, WAREHOUSE


def reload(kb: KnowledgeBase, domain: Path, tmp_path: Path, **kw: object) -> KnowledgeBase:
    text = kb.to_rddl_instance(**kw)  # type: ignore[arg-type]
    path = tmp_path / "generated.rddl"
    path.write_text(text)
    return KnowledgeBase.from_files(domain, path)


def same_knowledge(a: KnowledgeBase, b: KnowledgeBase) -> None:
    assert a.facts(non_fluents=True) == b.facts(non_fluents=True)
    assert (a.horizon, a.discount, a.max_nondef_actions) == (
        b.horizon,
        b.discount,
        b.max_nondef_actions,
    )
    assert a.instances() == b.instances()


def test_the_print_instance_after_updates_round_trips(
    turtlebot: KnowledgeBase, tmp_path: Path
) -> None:
    turtlebot.apply(
        [
            Update.set("distance", ("dan-office", "phdarea"), 16.61),  # a non-fluent
            Update.remove("robot_at", "kenny", "dan-office"),
            Update.add("robot_at", "kenny", "phdarea"),
            Update.add("somebody_at", "printer-corridor"),
        ],
        source="test",
    )
    turtlebot.horizon = 7
    text = turtlebot.to_rddl_instance()
    parsed = parse(text, "generated.rddl")
    (nf,) = parsed.non_fluents
    (inst,) = parsed.instances
    assert inst.name == "turtlebot_domain_prob_printing__generated_instance"
    assert nf.name == "nf_turtlebot_domain_prob_printing__generated_instance"
    assert inst.non_fluents == nf.name and inst.horizon == 7
    nf_names = {a.name for a in nf.values}
    init_names = {a.name for a in inst.init_state or ()}
    # decided by the declarations: distance is a non-fluent, somebody_at a state
    # fluent that no action changes (ROSPlan's guess filed such fluents wrongly)
    assert "distance" in nf_names and "somebody_at" in init_names
    assert nf_names <= {p["name"] for p in turtlebot.predicates() + turtlebot.functions()}
    assert not any(turtlebot.is_state_fluent(n) for n in nf_names)
    assert all(turtlebot.is_state_fluent(n) for n in init_names)
    again = reload(turtlebot, TURTLEBOT_DOMAIN, tmp_path)
    same_knowledge(turtlebot, again)
    assert again.get("distance", ("dan-office", "phdarea")) == 16.61
    # the generated text is a fixed point
    assert again.to_rddl_instance() == text


def test_explicit_writes_every_grounding_as_rosplan_did(
    warehouse: KnowledgeBase, tmp_path: Path
) -> None:
    text = warehouse.to_rddl_instance(explicit=True)
    inst = parse(text, "x.rddl").instances[0]
    assert len(inst.init_state or ()) == len(warehouse.facts())
    assert "~robot-at(c2);" in text and "status = @busy;" in text
    same_knowledge(warehouse, reload(warehouse, WAREHOUSE, tmp_path, explicit=True))


def test_a_state_at_its_defaults_still_has_an_init_state(
    warehouse: KnowledgeBase, tmp_path: Path
) -> None:
    warehouse.apply(
        [
            Update.remove("robot-at", "c1"),
            Update.remove("box-at", "b1", "c1"),
            Update.remove("box-at", "b2", "c2"),
            Update.set("battery", (), 10),
            Update.set("status", (), "@idle"),
        ],
        source="test",
    )
    text = warehouse.to_rddl_instance(name="empty", non_fluents_name="nf_empty")
    assert "init-state {\n        ~robot-at(c1);\n    };" in text
    same_knowledge(warehouse, reload(warehouse, WAREHOUSE, tmp_path))


def sample() -> list[tuple[Path, Path]]:
    """One instance of every seventh corpus domain folder, and the last
    (largest-numbered) instance of every IPPC 2011 domain."""
    pairs = corpus_pairs()
    by_domain: dict[Path, list[Path]] = {}
    for d, i in pairs:
        by_domain.setdefault(d, []).append(i)
    out = [(d, insts[0]) for n, (d, insts) in enumerate(sorted(by_domain.items())) if n % 7 == 0]
    out += [(d, insts[-1]) for d, insts in sorted(by_domain.items()) if "IPPC2011" in str(d)]
    return out


@pytest.mark.slow
@pytest.mark.parametrize(
    ("domain", "instance"), sample(), ids=lambda p: "/".join(Path(p).parts[-3:])
)
def test_ippc_instances_round_trip(domain: Path, instance: Path, tmp_path: Path) -> None:
    kb = KnowledgeBase.from_model(load_pair(domain, instance))
    again = reload(kb, domain, tmp_path)
    same_knowledge(kb, again)
    # and after toggling about a third of the boolean facts
    rng = np.random.default_rng(0)
    updates = []
    for (name, args), value in list(kb.facts().items()):
        if isinstance(value, bool) and rng.random() < 0.3:
            updates.append(Update("remove" if value else "add", name, args))
    # (a state no transition reaches: the domain's state invariants are not asked)
    kb.apply(updates, source="test", check_invariants=False)
    same_knowledge(kb, reload(kb, domain, tmp_path))
