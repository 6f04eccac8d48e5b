"""IPPC scores, as the competitions computed them.

The normalisation is rddlsim's evaluation code (``src/rddl/evaluate`` of
github.com/ssanner/rddlsim: ``MinMaxEval.java`` makes the per-instance constants,
``FinalEval.java`` the scores; the IPPC 2014 page, ssanner.github.io/IPPC_2014, links it
as the competition's "Evaluation code"):

* the rounds of a planner on an instance: the last N of them (N = the rounds a session
  plays, rddlsim's ``--num-trials``, 30 in every IPPC), chosen as the rule set says;
* ``min`` of an instance: the best average of the baselines (noop and random;
  ``MinMaxEval.BASELINE_POLICIES``, "Updating normalized score to use lower bound of
  max(random,noop)", rddlsim commit 29803f0, 2011-04-10), each over its chosen rounds;
* ``max``: the best average of any planner, baselines included, over its chosen rounds;
* a planner with fewer than N chosen rounds is padded up to N with ``min``
  (``FinalEval``: "Use min reward if not enough trials"); a planner that never played
  the instance gets 0;
* its score is ``(max(avg, min) - min) / (max - min)`` over the padded rounds, in [0, 1];
  where ``max == min`` rddlsim divides by 1e10, which makes the score 0 (every padded
  average is then ``min`` or less);
* per-domain and overall: the mean of the instance scores with a 95% interval of
  1.96 standard errors (``Statistics.StdError95``; rddlsim's "Avg of
  min(0,avg-norm-score-instance)" tables). The overall mean is over instances, as
  rddlsim's, not over domain means.

What the three rule sets change (`RULES`):

``ippc2011``
    rddlsim's evaluation code as it was for IPPC 2011 (commit 9cdff30, 2011-06-26;
    README: ``FinalEval --num-trials 30``): the last N round-ends of the planner on the
    instance, whatever they were, and no time limit. (2011's protocol had no practice
    rounds: every round-end in a log counted.)
``ippc2014``
    as 2011 plus the per-instance time limit (the IPPC 2014 page: "We change from a
    per-trial time limit to a per-instance time limit"; rddlsim commit 61e6eae,
    2014-06-03, README: ``FinalEval --time-limit 1080000 --num-trials 30``): the rounds
    are taken from the last one backwards while their summed time (rddlsim 2014's
    round-end ``time-used``; here the round's wall time) stays within the session's
    budget (1,080,000 ms unless the session said otherwise); earlier rounds are dropped
    and padded with ``min``.
``ippc2018``
    the 2018 server's rules (Thomas Keller's IPC 2018 changes to rddlsim: rounds asked
    for with ``execute-policy`` no are practice rounds that do not count, commit 13beeb3,
    2017-12-18, PROTOCOL.txt "Since IPC 2018"; the session clock runs from the
    connection and the server itself ends the session at its budget, commit 74b9fc2,
    2018-03-09, which also drops ``time-used``): only counted rounds score, with no time
    filter on the evaluation side; the normalisation is unchanged (rddlsim's evaluation
    code has not changed since 2014). The 2018 competition page
    (ipc2018-probabilistic.bitbucket.io) as stored for this project shows only its
    overview, not its scoring text: this rule set follows the 2018 server, not a
    published 2018 scoring rule.

One deliberate difference from rddlsim: ``MinMaxEval`` writes ``min`` and ``max`` to its
file with two decimals and ``FinalEval`` reads them back; here they keep full precision
(so a score never exceeds 1 by a rounding).
"""

from __future__ import annotations

import logging
import math
import statistics
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from .results import RoundRecord

__all__ = [
    "BASELINE_NAMES",
    "RULES",
    "InstanceScore",
    "RuleSet",
    "ScoreError",
    "ScoreTable",
    "ci95",
    "score",
]

log = logging.getLogger(__name__)

#: Planner names that are baselines: ours, and the client names of rddlsim's own
#: baseline policies (``MinMaxEval.BASELINE_POLICIES``), compared without case.
BASELINE_NAMES = frozenset({"noop", "random", "nooppolicy", "randompolicy", "randomboolpolicy"})

