"""Experiment files: what they say, and one clear error per problem, with its line and
column."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest
from ippc.batch import (
    BatchStore,
    ExperimentError,
    check_experiment,
    load_experiment,
    parse_experiment,
    resolve_instances,
)
from ippc.batch.experiment import fill_command
from ippc.batch.instances import domain_of
from ippc.batch.jobs import build_jobs, stable_seed
from ippc.server import store as server_store

from .conftest import REPO

EXAMPLES = REPO / "examples"


def problems(text: str, name: str = "exp.toml") -> list[str]:
    with pytest.raises(ExperimentError) as info:
        parse_experiment(text, Path(name))
    return info.value.problems


def test_the_issue_example_reads_as_written(tmp_path: Path) -> None:
    (tmp_path / "exp.toml").write_text(
        "rounds = 3\ntimeout = 60            # seconds per session\n"
        f'instances = ["{REPO / "domains" / "print_jobs"}/", "SysAdmin_MDP_ippc2011:1"]\n'
        '[planners.mcts]\nplanner = "mcts"\noptions = { seed = "1" }\n'
        "[planners.prost]\n"
        'command = "rddl-client --host {host} --port {port} --instance {instance} --prost /path/to/search"\n'
    )
    exp = load_experiment(tmp_path / "exp.toml")
    assert (exp.rounds, exp.timeout, exp.name) == (3, 60.0, "exp")
    assert [p.label for p in exp.planners] == ["noop", "random", "mcts", "prost"]
    assert exp.planner("mcts").options == {"seed": "1"}
    assert exp.planner("prost").command is not None
    argv = fill_command(exp.planner("prost").command, {"host": "h", "port": 9, "instance": "i"})
    assert argv == [
        "rddl-client",
        "--host",
        "h",
        "--port",
        "9",
        "--instance",
        "i",
        "--prost",
        "/path/to/search",
    ]
    names = [i.name for i in resolve_instances(exp)]
    assert names == [
        "print_jobs_inst_1",
        "print_jobs_inst_2",
        "print_jobs_inst_3",
        "sysadmin_inst_mdp__1",
    ]


def test_every_problem_is_reported_with_its_place_in_file_order() -> None:
    text = (
        "rounds = 0\n"  # 1
        'instances = ["x"]\n'  # 2
        "colour = 3\n"  # 3
        "[planners.a]\n"  # 4
        'planner = "no-such-planner"\n'  # 5
        "[planners.b]\n"  # 6
        'planner = "mcts"\n'  # 7
        'options = { exploraton = "2" }\n'  # 8
        "[planners.c]\n"  # 9
        'command = "prog --port {port} {hots}"\n'  # 10
        "[planners.d]\n"  # 11
        'command = "prog"\n'  # 12
        'planner = "noop"\n'  # 13
    )
    found = problems(text)
    assert found[0] == "exp.toml:1:1: 'rounds' must be an integer >= 1, got 0"
    assert (
        found[1]
        == "exp.toml:3:1: unknown key 'colour' (known: instances, jobs, name, planners, rounds, seed, timeout)"
    )
    assert found[2].startswith("exp.toml:5:1: planners.a: unknown planner 'no-such-planner'")
    # the option the planner refused, not its table
    assert found[3].startswith(
        "exp.toml:8:13: planners.b: planner 'mcts' has no option 'exploraton'"
    )
    assert found[4].startswith("exp.toml:10:31: planners.c: unknown placeholder {hots}")
    assert found[5].startswith("exp.toml:11:1: planners.d: give exactly one of 'planner'")
    assert len(found) == 6


def test_toml_syntax_error_names_line_and_column() -> None:
    (found,) = problems('rounds = 3\ninstances = ["a",\n[planners.x]\n')
    assert found == "exp.toml:3:2: not valid TOML: Invalid value"
    # tomllib says "at end of document": the end of the last line
    (found,) = problems('rounds = 3\ninstances = [\n  "a",\n')
    assert found == "exp.toml:3:7: not valid TOML: Invalid value"


def test_command_needs_the_port_and_options_belong_to_registered_planners() -> None:
    found = problems('instances = ["a"]\n[planners.c]\ncommand = "prog --host {host}"\n')
    assert found == [
        "exp.toml:3:1: planners.c: 'command' must contain {port} (the port of the session's server)"
    ]
    found = problems('instances = ["a"]\n[planners.random]\nplanner = "noop"\n')
    assert found == [
        "exp.toml:2:1: planners.random: the label 'random' is kept for the random baseline"
    ]


def test_instance_problems_name_the_spec_line(tmp_path: Path) -> None:
    (tmp_path / "exp.toml").write_text(
        "instances = [\n"
        '  "missing/folder/",\n'  # 2
        '  "SysAdmin_MDP_ippc2011:11",\n'  # 3
        '  "SysAdmin_MDP_ippc2011:3-1",\n'  # 4
        '  "NoSuchProblem_ippc2011:1",\n'  # 5
        f'  "{REPO / "tests" / "data" / "rddlsim" / "rddl" / "sysadmin_inst_mdp__1.rddl"}",\n'  # 6: fine
        "]\n"
    )
    exp = load_experiment(tmp_path / "exp.toml")
    with pytest.raises(ExperimentError) as info:
        resolve_instances(exp)
    where = str(tmp_path / "exp.toml")
    assert info.value.problems == [
        f"{where}:2:3: instance spec 'missing/folder/': no such file or folder",
        f"{where}:3:3: instance spec 'SysAdmin_MDP_ippc2011:11': SysAdmin_MDP_ippc2011 has no instance 11 "
        "(it has 1, 2, 3, 4, 5, 6, 7, 8, 9, 10)",
        f"{where}:4:3: instance spec 'SysAdmin_MDP_ippc2011:3-1': instance numbers must look like 1, 1-5 or 1,3,7",
        f"{where}:5:3: instance spec 'NoSuchProblem_ippc2011:1': no file, folder or rddlrepository problem of that name",
    ]


def test_instance_problems_come_with_the_files_other_problems(tmp_path: Path) -> None:
    # one run shows them all: the file's own problems and its instances', in file order
    (tmp_path / "exp.toml").write_text(
        'rounds = 0\ninstances = ["nowhere/", "SysAdmin_MDP_ippc2011:99"]\n'
        '[planners.m]\nplanner = "mcts"\noptions = { iterations = "many" }\n'
    )
    with pytest.raises(ExperimentError) as info:
        check_experiment(tmp_path / "exp.toml")
    (tmp_path / "exp.toml").write_text('rounds = 1\ninstances = ["SysAdmin_MDP_ippc2011:2"]\n')
    exp, instances = check_experiment(tmp_path / "exp.toml")
    assert exp.rounds == 1 and [i.name for i in instances] == ["sysadmin_inst_mdp__2"]
    where = str(tmp_path / "exp.toml")
    assert [p.split(" ", 1)[0] for p in info.value.problems] == [
        f"{where}:1:1:",
        f"{where}:2:14:",
        f"{where}:2:26:",
        f"{where}:5:13:",
    ]
    assert "'nowhere/': no such file or folder" in info.value.problems[1]
    assert "has no instance 99" in info.value.problems[2]


def test_examples_check_and_resolve() -> None:
    for name, n_instances in (("small.toml", 4), ("ippc2011.toml", 40)):
        exp = load_experiment(EXAMPLES / name)
        instances = resolve_instances(exp)
        assert len(instances) == n_instances, name
        assert {"noop", "random"} <= {p.label for p in exp.planners}
    domains = {i.domain for i in resolve_instances(load_experiment(EXAMPLES / "ippc2011.toml"))}
    assert len(domains) == 8


def test_seeds_are_stable_and_shared_by_the_planners_of_an_instance() -> None:
    exp = parse_experiment(
        f'seed = 3\ninstances = ["{REPO / "domains" / "print_jobs"}"]\n', Path("e.toml")
    )
    jobs = build_jobs(exp, resolve_instances(exp))
    assert stable_seed(3, "server", "print_jobs_inst_1") == stable_seed(
        3, "server", "print_jobs_inst_1"
    )
    by_instance: dict[str, set[int]] = {}
    for job in jobs:
        by_instance.setdefault(job.instance, set()).add(job.server_seed)
    assert all(len(s) == 1 for s in by_instance.values())  # common random numbers
    assert len({j.planner_seed for j in jobs}) == len(jobs)
    assert domain_of("sysadmin_inst_mdp__3") == "sysadmin_mdp"


def test_a_version_2_database_is_migrated_in_place(tmp_path: Path) -> None:
    db = tmp_path / "old.sqlite"
    conn = sqlite3.connect(db)
    conn.executescript(server_store._SCHEMA)
    conn.execute(
        "INSERT INTO sessions (server_session_id, instance, client_name, seed, num_rounds, time_allowed_ms,"
        " peer, no_header, started_at, owner) VALUES (1, 'i', 'c', 0, 30, 1000, 'p', 0, 0, 'o')"
    )
    conn.execute("PRAGMA user_version = 2")  # the schema before rddl-batch's jobs
    conn.commit()
    conn.close()
    with BatchStore(db) as store:
        assert store.raw("PRAGMA user_version")[0][0] == server_store.SCHEMA_VERSION == 5
        assert store.raw("SELECT instance FROM sessions")[0][0] == "i"  # kept
        assert store.jobs() == []
    with server_store.ResultStore(db) as rs:  # the server reads it as before
        assert rs.sessions()[0]["client_name"] == "c"


def test_the_bad_file_of_the_docs_gets_the_lines_the_docs_show(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import re

    from click.testing import CliRunner
    from ippc.batch.cli import main

    page = (REPO / "docs" / "batch.md").read_text()
    toml = re.search(r"^```toml exp.toml\n(.*?)^```$", page, re.S | re.M)
    shown = re.search(r"^```text rddl-batch run exp.toml\n(.*?)^```$", page, re.S | re.M)
    assert toml is not None and shown is not None
    (tmp_path / "exp.toml").write_text(toml.group(1))
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(main, ["run", "exp.toml"])
    assert result.exit_code == 2
    got = result.output.splitlines()
    expected = shown.group(1).splitlines()
    assert len(got) == len(expected), result.output
    for line, pattern in zip(got, expected, strict=True):
        # "(...)" on the page stands for a list in brackets
        assert re.fullmatch(re.escape(pattern).replace(r"\(\.\.\.\)", r"\(.*\)"), line), line


def test_jobs_carry_files_that_are_not_utf8() -> None:
    # Tamarisk 2014's domain file holds a cp1252 dash (byte 0x96) in a comment;
    # the jobs' texts are read as the RDDL loader reads files (Latin-1 there)
    exp = parse_experiment('instances = ["Tamarisk_MDP_ippc2014:1"]\n', Path("e.toml"))
    jobs = build_jobs(exp, resolve_instances(exp))
    assert [j.planner.label for j in jobs] == ["noop", "random"]
    assert all(any("351\x9663" in t for t in job.texts) for job in jobs)
