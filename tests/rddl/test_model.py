"""`load` and the checked `Model`: pairing by name, values, layouts."""

from __future__ import annotations

from pathlib import Path

import pytest
from ippc.rddl import RDDLSemanticError, check_files, load, load_model, load_pair

from .test_parser import DOMAIN, INSTANCE_2018


def test_sysadmin_model(rddlsim_rddl: Path) -> None:
    m = load(rddlsim_rddl / "sysadmin_mdp.rddl", rddlsim_rddl / "sysadmin_inst_mdp__1.rddl")[
        "sysadmin_inst_mdp__1"
    ]
    assert m.domain_name == "sysadmin_mdp"
    assert m.objects("computer") == tuple(f"c{i}" for i in range(1, 11))
    assert m.horizon == 5 and m.discount == 1.0 and m.max_nondef_actions == 1
    assert m.pvariables["running"].kind == "state-fluent"
    assert m.pvariables["reboot"].kind == "action-fluent"
    assert m.non_fluent_values[("REBOOT-PROB", ())] == 0.05
    assert m.value_of("CONNECTED", ("c1", "c4")) is True
    assert m.value_of("CONNECTED", ("c1", "c2")) is False  # the declared default
    assert all(m.value_of("running", (c,)) is True for c in m.objects("computer"))
    assert list(m.groundings("CONNECTED"))[:2] == [("c1", "c1"), ("c1", "c2")]
    assert not m.is_pomdp
    assert m.files() == [m.domain_file, m.instance_file]


def test_pomdp_and_enums(rddlsim_rddl: Path) -> None:
    models = load(rddlsim_rddl)
    assert models["sysadmin_inst_pomdp__1"].is_pomdp
    side = models["is2"]  # sidewalk.rddl holds domain, non-fluents and instances
    assert side.pvariables["walk"].range == "direction"
    assert side.default_of("walk") == "@none"
    assert side.objects("direction") == ("@up", "@down", "@left", "@right", "@none")
    traffic = models["inst_traffic_binary_ctm"]
    enum_state = [
        p for p in traffic.fluents("state-fluent") if p.range not in ("bool", "int", "real")
    ]
    assert enum_state, "the CTM domain has an enum-valued state fluent"


def test_2018_layout_subtypes_and_defaults(tmp_path: Path) -> None:
    (tmp_path / "toy.rddl").write_text(DOMAIN + INSTANCE_2018)
    m = load_model(tmp_path)
    assert m.name == "toy_1" and m.horizon is None and m.discount == 0.9
    # objects of a subtype are members of the supertype too
    assert m.objects("widget") == ("w1",)
    assert m.objects("thing") == ("t1", "t2", "w1")
    assert m.value_of("W") == 2.5
    assert m.value_of("on", ("t1",)) is True and m.value_of("on", ("t2",)) is False
    assert m.value_of("lvl") == "@low"
    assert m.pvariables["n"].level == 1


def test_instances_pair_with_domains_by_name_across_files(tmp_path: Path) -> None:
    (tmp_path / "a_domain.rddl").write_text(DOMAIN)
    (tmp_path / "b_instance.rddl").write_text(INSTANCE_2018)
    assert list(load(tmp_path)) == ["toy_1"]
    # the same pair given explicitly, as rddlrepository pairs files
    assert load_pair(tmp_path / "a_domain.rddl", tmp_path / "b_instance.rddl").name == "toy_1"


def test_missing_domain_is_reported_with_the_instance(tmp_path: Path) -> None:
    (tmp_path / "inst.rddl").write_text(INSTANCE_2018)
    with pytest.raises(RDDLSemanticError) as info:
        load(tmp_path)
    d = info.value.first
    assert (d.kind, d.line, d.column) == ("unknown-domain", 1, 10)


def test_domain_without_instance_is_checked_on_its_own(tmp_path: Path) -> None:
    (tmp_path / "d.rddl").write_text(DOMAIN)
    (r,) = check_files(tmp_path)
    assert (r.kind, r.name, r.ok) == ("domain", "toy", True)
    (tmp_path / "d.rddl").write_text(DOMAIN.replace("on(?t) + 1", "onn(?t) + 1"))
    (r,) = check_files(tmp_path)
    assert not r.ok and r.diagnostics[0].kind == "unknown-name"


def test_duplicate_same_value_assignments_are_accepted(tmp_path: Path) -> None:
    # IPPC 2014 TriangleTireworld repeats init-state lines; rddlsim accepts them.
    text = INSTANCE_2018.replace("init-state { on(t1);", "init-state { on(t1); on(t1);")
    (tmp_path / "t.rddl").write_text(DOMAIN + text)
    assert load_model(tmp_path).value_of("on", ("t1",)) is True
    text = INSTANCE_2018.replace("init-state { on(t1);", "init-state { on(t1); ~on(t1);")
    (tmp_path / "t.rddl").write_text(DOMAIN + text)
    with pytest.raises(RDDLSemanticError, match="twice, to true and false"):
        load(tmp_path)