#: rddlsim's default session budget and FinalEval's default time limit, in ms.
DEFAULT_TIME_ALLOWED_MS = 1_080_000.0
#: rddlsim's FinalEval.NUM_EXPECTED_TRIALS default.
DEFAULT_ROUNDS = 30


class ScoreError(ValueError):
    """Nothing can be scored (no rounds, or no baseline on any instance)."""


@dataclass(frozen=True)
class RuleSet:
    """How the rounds of a planner on an instance are chosen (see the module doc)."""

    name: str
    counted_only: bool  # drop practice rounds (2018)
    time_limit: bool  # keep the last rounds within the session's budget (2014)
    source: str  # where the rule comes from


RULES: dict[str, RuleSet] = {
    "ippc2011": RuleSet(
        "ippc2011",
        counted_only=False,
        time_limit=False,
        source="rddlsim src/rddl/evaluate (commit 9cdff30, 2011-06-26): FinalEval --num-trials 30",
    ),
    "ippc2014": RuleSet(
        "ippc2014",
        counted_only=False,
        time_limit=True,
        source="rddlsim src/rddl/evaluate (commit 61e6eae, 2014-06-03): FinalEval --time-limit "
        "1080000 --num-trials 30; ssanner.github.io/IPPC_2014: per-instance time limit",
    ),
    "ippc2018": RuleSet(
        "ippc2018",
        counted_only=True,
        time_limit=False,
        source="rddlsim IPC 2018 server (commits 13beeb3, 74b9fc2): practice rounds do not "
        "count, the server enforces the budget; normalisation as rddlsim's FinalEval",
    ),
}


def ci95(values: list[float]) -> float | None:
    """1.96 standard errors of the mean (rddlsim's StdError95); None for fewer than 2."""
    if len(values) < 2:
        return None
    return 1.96 * statistics.stdev(values) / math.sqrt(len(values))


@dataclass(frozen=True)
class InstanceScore:
    """One planner on one instance."""

    planner: str
    instance: str
    domain: str
    rounds: int  # rounds chosen by the rules (before padding)
    mean: float | None  # their average reward (None: none)
    score: float


@dataclass
class ScoreTable:
    """Scores per instance, per domain and overall, under one rule set."""

    rules: str
    expected_rounds: int | None
    instances: list[InstanceScore] = field(default_factory=list)
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)  # instance -> (min, max)
    skipped: dict[str, str] = field(default_factory=dict)  # instance -> why it has no score

    def planners(self) -> list[str]:
        seen: dict[str, None] = {}
        for s in self.instances:
            seen.setdefault(s.planner, None)
        return list(seen)

    def domains(self) -> list[str]:
        seen: dict[str, None] = {}
        for s in self.instances:
            seen.setdefault(s.domain, None)
        return list(seen)

    def overall(self) -> list[tuple[str, float, float | None, int]]:
        """(planner, mean score, ci95, instances) for every planner, best first."""
        by: dict[str, list[float]] = defaultdict(list)
        for s in self.instances:
            by[s.planner].append(s.score)
        rows = [(p, statistics.fmean(v), ci95(v), len(v)) for p, v in by.items()]
        return sorted(rows, key=lambda r: (-r[1], r[0]))

    def per_domain(self) -> list[tuple[str, str, float, float | None, int]]:
        """(domain, planner, mean score, ci95, instances)."""
        by: dict[tuple[str, str], list[float]] = defaultdict(list)
        for s in self.instances:
            by[(s.domain, s.planner)].append(s.score)
        return [(d, p, statistics.fmean(v), ci95(v), len(v)) for (d, p), v in by.items()]

    def as_json(self) -> dict[str, Any]:
        """``{"rules", "instances": [...], "planners": [...], "domains": [...]}``."""
        return {
            "rules": self.rules,
            "instances": [
                {
                    "instance": s.instance,
                    "domain": s.domain,
                    "planner": s.planner,
                    "rounds": s.rounds,
                    "mean": s.mean,
                    "score": s.score,
                }
                for s in self.instances
            ],
            "planners": [
                {"planner": p, "score": m, "ci95": c, "instances": n}
                for p, m, c, n in self.overall()
            ],
            "domains": [
                {"domain": d, "planner": p, "score": m, "ci95": c, "instances": n}
                for d, p, m, c, n in self.per_domain()
            ],
            "bounds": {i: {"min": lo, "max": hi} for i, (lo, hi) in self.bounds.items()},
            "skipped": self.skipped,
        }


