"""IPPC scoring on hand-computed fixtures, and what each rule set changes."""

from __future__ import annotations

import math

import pytest
from ippc.batch.results import RoundRecord
from ippc.batch.scoring import RULES, ScoreError, ci95, score


def rounds(
    planner: str,
    instance: str,
    rewards: list[float],
    *,
    counted: list[bool] | None = None,
    times: list[float] | None = None,
    allowed: float | None = None,
    n: int | None = None,
) -> list[RoundRecord]:
    return [
        RoundRecord(
            planner,
            instance,
            instance.split("__")[0],
            r,
            True if counted is None else counted[i],
            None if times is None else times[i],
            allowed,
            n,
        )
        for i, r in enumerate(rewards)
    ]


def by(table, planner: str, instance: str):
    (found,) = [s for s in table.instances if s.planner == planner and s.instance == instance]
    return found


# a__1: random is the better baseline (min 2); p and r tie for the best (max 5); q is
# below both baselines.
A = (
    rounds("noop", "a__1", [0, 0, 0])
    + rounds("random", "a__1", [1, 2, 3])
    + rounds("p", "a__1", [4, 5, 6])
    + rounds("q", "a__1", [1, 1, 1])
    + rounds("r", "a__1", [5, 5, 5])
)
# b__1: everybody gets 1: max equals min.
B = (
    rounds("noop", "b__1", [1, 1, 1])
    + rounds("random", "b__1", [1, 1, 1])
    + rounds("p", "b__1", [1, 1, 1])
)
# c__1: p played 2 of 3 rounds (avg 6 sets max); its padded average is (6+6+2)/3.
C = (
    rounds("noop", "c__1", [0, 0, 0])
    + rounds("random", "c__1", [2, 2, 2])
    + rounds("p", "c__1", [6, 6])
    + rounds("q", "c__1", [3, 3, 3])
    + rounds("r", "c__1", [2, 2, 2])
)


@pytest.mark.parametrize("rules", sorted(RULES))
def test_hand_computed_instance_scores(rules: str) -> None:
    table = score(A + B + C, rules, expected_rounds=3)
    assert table.bounds == {"a__1": (2.0, 5.0), "b__1": (1.0, 1.0), "c__1": (2.0, 6.0)}
    assert by(table, "p", "a__1").score == pytest.approx(1.0)
    assert by(table, "r", "a__1").score == pytest.approx(1.0)  # a tie for the best: both 1
    assert by(table, "q", "a__1").score == 0.0  # below the baselines: 0, not negative
    assert by(table, "q", "a__1").mean == pytest.approx(1.0)
    assert by(table, "random", "a__1").score == 0.0
    assert by(table, "noop", "a__1").score == 0.0
    for planner in ("noop", "random", "p"):
        assert by(table, planner, "b__1").score == 0.0  # max == min
    # q and r never played b__1: 0 with no rounds
    assert by(table, "q", "b__1").rounds == 0 and by(table, "q", "b__1").mean is None
    assert by(table, "q", "b__1").score == 0.0
    # missing rounds are padded with min: (6 + 6 + 2) / 3 = 14/3 -> (14/3 - 2) / 4 = 2/3
    c = by(table, "p", "c__1")
    assert (c.rounds, c.mean) == (2, 6.0)
    assert c.score == pytest.approx((14 / 3 - 2) / 4)
    assert by(table, "q", "c__1").score == pytest.approx(0.25)


def test_overall_and_domain_means_with_ci95() -> None:
    table = score(A + B + C, "ippc2011", expected_rounds=3)
    overall = {p: (m, c, n) for p, m, c, n in table.overall()}
    p_scores = [1.0, 0.0, (14 / 3 - 2) / 4]
    mean = sum(p_scores) / 3
    sd = math.sqrt(sum((x - mean) ** 2 for x in p_scores) / 2)
    assert overall["p"][0] == pytest.approx(mean)
    assert overall["p"][1] == pytest.approx(1.96 * sd / math.sqrt(3))
    assert overall["p"][2] == 3
    assert table.overall()[0][0] == "p"  # best first
    domains = {(d, p): (m, c) for d, p, m, c, _ in table.per_domain()}
    assert domains[("a", "r")] == (pytest.approx(1.0), None)  # one instance: no interval
    assert ci95([1.0]) is None


