"""`rddl check` and `rddl fmt` as a user runs them."""

from __future__ import annotations

import json
from pathlib import Path

from click.testing import CliRunner
from ippc.rddl.cli import main

from .test_parser import DOMAIN, INSTANCE_2018


def test_check_ok_folder(rddlsim_rddl: Path) -> None:
    res = CliRunner().invoke(main, ["check", str(rddlsim_rddl)])
    assert res.exit_code == 0, res.output
    lines = res.output.strip().splitlines()
    assert lines[-1] == "9 checked (9 instances): 9 ok, 0 failed"
    assert any(line.startswith("ok    sysadmin_inst_mdp__1 ") for line in lines)


def test_check_reports_first_error_and_exit_code(tmp_path: Path) -> None:
    bad = DOMAIN.replace("on(?t) + 1", "onn(?t) + 1")
    (tmp_path / "toy.rddl").write_text(bad + INSTANCE_2018)
    res = CliRunner().invoke(main, ["check", str(tmp_path)])
    assert res.exit_code == 1
    first = res.output.splitlines()[0]
    assert first.startswith("FAIL  toy_1 ")
    assert f"{tmp_path / 'toy.rddl'}:17:17: unknown-name: unknown pvariable 'onn'" in first
    assert res.output.strip().endswith("1 checked (1 instances): 0 ok, 1 failed")


def test_check_verbose_shows_source_and_caret(tmp_path: Path) -> None:
    (tmp_path / "toy.rddl").write_text(DOMAIN.replace("on(?t) + 1", "onn(?t) + 1") + INSTANCE_2018)
    res = CliRunner().invoke(main, ["check", "-v", str(tmp_path)])
    assert "n(?t) = onn(?t) + 1;" in res.output
    caret_line = res.output.splitlines()[
        res.output.splitlines().index(
            next(line for line in res.output.splitlines() if line.strip() == "n(?t) = onn(?t) + 1;")
        )
        + 1
    ]
    source_line = next(
        line for line in res.output.splitlines() if line.strip() == "n(?t) = onn(?t) + 1;"
    )
    assert caret_line.index("^") == source_line.index("onn")


def test_check_json(tmp_path: Path) -> None:
    (tmp_path / "toy.rddl").write_text(
        DOMAIN
        + INSTANCE_2018
        + "instance broken { domain = nowhere; horizon = 1; discount = 1.0; }\n"
    )
    res = CliRunner().invoke(main, ["check", "--json", str(tmp_path)])
    assert res.exit_code == 1
    data = json.loads(res.output)
    assert (data["checked"], data["ok"], data["failed"]) == (2, 1, 1)
    broken = next(r for r in data["results"] if r["name"] == "broken")
    assert broken["errors"][0]["kind"] == "unknown-domain"
    # the broken instance starts on the line after the domain and toy_1
    assert broken["errors"][0]["line"] == len((DOMAIN + INSTANCE_2018).splitlines()) + 1


def test_check_missing_path_is_a_usage_error(tmp_path: Path) -> None:
    res = CliRunner().invoke(main, ["check", str(tmp_path / "nope.rddl")])
    assert res.exit_code == 2
    assert "does not exist" in res.output


def test_fmt_round_trips(tmp_path: Path) -> None:
    from ippc.rddl import parse

    src = tmp_path / "toy.rddl"
    src.write_text(DOMAIN + INSTANCE_2018)
    res = CliRunner().invoke(main, ["fmt", str(src)])
    assert res.exit_code == 0, res.output
    a, b = parse(src.read_text()), parse(res.output)
    assert (a.domains, a.instances) == (b.domains, b.instances)


def test_fmt_syntax_error_is_clear(tmp_path: Path) -> None:
    src = tmp_path / "bad.rddl"
    src.write_text("domain d { types { t : object } }\n")
    res = CliRunner().invoke(main, ["fmt", str(src)])
    assert res.exit_code == 1
    assert f"{src}:1:31: syntax: unexpected '}}'; expected ';'" in res.output
