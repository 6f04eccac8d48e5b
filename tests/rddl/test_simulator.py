"""The simulator: rddlsim's semantics on the recorded sessions, batches,
reproducibility, constraints and parameter checks."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from ippc.rddl import load, load_model
from ippc.rddl.simulator import SimulationError, Simulator

from .test_parser import DOMAIN, INSTANCE_2018

_FLUENT = re.compile(
    r"<observed-fluent><fluent-name>([^<]*)</fluent-name>((?:<fluent-arg>[^<]*</fluent-arg>)*)"
    r"<fluent-value>([^<]*)</fluent-value></observed-fluent>"
)
_ACTION = re.compile(
    r"<action>\s*<action-name>([^<]*)</action-name>((?:\s*<action-arg>[^<]*</action-arg>)*)"
    r"\s*<action-value>([^<]*)</action-value>\s*</action>"
)
_ARG = re.compile(r"<(?:fluent|action)-arg>([^<]*)</")


def _value(text: str, rng: str) -> object:
    if rng == "bool":
        return text == "true"
    if rng == "int":
        return int(float(text))
    if rng == "real":
        return float(text)
    return text if text.startswith("@") else "@" + text


def _episodes(path: Path) -> list[list[tuple[str, str | None]]]:
    """Per round: (turn message, actions message sent after it)."""
    rounds: list[list[tuple[str, str | None]]] = []
    current: list[tuple[str, str | None]] = []
    for line in path.read_text().splitlines():
        d = json.loads(line)
        data = d.get("data")
        if not data:
            continue
        if "<round-init>" in data:
            current = []
            rounds.append(current)
        elif "<turn>" in data:
            current.append((data, None))
        elif "<actions" in data and current and current[-1][1] is None:
            current[-1] = (current[-1][0], data)
    return [r for r in rounds if r]


# (transcript, instance): the Java-client sessions of MDPs
RECORDED = [
    ("java_sysadmin_mdp", "sysadmin_inst_mdp__1"),
    ("java_game_of_life", "game_of_life_inst_mdp__1"),
    ("java_elevators", "elevators_inst_mdp__1"),
    ("java_crossing_traffic", "crossing_traffic_inst_mdp__1"),
    ("java_sidewalk", "is2"),
    ("java_traffic_ctm_enum", "inst_traffic_binary_ctm"),
]


@pytest.mark.parametrize("scenario, instance", RECORDED)
def test_agrees_with_rddlsim_recordings(recordings: Path, scenario: str, instance: str) -> None:
    model = load(recordings / "rddlsim" / "rddl")[instance]
    sim = Simulator(model)
    rng = np.random.default_rng(7)
    state_fluents = {p.name: p for p in sim.state_fluents}
    rounds = _episodes(recordings / "rddlsim" / "transcripts" / f"{scenario}.jsonl")
    assert rounds
    checked = 0
    for turns in rounds:
        states = []
        for turn, _ in turns:
            named = {}
            for name, args, value in _FLUENT.findall(turn):
                key = f"{name}({','.join(_ARG.findall(args))})" if args else name
                named[key] = _value(value, state_fluents[name].range)
            states.append(named)
        # the first turn shows the instance's initial state, every grounding
        assert sim.state_to_names(sim.initial_state()) == states[0]
        for k in range(len(turns) - 1):
            state = sim.initial_state()
            for p in sim.state_fluents:  # set the state the server reported
                for args, idx in sim._ground(p):
                    key = f"{p.name}({','.join(args)})" if args else p.name
                    state.values[p.name][(0, *idx)] = sim._encode(p, states[k][key])
            acts = {}
            for name, args, value in _ACTION.findall(turns[k][1] or ""):
                p = model.pvariables[name]
                acts[(name, tuple(_ARG.findall(args)))] = _value(value, p.range)
            actions = sim.actions_from_names([acts] * 256)
            batch = state[[0] * 256]
            out = sim.step(batch, actions, rng)
            reported = float(re.search(r"<immediate-reward>([^<]*)<", turns[k + 1][0]).group(1))  # type: ignore[union-attr]
            # the reward of a transition depends on state and actions only here
            assert out.reward == pytest.approx(np.full(256, reported)), (scenario, k)
            # every recorded next-state value is one the simulator can produce
            seen: dict[str, set[object]] = {}
            for i in range(256):
                for key, v in sim.state_to_names(out.next_state, i).items():
                    seen.setdefault(key, set()).add(v)
            for key, v in states[k + 1].items():
                assert v in seen[key], (scenario, k, key, v, seen[key])
            checked += 1
    assert checked >= 4


def test_sysadmin_deterministic_reboot_and_reward(rddlsim_rddl: Path) -> None:
    m = load(rddlsim_rddl)["sysadmin_inst_mdp__1"]
    sim = Simulator(m)
    s = sim.initial_state(3)
    s.values["running"][:, 2] = False  # c3 is down in every state of the batch
    acts = sim.actions_from_names({("reboot", ("c3",)): True})
    acts = {k: np.repeat(v, 3, axis=0) for k, v in acts.items()}
    out = sim.step(s, acts, np.random.default_rng(1))
    assert out.next_state.values["running"][:, 2].all()  # a rebooted computer runs
    # reward: 1 per running computer (9) minus 0.75 per reboot
    assert out.reward.tolist() == [8.25, 8.25, 8.25]
    assert out.observation is None and not out.done.any()


def test_same_seed_same_trajectory(rddlsim_rddl: Path) -> None:
    m = load(rddlsim_rddl)["game_of_life_inst_mdp__1"]
    sim = Simulator(m)

    def run(seed: int) -> list[np.ndarray]:
        rng = np.random.default_rng(seed)
        s = sim.initial_state(8)
        out = []
        for _ in range(5):
            step = sim.step(s, sim.noop(8), rng)
            s = step.next_state
            out.append(step.reward)
        return out

    a, b, c = run(3), run(3), run(4)
    assert all((x == y).all() for x, y in zip(a, b, strict=True))
    assert any((x != z).any() for x, z in zip(a, c, strict=True))


def test_max_nondef_actions_and_legal_mask(rddlsim_rddl: Path) -> None:
    m = load(rddlsim_rddl)["sysadmin_inst_mdp__1"]
    sim = Simulator(m)
    two = sim.actions_from_names({("reboot", ("c1",)): True, ("reboot", ("c2",)): True})
    with pytest.raises(SimulationError, match="max-nondef-actions is 1"):
        sim.step(sim.initial_state(), two, np.random.default_rng(0))
    one = sim.actions_from_names([{("reboot", ("c1",)): True}, {}])
    both = {k: np.concatenate([two[k], one[k]]) for k in two}
    assert sim.check_actions(sim.initial_state(3), both).tolist() == [False, True, True]


def test_preconditions_name_the_constraint(tmp_path: Path) -> None:
    (tmp_path / "toy.rddl").write_text(DOMAIN + INSTANCE_2018)
    m = load_model(tmp_path)
    sim = Simulator(m)
    s = sim.initial_state()
    go_on = sim.actions_from_names({("go", ("t1",)): True})  # t1 is on: go(t1) is illegal
    with pytest.raises(SimulationError) as info:
        sim.step(s, go_on, np.random.default_rng(0))
    msg = str(info.value)
    assert ":23:" in msg and "go(t1) = true" in msg
    assert "forall_{?t : thing} (go(?t) => ~on(?t))" in msg
    ok = sim.actions_from_names({("go", ("t2",)): True})
    out = sim.step(s, ok, np.random.default_rng(0))
    assert out.next_state.values["on"].tolist() == [[True, True, False]]
    assert out.reward.tolist() == [2.5]  # sum_{t} on(t) * W over the current state: only t1 is on
    assert out.observation is not None and out.observation["o"].tolist() == [[True, True, False]]
    assert not out.done.any()
    assert m.objects("thing") == ("t1", "t2", "w1")


def test_bad_distribution_parameters_raise(tmp_path: Path) -> None:
    text = DOMAIN.replace("on'(?t) = go(?t) | on(?t);", "on'(?t) = Bernoulli(W);") + INSTANCE_2018
    (tmp_path / "toy.rddl").write_text(text)
    sim = Simulator(load_model(tmp_path))  # W = 2.5 is no probability
    with pytest.raises(SimulationError, match=r"Bernoulli probability outside \[0, 1\]: 2.5"):
        sim.step(sim.initial_state(), None, np.random.default_rng(0))


def test_batch_matches_single_states(rddlsim_rddl: Path) -> None:
    m = load(rddlsim_rddl)["elevators_inst_mdp__1"]
    sim = Simulator(m)
    s = sim.initial_state(1024)
    out = sim.step(s, sim.noop(1024), np.random.default_rng(0))
    assert out.reward.shape == (1024,)
    for name, arr in out.next_state.values.items():
        assert arr.shape[0] == 1024, name
    # indexing a batch gives a batch of one
    assert out.next_state[5].batch == 1


IID = """\
domain iid { types { obj : object; };
  pvariables { p(obj) : { state-fluent, bool, default = false };
               a : { action-fluent, bool, default = false }; };
  cpfs { p'(?x) = Bernoulli(0.5); };
  reward = sum_{?x : obj} p(?x); }
instance iid_1 { domain = iid; objects { obj : {o1,o2,o3,o4,o5,o6,o7,o8}; };
  max-nondef-actions = 1; horizon = 10; discount = 1.0; }
"""


def test_each_grounding_draws_independently(tmp_path: Path) -> None:
    # Bernoulli(0.5) depends on no variable, yet every ?x gets its own draw
    (tmp_path / "iid.rddl").write_text(IID)
    sim = Simulator(load_model(tmp_path))
    out = sim.step(sim.initial_state(2000), None, np.random.default_rng(0))
    p = out.next_state.values["p"]
    rows_all_equal = (p.all(axis=1) | (~p).all(axis=1)).mean()
    assert rows_all_equal < 0.05  # 2 / 2**8 if independent, 1.0 if shared
    assert abs(p.mean() - 0.5) < 0.02
    # and the next state is the caller's to change
    p[0, 0] = not p[0, 0]