def test_json_shape() -> None:
    data = score(A, "ippc2014", expected_rounds=3).as_json()
    assert data["rules"] == "ippc2014"
    assert {"instance", "planner", "rounds", "mean", "score"} <= set(data["instances"][0])
    assert {"planner", "score", "ci95"} <= set(data["planners"][0])
    assert [p["planner"] for p in data["planners"]][:2] in (["p", "r"], ["r", "p"])


def test_last_n_rounds_only() -> None:
    recs = (
        rounds("noop", "d__1", [0, 0])
        + rounds("random", "d__1", [0, 0])
        + rounds("p", "d__1", [-8, 4, 4])
    )
    for rules in RULES:
        table = score(recs, rules, expected_rounds=2)
        assert by(table, "p", "d__1").mean == 4.0  # the first of three rounds is dropped


def test_practice_rounds_count_in_2011_and_2014_but_not_2018() -> None:
    recs = (
        rounds("noop", "e__1", [0, 0])
        + rounds("random", "e__1", [0, 0])
        + rounds("p", "e__1", [10, 10, -10], counted=[True, True, False])
    )
    # 2011/2014 read every round-end, as rddlsim's LogReader does: the last two are
    # [10, -10], average 0 = min = max
    for rules in ("ippc2011", "ippc2014"):
        p = by(score(recs, rules, expected_rounds=2), "p", "e__1")
        assert (p.rounds, p.mean, p.score) == (2, 0.0, 0.0)
    p = by(score(recs, "ippc2018", expected_rounds=2), "p", "e__1")
    assert (p.rounds, p.mean, p.score) == (2, 10.0, 1.0)


def test_2014_time_limit_keeps_the_last_rounds_within_the_budget() -> None:
    recs = (
        rounds("noop", "f__1", [0, 0, 0], times=[1, 1, 1], allowed=1000)
        + rounds("random", "f__1", [0, 0, 0], times=[1, 1, 1], allowed=1000)
        + rounds("p", "f__1", [9, 9, 9], times=[100, 500, 600], allowed=1000)
    )
    # backwards: 600 ms fits, 600 + 500 > 1000: one round kept, two padded with min 0
    p14 = by(score(recs, "ippc2014", expected_rounds=3), "p", "f__1")
    assert (p14.rounds, p14.mean) == (1, 9.0)
    assert p14.score == pytest.approx(1 / 3)
    for rules in ("ippc2011", "ippc2018"):
        p = by(score(recs, rules, expected_rounds=3), "p", "f__1")
        assert (p.rounds, p.score) == (3, 1.0)


def test_expected_rounds_default_to_the_sessions() -> None:
    recs = rounds("noop", "g__1", [0, 0, 0, 0], n=4) + rounds("random", "g__1", [0] * 4, n=4)
    recs += rounds("p", "g__1", [8, 8], n=4)
    assert by(score(recs, "ippc2011"), "p", "g__1").score == pytest.approx(0.5)  # (8+8+0+0)/4 / 8


def test_instance_without_baseline_is_skipped_and_planners_never_seen_score_zero() -> None:
    recs = rounds("p", "h__1", [1, 2]) + A
    table = score(recs, "ippc2011", expected_rounds=3, expected=[("late", "a__1", "a")])
    assert "h__1" in table.skipped and "h__1" not in table.bounds
    assert by(table, "late", "a__1").score == 0.0
    with pytest.raises(ScoreError, match="no instance could be scored"):
        score(rounds("p", "h__1", [1]), "ippc2011")
    with pytest.raises(ScoreError, match="unknown rules"):
        score(A, "ippc1999")
    with pytest.raises(ScoreError, match="no rounds"):
        score([], "ippc2011")


def test_rddlsim_baseline_names_are_baselines() -> None:
    recs = rounds("NoopPolicy", "i__1", [0, 0]) + rounds("RandomBoolPolicy", "i__1", [3, 3])
    recs += rounds("x", "i__1", [6, 6])
    table = score(recs, "ippc2011", expected_rounds=2)
    assert table.bounds["i__1"] == (3.0, 6.0)
    assert by(table, "x", "i__1").score == 1.0
