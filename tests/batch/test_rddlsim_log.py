"""rddlsim's server logs, read as rddlsim's LogReader reads them."""

from __future__ import annotations

from pathlib import Path

import pytest
from ippc.batch import read_rddlsim_log, score
from ippc.batch.rddlsim_log import RddlsimLogError
from ippc.batch.results import RoundRecord

from .conftest import REPO

DATA = REPO / "tests" / "data" / "batch"


def test_a_real_rddlsim_log() -> None:
    # rddlsim's Java server, 30 rounds of RandomConcurrentPolicy on skill_teaching
    # instance 1 (tests/data/README.md)
    rounds = read_rddlsim_log(DATA / "rddlsim-skill-teaching-random.log")
    assert len(rounds) == 30
    assert {(r.planner, r.instance, r.domain) for r in rounds} == {
        ("javaclient", "skill_teaching_inst_mdp__1", "skill_teaching_mdp")
    }
    assert rounds[0].reward == 4.597763
    assert sum(r.reward for r in rounds) == pytest.approx(404.12649890000006)
    assert all(r.time_ms is None for r in rounds)  # rddlsim since 2018 logs no time-used


def test_time_used_and_bad_lines(tmp_path: Path) -> None:
    decl = '<?xml version="1.0" encoding="UTF-8"?>'
    ok = (
        f"{decl}\n<client-info><client-hostname>h</client-hostname></client-info>\n"
        f"{decl}\n<round-end><instance-name>a_inst_mdp__1</instance-name><client-name>NoopPolicy</client-name>"
        "<round-reward>2.5</round-reward><time-used>120</time-used></round-end>\n"
        f"{decl}\n<round-end><instance-name>a_inst_mdp__1</instance-name><round-reward>9</round-reward></round-end>\n"
        f"{decl}\n<round-end><instance-name>a_inst_mdp__1</instance-name><client-name>p</client-name>"
        "<round-reward>4.5</round-reward><time-used>80</time-used></round-end>\n"
    )
    (tmp_path / "ok.log").write_text(ok)
    rounds = read_rddlsim_log(tmp_path / "ok.log")
    assert rounds == [
        RoundRecord("NoopPolicy", "a_inst_mdp__1", "a_mdp", 2.5, True, 120.0),
        RoundRecord("p", "a_inst_mdp__1", "a_mdp", 4.5, True, 80.0),  # no client name: skipped
    ]
    assert score(rounds, "ippc2011", expected_rounds=1).bounds == {"a_inst_mdp__1": (2.5, 4.5)}
    (tmp_path / "bad.log").write_text(ok + f"{decl}\n<round-end><client-name>p</round-end>\n")
    with pytest.raises(RddlsimLogError, match=r"bad\.log:10: not an rddlsim log"):
        read_rddlsim_log(tmp_path / "bad.log")
    (tmp_path / "nonum.log").write_text(
        f"{decl}\n<x/>\n{decl}\n<round-end><client-name>p</client-name><round-reward>x</round-reward></round-end>\n"
    )
    with pytest.raises(
        RddlsimLogError, match=r"nonum\.log:4: round-end without a numeric round-reward"
    ):
        read_rddlsim_log(tmp_path / "nonum.log")
