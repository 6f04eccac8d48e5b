"""Episodes, the random policy, legal actions and `rddl sim`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from ippc.rddl import load, load_pair
from ippc.rddl.cli import main
from ippc.rddl.rollout import run_episodes
from ippc.rddl.simulator import SimulationError, Simulator

REPO = Path(__file__).resolve().parents[2]
DOMAINS = REPO / "domains"


def test_random_policy_respects_max_nondef_actions(rddlsim_rddl: Path) -> None:
    m = load(rddlsim_rddl)["sysadmin_inst_mdp__1"]
    sim = Simulator(m)
    rng = np.random.default_rng(0)
    s = sim.initial_state(200)
    for _ in range(5):
        acts = sim.random_actions(s, rng)
        per_state = acts["reboot"].sum(axis=1)
        assert per_state.max() <= 1  # max-nondef-actions = 1
        # ten coin flips: some reboot is taken unless all ten fail (1 in 1024)
        assert (per_state == 1).mean() > 0.97
        s = sim.step(s, acts, rng).next_state


def test_random_policy_respects_preconditions() -> None:
    m = load(DOMAINS / "print_jobs")["print_jobs_inst_2"]
    sim = Simulator(m)
    rng = np.random.default_rng(1)
    s = sim.initial_state(64)
    chose_something = 0
    for _ in range(10):
        acts = sim.random_actions(s, rng)
        assert sim.check_actions(s, acts).all()
        chose_something += int(sim.count_nondefault(acts, 64).sum())
        s = sim.step(s, acts, rng).next_state
    assert chose_something > 0


def test_random_enum_actions_stay_in_the_enum() -> None:
    m = load(DOMAINS / "corridor_enum")["corridor_enum_inst_1"]
    sim = Simulator(m)
    acts = sim.random_actions(sim.initial_state(100), np.random.default_rng(2))
    codes = acts["step"]
    assert codes.min() >= 0 and codes.max() < len(m.objects("direction"))
    names = {n for i in range(100) for n in sim.actions_to_names(acts, i)}
    assert names <= {"step = @left", "step = @right"}  # the default @stay is never listed


def test_legal_actions_of_a_boolean_action_space(rddlsim_rddl: Path) -> None:
    sim = Simulator(load(rddlsim_rddl)["sysadmin_inst_mdp__1"])
    legal = sim.legal_actions(sim.initial_state())
    assert legal["reboot"].shape == (11, 10)  # noop and each single reboot
    assert legal["reboot"][0].sum() == 0
    pf = Simulator(load(DOMAINS / "print_jobs")["print_jobs_inst_1"])
    legal = pf.legal_actions(pf.initial_state())
    # at the dock: noop or the one move the map allows
    assert [pf.actions_to_names(legal, i) for i in range(len(legal["move"]))] == [
        [],
        ["move(printroom) = true"],
    ]


def test_run_episodes_counts_and_reproducibility(rddlsim_rddl: Path) -> None:
    m = load(rddlsim_rddl)["sysadmin_inst_mdp__1"]  # horizon 5 in the recorded files
    a = run_episodes(m, "random", episodes=30, seed=5)
    b = run_episodes(m, "random", episodes=30, seed=5)
    assert a.steps == 30 * 5 and a.returns.shape == (30,)
    assert (a.returns == b.returns).all()
    noop = run_episodes(m, "noop", episodes=30, seed=5)
    assert noop.returns.max() <= 10 * 5  # at most ten running computers a step


def test_termination_ends_episodes_early() -> None:
    m = load(DOMAINS / "corridor_enum")["corridor_enum_inst_1"]
    stats = run_episodes(m, "random", episodes=200, seed=3)
    assert stats.steps < 200 * (m.horizon or 0)


def test_cli_sim_json() -> None:
    res = CliRunner().invoke(
        main,
        [
            "sim",
            str(DOMAINS / "print_jobs" / "domain.rddl"),
            str(DOMAINS / "print_jobs" / "instance1.rddl"),
            "--policy",
            "random",
            "--episodes",
            "20",
            "--seed",
            "4",
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    data = json.loads(res.output)
    assert set(data) == {
        "instance",
        "episodes",
        "mean_return",
        "std_return",
        "steps",
        "steps_per_second",
    }
    assert (
        data["instance"] == "print_jobs_inst_1"
        and data["episodes"] == 20
        and data["steps"] == 20 * 20
    )
    again = json.loads(
        CliRunner()
        .invoke(
            main,
            [
                "sim",
                str(DOMAINS / "print_jobs" / "domain.rddl"),
                str(DOMAINS / "print_jobs" / "instance1.rddl"),
                "--policy",
                "random",
                "--episodes",
                "20",
                "--seed",
                "4",
                "--json",
            ],
        )
        .output
    )
    assert again["mean_return"] == data["mean_return"]


def test_cli_sim_reports_simulation_errors(tmp_path: Path) -> None:
    from .test_parser import DOMAIN, INSTANCE_2018

    (tmp_path / "d.rddl").write_text(
        DOMAIN.replace("on'(?t) = go(?t) | on(?t);", "on'(?t) = Bernoulli(W);")
    )
    (tmp_path / "i.rddl").write_text(INSTANCE_2018.replace("horizon = pos-inf;", "horizon = 3;"))
    res = CliRunner().invoke(main, ["sim", str(tmp_path / "d.rddl"), str(tmp_path / "i.rddl")])
    assert res.exit_code == 1
    assert "Bernoulli probability outside [0, 1]: 2.5" in res.output


def test_pos_inf_horizon_needs_a_horizon(tmp_path: Path) -> None:
    from .test_parser import DOMAIN, INSTANCE_2018

    (tmp_path / "d.rddl").write_text(DOMAIN)
    (tmp_path / "i.rddl").write_text(INSTANCE_2018)
    m = load_pair(tmp_path / "d.rddl", tmp_path / "i.rddl")
    with pytest.raises(SimulationError, match="no finite horizon"):
        run_episodes(m)
    assert run_episodes(m, horizon=4).steps <= 4
