"""The whole loop: world (or a robot), sensing, knowledge base, dispatcher,
planner over the IPPC protocol, handlers."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from click.testing import CliRunner
from ippc.dispatch.actions import Dispatch
from ippc.dispatch.cli import main
from ippc.dispatch.run import PlannerSpec, executed_plan, simulate
from ippc.dispatch.world import SimulatedWorld
from ippc.server.store import ResultStore

from .conftest import DOMAIN, ONE, TWO

# what the optimal policy does on courier_one with the world's seed 1: the
# sender is at the desk when the robot gets there
PLAN_SEED_1 = [
    ("move(r1,hall,office)", "succeeded"),
    ("pickup(r1)", "succeeded"),
    ("move(r1,office,hall)", "succeeded"),
    ("move(r1,hall,lab)", "succeeded"),
    ("drop(r1)", "succeeded"),
]


def plan(report_executed: list[dict[str, object]]) -> list[tuple[object, object]]:
    return [(e["action"], e["outcome"]) for e in report_executed]


@pytest.mark.parametrize("no_header", [False, True], ids=["nul", "no-header"])
def test_a_built_in_planner_reaches_the_goal_with_either_framing(
    tmp_path: Path, no_header: bool
) -> None:
    db = tmp_path / "runs.db"
    report = simulate(DOMAIN, ONE, seed=1, planner=PlannerSpec("exact", no_header=no_header), db=db)
    assert report.goal_reached and report.session_status == "finished"
    assert plan(report.executed) == PLAN_SEED_1
    assert [e["turn"] for e in report.executed] == [1, 2, 3, 4, 5]
    assert report.turns == 5 and report.rounds == 1 and report.failed_actions == 0
    assert report.reward == -5.0  # -1 a step until delivered, as the world counted
    assert report.execution_seconds == pytest.approx(5 * 1.1)  # 1 s an action + a settle period
    assert report.planning_seconds > 0.0 and report.planner_error is None
    # every turn is in the result store, with its outcome, and the plan prints from there
    with ResultStore(db) as store:
        (session,) = store.sessions()
        assert session["no_header"] is no_header and session["status"] == "finished"
        (rnd,) = store.rounds(session["id"])
        assert rnd["status"] == "terminal" and rnd["turns_used"] == 5
        steps = store.steps(rnd["id"])
        assert [s["actions"] for s in steps][0] == [
            ("move", ("r1", "hall", "office"), "true")
        ]  # as received
        assert ("robot-at", ("r1", "hall"), True) in steps[0]["state"]
        assert steps[-1]["outcome"]["goal"] is True
        assert all(s["execution_seconds"] == pytest.approx(1.1) for s in steps)
    assert plan(executed_plan(db)) == PLAN_SEED_1


def test_an_injected_failure_is_logged_and_the_next_turn_is_replanned() -> None:
    def fail_first_pickup(d: Dispatch, world: SimulatedWorld) -> bool:
        return d.action.name == "pickup" and world.steps == 1

    report = simulate(DOMAIN, ONE, seed=1, planner=PlannerSpec("exact"), failures=fail_first_pickup)
    assert report.goal_reached
    executed = plan(report.executed)
    assert executed[:3] == [
        ("move(r1,hall,office)", "succeeded"),
        ("pickup(r1)", "failed"),
        ("pickup(r1)", "succeeded"),
    ]
    assert report.executed[1]["message"] == "injected failure"
    assert report.failed_actions == 1 and report.replans == 1
    assert report.turns == 6


def test_fake_prost_plays_concurrent_actions(prost_dir: Path, tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    script = tmp_path / "actions.txt"
    script.write_text(
        "Submitted action: move(r1, hall, office) move(r2, lab, hall) \n"
        "Submitted action: pickup(r1) \n"
        "Submitted action: drop(r2) \n"  # r2 holds nothing: precondition false, not dispatched
        "Submitted action: move(r1, office, hall) \n"
        "Submitted action: move(r1, hall, lab) \n"
        "Submitted action: drop(r1) \n"
    )
    monkeypatch.setenv("FAKE_PROST_ACTIONS_FILE", str(script))
    report = simulate(
        DOMAIN,
        TWO,
        seed=1,
        planner=PlannerSpec(prost=str(prost_dir / "search")),
        rounds=1,
        durations={"move": 3.0, "pickup": 1.0, "drop": 1.0},
    )
    assert report.planner == "prost" and report.planner_error is None
    assert report.goal_reached and report.turns == 6
    assert plan(report.executed) == [
        ("move(r1,hall,office)", "succeeded"),
        ("move(r2,lab,hall)", "succeeded"),
        ("pickup(r1)", "succeeded"),
        ("drop(r2)", "precondition-false"),
        ("move(r1,office,hall)", "succeeded"),
        ("move(r1,hall,lab)", "succeeded"),
        ("drop(r1)", "succeeded"),
    ]
    # the constraint that failed, with its place in the domain file
    assert report.executed[3]["message"].startswith(f"{DOMAIN}:65:9: constraint violated")
    assert "(drop(?r) => holding(?r)); actions: drop(r2) = true" in report.executed[3]["message"]
    # the two moves of turn 1 ran at once: 3 s, not 6 (plus a settle period each turn)
    assert report.execution_seconds == pytest.approx(3 + 1 + 0 + 3 + 3 + 1 + 6 * 0.1)


def test_the_cli_simulates_and_writes_json(tmp_path: Path) -> None:
    out = tmp_path / "run.json"
    result = CliRunner().invoke(
        main,
        [
            str(DOMAIN),
            str(ONE),
            "--simulate",
            "--seed",
            "1",
            "--planner",
            "exact",
            "-q",
            "--json-out",
            str(out),
        ],
    )
    assert result.exit_code == 0, result.output
    assert "   2  pickup(r1)" in result.output
    assert "goal reached: 5 turns in 1 round(s), reward -5" in result.output
    data = json.loads(out.read_text())
    for key in (
        "goal_reached",
        "turns",
        "reward",
        "executed",
        "failed_actions",
        "planning_seconds",
    ):
        assert key in data
    assert data["goal_reached"] is True and data["failed_actions"] == 0
    assert [(e["turn"], e["action"], e["outcome"]) for e in data["executed"]][1] == (
        2,
        "pickup(r1)",
        "succeeded",
    )


def test_the_cli_refuses_bad_combinations(tmp_path: Path) -> None:
    runner = CliRunner()
    both = runner.invoke(main, [str(DOMAIN), str(ONE), "--planner", "noop", "--prost", "x"])
    assert both.exit_code != 0 and "give --planner or --prost, not both" in both.output
    unknown = runner.invoke(main, [str(DOMAIN), str(ONE), "--simulate", "--planner", "nope"])
    assert unknown.exit_code != 0 and "nope" in unknown.output
    nothing = runner.invoke(main, [])
    assert nothing.exit_code != 0 and "DOMAIN and INSTANCE are needed" in nothing.output


def test_the_cli_reports_a_bad_sensing_config_or_robot_file(tmp_path: Path) -> None:
    config = tmp_path / "sensing.yaml"
    config.write_text("sensors:\n  present:\n    stream: cam\n    value: open('/etc/passwd')\n")
    robot = tmp_path / "robot.py"
    robot.write_text("def setup(robot):\n    raise RuntimeError('no robot here')\n")
    runner = CliRunner()
    bad = runner.invoke(main, [str(DOMAIN), str(ONE), "--sensing", str(config)])
    assert bad.exit_code == 1
    assert f"{config}:4:12: present: value function calls are not allowed" in bad.output
    config.write_text("sensors:\n  present:\n    stream: cam\n    value: msg.seen\n")
    failing = runner.invoke(
        main, [str(DOMAIN), str(ONE), "--sensing", str(config), "--robot", str(robot)]
    )
    assert failing.exit_code == 1
    assert f"{robot}:2: setup failed: RuntimeError: no robot here" in failing.output
    robot.write_text("x = 1\n")
    empty = runner.invoke(main, [str(DOMAIN), str(ONE), "--robot", str(robot)])
    assert empty.exit_code == 1 and "defines no setup(robot) function" in empty.output
    robot.write_text("import trio\n\ndef setup(robot)\n    pass\n")
    syntax = runner.invoke(main, [str(DOMAIN), str(ONE), "--robot", str(robot)])
    assert syntax.exit_code == 1
    assert syntax.output == f"Error: {robot}:3:17: SyntaxError: expected ':'\n"
    robot.write_text("import trio\nspeed = top_speed / 2\n")
    name = runner.invoke(main, [str(DOMAIN), str(ONE), "--robot", str(robot)])
    assert name.output == f"Error: {robot}:2: NameError: name 'top_speed' is not defined\n"


def test_the_cli_refuses_a_planner_it_cannot_start_before_it_listens(tmp_path: Path) -> None:
    runner = CliRunner()
    args = [str(DOMAIN), str(ONE), "--simulate", "-q"]
    bad_option = runner.invoke(main, [*args, "--planner", "mcts", "--planner-option", "foo=1"])
    assert bad_option.exit_code == 1  # it played an empty session and exited 0
    assert bad_option.output.startswith("Error: planner 'mcts' has no option 'foo'")
    no_prost = runner.invoke(main, [*args, "--prost", str(tmp_path / "search")])
    assert no_prost.exit_code == 1
    assert no_prost.output == f"Error: prost: PROST binary not found: {tmp_path / 'search'}\n"
    orphan = runner.invoke(main, [*args, "--planner-option", "seed=1"])
    assert orphan.exit_code == 2 and "give --planner or --prost" in orphan.output


def test_the_cli_answers_a_file_that_is_not_a_store_with_one_line(tmp_path: Path) -> None:
    notes = tmp_path / "notes.db"
    notes.write_text("not a database\n")
    runner = CliRunner()
    run = runner.invoke(main, [str(DOMAIN), str(ONE), "--simulate", "--db", str(notes)])
    assert (run.exit_code, run.output) == (1, f"Error: --db {notes}: file is not a database\n")
    plan = runner.invoke(main, ["--plan-of", str(notes)])
    assert (plan.exit_code, plan.output) == (
        1,
        f"Error: --plan-of {notes}: file is not a database\n",
    )


def test_plan_of_skips_sessions_rddl_server_played(tmp_path: Path) -> None:
    from ippc.server.store import ResultStore

    db = tmp_path / "runs.db"
    simulate(DOMAIN, ONE, seed=1, planner=PlannerSpec("exact"), rounds=1, db=db)
    with ResultStore(db) as store:  # a session rddl-server played afterwards, in the same file
        sid = store.start_session(
            server_session_id=1,
            instance="courier_one",
            client_name="noop",
            seed=0,
            num_rounds=1,
            time_allowed_ms=1000.0,
            peer="127.0.0.1:1",
            no_header=False,
            started_at=0.0,
        )
        rnd = store.start_round(sid, round_num=1, counted=True, started_at=0.0)
        store.record_step(
            rnd,
            turn_num=1,
            state=[],
            actions=[],
            reward=0.0,
            turn_sent_at=0.0,
            actions_received_at=0.0,
        )
    assert plan(executed_plan(db)) == PLAN_SEED_1  # the last dispatcher session
    with pytest.raises(KeyError, match=f"session {sid} was not played by rddl-dispatch"):
        executed_plan(db, sid)


@pytest.mark.alone
def test_real_prost_reaches_the_goal() -> None:
    binary = os.environ.get("PROST_BIN")
    if not binary:
        pytest.skip(
            "no PROST: set PROST_BIN to PROST's search program (e.g. a build's bin/search-release, "
            "with rddl-parser-release beside it) to run the dispatcher against the real PROST"
        )
    report = simulate(
        DOMAIN, ONE, seed=1, planner=PlannerSpec(prost=binary), rounds=1, timeout=30.0
    )
    assert report.planner_error is None, report.planner_error
    assert report.goal_reached and plan(report.executed)[-1] == ("drop(r1)", "succeeded")


@pytest.mark.parametrize("which", ["--port", "--kb-port"])
def test_a_port_in_use_names_the_socket(tmp_path: Path, which: str) -> None:
    import socket

    config = tmp_path / "sensing.yaml"
    config.write_text("sensors:\n  present:\n    stream: cam\n    value: msg.seen\n")
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        args = [str(DOMAIN), str(ONE), "--sensing", str(config), "--planner", "exact", "-q"]
        args += ["--port", "0", "--kb-port", "0"]
        args[args.index(which) + 1] = str(port)
        result = CliRunner().invoke(main, args)
    what = "the planner's socket" if which == "--port" else "the knowledge base's socket"
    assert result.exit_code == 1
    assert f"Error: cannot listen on 127.0.0.1:{port} ({what}, {which}): " in result.output


def test_a_planner_that_raises_ends_its_session_not_the_dispatcher(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from ippc.dispatch import run as dispatch_run
    from ippc.planners.base import Planner

    class Broken(Planner):
        name = "broken"

        def act(self, obs):  # type: ignore[no-untyped-def]
            raise RuntimeError("planner bug")

    real = dispatch_run.make_planner
    monkeypatch.setattr(
        dispatch_run, "make_planner", lambda n, o: Broken() if n == "broken" else real(n, o)
    )
    report = simulate(DOMAIN, ONE, seed=1, planner=PlannerSpec("broken"), rounds=1)
    assert report.planner_error == "the planner raised RuntimeError: planner bug"
    assert report.session_status == "dropped" and report.turns == 0
    # the command line prints the report and says so in its status
    monkeypatch.setattr("ippc.dispatch.cli.make_planner", lambda n, o: Broken())
    result = CliRunner().invoke(main, [str(DOMAIN), str(ONE), "--simulate", "--planner", "broken"])
    assert result.exit_code == 1
    assert "goal not reached: 0 turns" in result.output
    assert "planner: the planner raised RuntimeError: planner bug" in result.output
    assert result.output.endswith("rddl-dispatch: the session dropped\n")


@pytest.mark.parametrize("mode", [["--simulate"], ["--port", "0"]], ids=["simulate", "robot"])
def test_a_partially_observed_instance_is_refused_in_one_line(mode: list[str]) -> None:
    folder = Path(__file__).resolve().parents[2] / "domains" / "print_jobs_pomdp"
    instance = folder / "instance1.rddl"
    result = CliRunner().invoke(main, [str(folder / "domain.rddl"), str(instance), *mode, "-q"])
    assert result.exit_code == 1
    assert result.output == (
        f"Error: {instance}: print_jobs_pomdp_inst_1 is partially observed: the dispatcher "
        "serves the knowledge base's state, so only MDP domains\n"
    )
