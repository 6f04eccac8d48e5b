"""rddl.wire: rddlsim's fluent order and its reading of received actions."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from ippc.rddl import load
from ippc.rddl.simulator import Simulator
from ippc.rddl.wire import WireCodec, WireError, java_string_hash, rddlsim_order
from lxml import etree


@pytest.fixture(scope="module")
def models(rddlsim_rddl: Path):
    return load(rddlsim_rddl)


@pytest.fixture(scope="module")
def sysadmin(models):
    return WireCodec(Simulator(models["sysadmin_inst_mdp__1"]))


def test_java_string_hash_matches_java():
    # values of "...".hashCode() in Java
    assert java_string_hash("") == 0
    assert java_string_hash("a") == 97
    assert java_string_hash("ab") == 3105
    assert java_string_hash("hello") == 99162322
    assert java_string_hash("polygenelubricants") == -(2**31)


def _recorded_turns(recordings: Path):
    for f in sorted((recordings / "rddlsim" / "transcripts").glob("*.jsonl")):
        lines = [json.loads(x) for x in f.read_text().splitlines()]
        inst = lines[0]["meta"].get("instance")
        for rec in lines[1:]:
            data = rec.get("data", "")
            if rec.get("dir") == "s2c" and "<turn>" in data and "<observed-fluent>" in data:
                yield f.stem, inst, data.rstrip("\0")


def test_fluent_order_and_initial_values_match_every_recorded_turn(models, recordings):
    codecs: dict[str, WireCodec] = {}
    checked = 0
    for scenario, inst, doc in _recorded_turns(recordings):
        if inst not in codecs:
            codecs[inst] = WireCodec(Simulator(models[inst]))
        wc = codecs[inst]
        root = etree.fromstring(doc.encode())
        got = [
            (of.findtext("fluent-name"), tuple(a.text for a in of.findall("fluent-arg")))
            for of in root.findall("observed-fluent")
        ]
        sim = wc.sim
        if wc.pomdp:
            ours = wc.observation({p.name: sim._default_array(p)[None] for p in sim.observ_fluents})
        else:
            ours = wc.state(sim.initial_state())
        assert got == [(n, a) for n, a, _ in ours], scenario
        if root.findtext("turn-num") == "1" and not wc.pomdp:
            values = [of.findtext("fluent-value") for of in root.findall("observed-fluent")]
            assert values == [_java(v) for _, _, v in ours], scenario
        checked += 1
    assert checked > 150


def _java(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def test_order_is_hashmap_order_not_declaration_order(models):
    m = models["elevators_inst_mdp__1"]
    order = [p.name for p in rddlsim_order(m, "state-fluent")]
    declared = [p.name for p in m.fluents("state-fluent")]
    assert sorted(order) == sorted(declared)
    assert order != declared
    assert order.index("elevator-closed") < order.index("elevator-at-floor")


def test_state_round_trip(sysadmin):
    sim = sysadmin.sim
    rng = np.random.default_rng(1)
    state = sim.step(sim.initial_state(), None, rng).next_state
    wire = sysadmin.state(state)
    back = sysadmin.state_from(wire)
    for k, v in state.values.items():
        assert np.array_equal(back.values[k], v)


def test_state_from_rejects_unknown_fluent(sysadmin):
    with pytest.raises(WireError, match="not a state fluent"):
        sysadmin.state_from([("nosuch", (), True)])
    with pytest.raises(WireError, match="unknown grounding"):
        sysadmin.state_from([("running", ("c99",), True)])


def test_actions_as_rddlsim_reads_them(sysadmin):
    state = sysadmin.sim.initial_state()
    d = sysadmin.actions_from([("reboot", ("c1",), True)])
    assert sysadmin.actions(d.arrays) == [("reboot", ("c1",), True)]
    assert sysadmin.check(state, d) is None
    # explicit default: no action, counts for nothing
    d = sysadmin.actions_from([("reboot", ("c1",), False), ("reboot", ("$c2",), True)])
    assert sysadmin.actions(d.arrays) == [("reboot", ("c2",), True)]
    # wrong arity / unknown object: no effect, but counted by max-nondef-actions
    d = sysadmin.actions_from([("reboot", (), True), ("reboot", ("c99",), True)])
    assert sysadmin.actions(d.arrays) == []
    assert d.extra_nondefault == 2 and len(d.ignored) == 2
    assert "max-nondef-actions" in sysadmin.check(state, d)
    # too many real ones
    d = sysadmin.actions_from([("reboot", ("c1",), True), ("reboot", ("c2",), True)])
    assert "2 actions differ" in sysadmin.check(state, d)


def test_state_fluent_as_action(sysadmin):
    state = sysadmin.sim.initial_state()
    default = sysadmin.model.default_of("running")
    d = sysadmin.actions_from([("running", ("c1",), not default)])
    assert d.illegal and "not an action" in sysadmin.check(state, d)
    with pytest.raises(WireError, match="not an action"):
        sysadmin.actions_from([("running", ("c1",), default)])
    with pytest.raises(WireError, match="unknown action"):
        sysadmin.actions_from([("reboot_all", (), True)])


def test_enum_values_outside_the_enum_match_nothing(models):
    wc = WireCodec(Simulator(models["is2"]))
    enum_actions = [p for p in wc.sim.action_fluents if p.range in wc.model.types]
    assert enum_actions
    p = enum_actions[0]
    args = tuple(wc.model.types[t].members[0] for t in p.params)
    d = wc.actions_from([(p.name, args, "@sideways")])
    assert int(np.asarray(d.arrays[p.name]).reshape(-1)[0]) == -1