def _choose(rounds: list[RoundRecord], rules: RuleSet, n: int) -> list[float]:
    """The rewards the rules keep, from the planner's rounds on one instance in play order."""
    if rules.counted_only:
        rounds = [r for r in rounds if r.counted]
    window = rounds[-n:] if n > 0 else []
    if not rules.time_limit:
        return [r.reward for r in window]
    kept: list[float] = []
    spent = 0.0
    for r in reversed(window):  # FinalEval walks back from the last round
        limit = r.time_allowed_ms or DEFAULT_TIME_ALLOWED_MS
        t = r.time_ms or 0.0
        if spent + t > limit:
            break
        kept.append(r.reward)
        spent += t
    return kept


def score(
    records: Iterable[RoundRecord],
    rules: str = "ippc2014",
    *,
    expected_rounds: int | None = None,
    expected: Iterable[tuple[str, str, str]] = (),
) -> ScoreTable:
    """Score every planner on every instance under `rules` (a key of `RULES`).

    ``expected_rounds`` is N (default: the rounds the instance's sessions were to play,
    else 30). ``expected`` lists (planner, instance, domain) that should have played
    (jobs not played yet). Every planner gets a score on every instance: 0 where it has no
    round, as in FinalEval. An instance without a baseline round cannot be
    normalised: it is left out (rddlsim's MinMaxEval stops there), and
    listed in ``skipped`` (the CLI prints it).
    """
    try:
        rule = RULES[rules]
    except KeyError:
        raise ScoreError(f"unknown rules {rules!r} (known: {', '.join(RULES)})") from None
    expected = list(expected)
    by: dict[tuple[str, str], list[RoundRecord]] = defaultdict(list)
    domains: dict[str, str] = {}
    order: dict[str, None] = {}
    planners: dict[str, None] = {}
    for r in records:
        by[(r.instance, r.planner)].append(r)
        domains.setdefault(r.instance, r.domain)
        order.setdefault(r.instance, None)
        planners.setdefault(r.planner, None)
    for planner, instance, domain in expected:
        domains.setdefault(instance, domain)
        order.setdefault(instance, None)
        planners.setdefault(planner, None)
    if not by:
        raise ScoreError("no rounds to score")
    table = ScoreTable(rules=rule.name, expected_rounds=expected_rounds)
    for instance in order:
        sessions_rounds = [
            r.num_rounds for (i, _), rs in by.items() if i == instance for r in rs if r.num_rounds
        ]
        n = expected_rounds or (max(sessions_rounds) if sessions_rounds else DEFAULT_ROUNDS)
        chosen = {p: _choose(rs, rule, n) for (i, p), rs in by.items() if i == instance}
        means = {p: statistics.fmean(v) for p, v in chosen.items() if v}
        baseline = [m for p, m in means.items() if p.lower() in BASELINE_NAMES]
        if not baseline:
            why = (
                "no baseline (noop or random) round to normalise with"
                if means
                else "no round played yet"
            )
            log.info("instance %s: %s; not scored", instance, why)
            table.skipped[instance] = why
            continue
        lo = max(baseline)
        hi = max(means.values())
        table.bounds[instance] = (lo, hi)
        for planner in planners:
            # every planner gets a score on every instance, 0 where it never played
            # (FinalEval scores a client missing an instance with the min's own rounds)
            kept = chosen.get(planner, [])
            padded = kept + [lo] * max(0, n - len(kept))
            avg = statistics.fmean(padded) if padded else lo
            value = 0.0 if hi == lo else (max(avg, lo) - lo) / (hi - lo)
            table.instances.append(
                InstanceScore(
                    planner, instance, domains[instance], len(kept), means.get(planner), value
                )
            )
    if not table.instances:
        raise ScoreError(
            "no instance could be scored: "
            + "; ".join(f"{i}: {w}" for i, w in table.skipped.items())
        )
    return table
