"""Quality of ippc's planners on IPPC instances, through our server and client.

What it measures
    For each instance (instance 1 of SysAdmin, Elevators, GameOfLife,
    CrossingTraffic and Navigation of IPPC 2011 and AcademicAdvising of
    IPPC 2014, MDP versions, from the installed ``rddlrepository`` package)
    and each planner (noop, random, replan, mcts), one session of
    ``--rounds`` rounds played by ``ippc.client.run_session`` against
    ``ippc.server.serve`` over 127.0.0.1, both in this process (one trio
    run; the server is idle while the planner thinks). The server's session
    budget is ``--seconds`` per step of every round (rounds x horizon x
    seconds), as IPPC's "1 s per step"; the planners get the client's
    default deadline (the remaining budget spread over the remaining
    steps), unless ``--mcts-option time_per_step=...`` says otherwise.

    Each cell is the mean round reward and the half-width of its 95%
    confidence interval (Student's t over the rounds). ``mcts steps/s`` is
    the simulated state transitions per second of mcts's search over the
    session. For SysAdmin, Elevators and GameOfLife the issue's PROST 2014
    reference (``[PROST -s 1 -se [IPC2014]]``, 1 s per step, 5 rounds) and
    IPPC floor (the better of noop and random) are printed with the fraction
    of the way mcts went from the floor to PROST (goal: >= 0.9). For the
    others the floor is the better of this run's noop and random means
    (goal: mcts above it).

    replan is shown as 'n/a' when ``ippc.planners.replan`` is missing or
    fails on the instance (the error is printed below the table).

    Exact values (``ippc.planners.exact``): where an instance is small
    enough to enumerate (every one here but AcademicAdvising), value
    iteration gives the optimal expected round reward, and every decision
    each planner makes in the run is priced by its *regret*: the expected
    return lost by that action against the best one, in that state with
    those steps left. A round's regrets add up to an unbiased estimate of
    how far the planner's expected round reward lies below the optimum,
    with far less noise than the round rewards (the luck of the world's
    draws does not enter it). A second table prints them, with the optimum, the fraction of the
    way from the floor to PROST that ``optimum - regret`` reaches, and the
    exact expected round reward of noop. ``--no-exact`` skips it.

Usage
    python bench/planners.py                       # everything: about 20 minutes (mcts uses its whole budget)
    python bench/planners.py --rounds 3 --domains SysAdmin,GameOfLife --planners mcts
    python bench/planners.py --mcts-option rollout_depth=15 --json results.json
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import statistics
import sys
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import trio
from ippc.client.session import ClientConfig, run_session
from ippc.planners import Observation, Planner, PlannerError, SessionInfo, make_planner
from ippc.planners.exact import ExactUnsupported, Solution, solve
from ippc.rddl.wire import WireCodec
from ippc.server.app import serve
from ippc.server.config import ServerConfig
from ippc.server.registry import Registry
from ippc.server.session import Services

DOMAINS = {
    "SysAdmin_MDP_ippc2011": "IPPC2011/SysAdmin/MDP",
    "Elevators_MDP_ippc2011": "IPPC2011/Elevators/MDP",
    "GameOfLife_MDP_ippc2011": "IPPC2011/GameOfLife/MDP",
    "CrossingTraffic_MDP_ippc2011": "IPPC2011/CrossingTraffic/MDP",
    "Navigation_MDP_ippc2011": "IPPC2011/Navigation/MDP",
    "AcademicAdvising_MDP_ippc2014": "IPPC2014/AcademicAdvising/MDP",
}
PLANNERS = ("noop", "random", "replan", "mcts")

# The reference figures for instance 1: PROST 2014 and the IPPC floor
# (the better of noop and random).
PROST_2014 = {
    "SysAdmin_MDP_ippc2011": 323.95,
    "Elevators_MDP_ippc2011": -47.80,
    "GameOfLife_MDP_ippc2011": 209.60,
}
IPPC_FLOOR = {
    "SysAdmin_MDP_ippc2011": 210.18,
    "Elevators_MDP_ippc2011": -65.2,
    "GameOfLife_MDP_ippc2011": 70.53,
}
GOAL_FRACTION = 0.9

# Student's t, two-sided 95%, by degrees of freedom
_T95 = [
    12.706,
    4.303,
    3.182,
    2.776,
    2.571,
    2.447,
    2.365,
    2.306,
    2.262,
    2.228,
    2.201,
    2.179,
    2.160,
    2.145,
    2.131,
    2.120,
    2.110,
    2.101,
    2.093,
    2.086,
    2.080,
    2.074,
    2.069,
    2.064,
    2.060,
    2.056,
    2.052,
    2.048,
    2.045,
    2.042,
]


def t95(df: int) -> float:
    return _T95[df - 1] if 1 <= df <= len(_T95) else 1.96


@dataclass
class Cell:
    planner: str
    rewards: list[float] = field(default_factory=list)
    seconds: float = 0.0
    steps_per_second: float | None = None
    error: str | None = None
    regrets: list[float] = field(default_factory=list)  # per round, with exact values

    @property
    def mean(self) -> float:
        return statistics.fmean(self.rewards)

    @property
    def ci(self) -> float:
        return mean_ci(self.rewards)[1] if self.rewards else float("nan")

    def text(self) -> str:
        if self.error is not None or not self.rewards:
            return "n/a"
        return f"{self.mean:8.2f} ± {self.ci:6.2f}"


def mean_ci(values: list[float]) -> tuple[float, float]:
    n = len(values)
    mean = statistics.fmean(values)
    return mean, (t95(n - 1) * statistics.stdev(values) / math.sqrt(n) if n > 1 else float("nan"))


class Priced(Planner):
    """Plays as `inner` does and prices each of its decisions with the
    exact values of `solution` (the regret per round adds up in `regrets`)."""

    name = "priced"

    def __init__(self, inner: Planner, solution: Solution):
        super().__init__()
        self.inner = inner
        self.solution = solution
        self.regrets: list[float] = []
        self._codec: WireCodec | None = None

    @property
    def stats(self) -> Any:
        return getattr(self.inner, "stats", None)

    def start_session(self, session: SessionInfo) -> None:
        super().start_session(session)
        self._codec = WireCodec(session.simulator)
        self.inner.start_session(session)

    def start_round(self, round_num: int) -> None:
        self.regrets.append(0.0)
        self.inner.start_round(round_num)

    def act(self, obs: Observation) -> Any:
        chosen = self.inner.act(obs)
        assert self._codec is not None and obs.state is not None
        arrays = self._codec.actions_from(chosen).arrays
        self.regrets[-1] += self.solution.regret(obs.steps_left, obs.state, arrays)
        return chosen

    def end_round(self, reward: float) -> None:
        self.inner.end_round(reward)

    def end_session(self, total_reward: float) -> None:
        self.inner.end_session(total_reward)


def corpus_root() -> Path:
    try:
        import rddlrepository
    except ImportError:
        sys.exit("bench/planners.py needs the rddlrepository package (pip install rddlrepository)")
    return Path(rddlrepository.__file__).parent / "archive" / "competitions"


async def play(
    registry: Registry, instance: str, planner: Planner, name: str, rounds: int, budget: float
) -> Cell:
    """One session of `rounds` rounds on a fresh in-process server."""
    config = ServerConfig(port=0, rounds=rounds, timeout=budget, seed=0)
    services = Services(config, registry)
    cell = Cell(name)
    t0 = time.monotonic()
    async with trio.open_nursery() as nursery:
        port = await nursery.start(partial(serve, config, registry, services=services))
        client = ClientConfig(
            port=port, instance=instance, client_name=f"bench-{name}", timeout=budget + 120.0
        )
        result = await run_session(client, planner, name)
        nursery.cancel_scope.cancel()
    cell.rewards = [r.reward for r in result.rounds if not r.training]
    if isinstance(planner, Priced):
        cell.regrets = planner.regrets[-len(cell.rewards) :] if cell.rewards else []
    cell.seconds = time.monotonic() - t0
    stats = getattr(planner, "stats", None)
    if stats is not None and hasattr(stats, "steps_per_second"):
        cell.steps_per_second = float(stats.steps_per_second)
    return cell


def run_cell(
    registry: Registry,
    instance: str,
    name: str,
    options: dict[str, str],
    rounds: int,
    budget: float,
    solution: Solution | None = None,
) -> Cell:
    try:
        planner = make_planner(name, options)
    except PlannerError as err:
        return Cell(name, error=str(err))
    except Exception as err:  # a planner module that does not import
        return Cell(name, error=f"{type(err).__name__}: {err}")
    if not isinstance(planner, Planner):
        return Cell(name, error="an external planner (not driven turn by turn)")
    if solution is not None:
        planner = Priced(planner, solution)
    try:
        return trio.run(play, registry, instance, planner, name, rounds, budget)
    except Exception as err:
        return Cell(name, error=f"{type(err).__name__}: {err}")


def fraction(domain: str, mean: float) -> float | None:
    if domain not in PROST_2014:
        return None
    floor, prost = IPPC_FLOOR[domain], PROST_2014[domain]
    return (mean - floor) / (prost - floor)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5, help="rounds per session (default 5)")
    ap.add_argument(
        "--seconds",
        type=float,
        default=1.0,
        help="seconds per step of the session budget (default 1)",
    )
    ap.add_argument(
        "--domains", default="", help="comma-separated parts of domain names (default: all six)"
    )
    ap.add_argument(
        "--planners",
        default=",".join(PLANNERS),
        help="comma-separated planners (default: noop,random,replan,mcts)",
    )
    ap.add_argument("--instance", default="1", help="instance number (default 1)")
    ap.add_argument(
        "--mcts-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="an option for mcts (repeatable)",
    )
    ap.add_argument(
        "--replan-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="an option for replan (repeatable)",
    )
    ap.add_argument(
        "--no-exact",
        action="store_true",
        help="skip the exact values and the regrets (value iteration where an instance is small)",
    )
    ap.add_argument("--json", type=Path, help="also write the results here")
    ap.add_argument("-v", "--verbose", action="store_true", help="log the planners' progress")
    args = ap.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="%(asctime)s %(name)s: %(message)s",
    )

    wanted = [d.strip().lower() for d in args.domains.split(",") if d.strip()]
    domains = [d for d in DOMAINS if not wanted or any(w in d.lower() for w in wanted)]
    planners = [p.strip() for p in args.planners.split(",") if p.strip()]
    options = {
        "mcts": dict(o.split("=", 1) for o in args.mcts_option),
        "replan": dict(o.split("=", 1) for o in args.replan_option),
    }
    root = corpus_root()
    started = time.monotonic()
    results: dict[str, dict[str, Cell]] = {}
    exact: dict[str, Solution | str] = {}
    for domain in domains:
        folder = root / DOMAINS[domain]
        registry = Registry.load(folder / "domain.rddl", folder / f"instance{args.instance}.rddl")
        if len(registry) != 1:
            print(
                f"{domain}: cannot serve instance {args.instance}: {registry.broken}",
                file=sys.stderr,
            )
            continue
        instance = registry.names()[0]
        horizon = registry.get(instance).horizon or 40
        budget = args.rounds * horizon * args.seconds
        row = results[domain] = {}
        solution: Solution | None = None
        if not args.no_exact:
            t0 = time.monotonic()
            try:
                solution = solve(registry.get(instance).model)
                exact[domain] = solution
                print(
                    f"# {domain}: exact values of {len(solution.bits)} states in "
                    f"{time.monotonic() - t0:.1f} s; optimum {solution.initial_value:.2f}",
                    file=sys.stderr,
                    flush=True,
                )
            except ExactUnsupported as err:
                exact[domain] = str(err)
        for name in planners:
            cell = run_cell(
                registry, instance, name, options.get(name, {}), args.rounds, budget, solution
            )
            row[name] = cell
            sps = f", {cell.steps_per_second:,.0f} steps/s" if cell.steps_per_second else ""
            status = cell.text() if cell.error is None else f"n/a ({cell.error})"
            print(
                f"# {domain} {name}: {status} in {cell.seconds:.0f} s{sps}",
                file=sys.stderr,
                flush=True,
            )
    print_table(results, planners, args)
    if exact:
        print()
        print_exact(results, planners, exact)
    print(
        f"\n{args.rounds} rounds per cell, {args.seconds:g} s per step, instance {args.instance}; "
        f"run {time.strftime('%Y-%m-%d')}, {time.monotonic() - started:.0f} s in all"
    )
    errors = [(d, c) for d, row in results.items() for c in row.values() if c.error]
    for domain, cell in errors:
        print(f"{cell.planner} on {domain}: {cell.error}")
    if args.json:
        data = {
            d: {
                p: {
                    "rewards": c.rewards,
                    "mean": c.mean if c.rewards else None,
                    "ci95": c.ci if c.rewards else None,
                    "seconds": c.seconds,
                    "steps_per_second": c.steps_per_second,
                    "regrets": c.regrets or None,
                    "error": c.error,
                }
                for p, c in row.items()
            }
            for d, row in results.items()
        }
        args.json.write_text(
            json.dumps(
                {
                    "rounds": args.rounds,
                    "seconds": args.seconds,
                    "results": data,
                    "optimum": {
                        d: e.initial_value if isinstance(e, Solution) else None
                        for d, e in exact.items()
                    },
                },
                indent=2,
            )
        )
    return 0


def run_floor(row: dict[str, Cell]) -> float | None:
    """The better of this run's noop and random means (None without them)."""
    base = [row[p].mean for p in ("noop", "random") if p in row and row[p].rewards]
    return max(base) if base else None


def print_table(results: dict[str, dict[str, Cell]], planners: list[str], args: Any) -> None:
    head = f"{'instance ' + args.instance:<30}" + "".join(f"{p:>20}" for p in planners)
    head += f"{'mcts steps/s':>14}{'floor':>9}{'PROST':>9}{'fraction':>10}  goal"
    print(head)
    print("-" * len(head))
    for domain, row in results.items():
        line = f"{domain:<30}" + "".join(f"{row[p].text():>20}" for p in planners)
        mcts = row.get("mcts")
        sps = mcts.steps_per_second if mcts and mcts.steps_per_second else None
        line += f"{sps:>14,.0f}" if sps else f"{'':>14}"
        if domain in PROST_2014:
            floor: float | None = IPPC_FLOOR[domain]
            prost = f"{PROST_2014[domain]:9.2f}"
        else:
            floor = run_floor(row)
            prost = f"{'-':>9}"
        line += f"{floor:9.2f}" if floor is not None else f"{'-':>9}"
        line += prost
        goal = ""
        if mcts is not None and mcts.rewards:
            frac = fraction(domain, mcts.mean)
            line += f"{frac:10.2f}" if frac is not None else f"{'-':>10}"
            if frac is not None:
                goal = "met" if frac >= GOAL_FRACTION else "not met"
            elif floor is not None:
                goal = "met" if mcts.mean > floor else "not met"
        else:
            line += f"{'-':>10}"
        print(line + "  " + goal)


def print_exact(
    results: dict[str, dict[str, Cell]], planners: list[str], exact: dict[str, Solution | str]
) -> None:
    """The second table: the optimum, noop's exact value, and each planner's
    expected round reward lost to the optimum (mean regret per round)."""
    print(
        "expected round reward lost to the optimum (sum of each round's regrets, mean ± 95% CI); "
        "goal judged on the optimum less mcts's mean regret"
    )
    head = f"{'instance':<30}{'states':>8}{'optimum':>9}{'noop exact':>11}"
    head += "".join(f"{p + ' regret':>22}" for p in planners)
    head += f"{'mcts: opt-regret':>18}{'fraction':>10}  goal"
    print(head)
    print("-" * len(head))
    for domain, row in results.items():
        sol = exact.get(domain)
        if not isinstance(sol, Solution):
            print(f"{domain:<30}  not solved: {sol}")
            continue
        noop = sol.policy_value(np.zeros(len(sol.bits), dtype=np.int64))
        line = f"{domain:<30}{len(sol.bits):>8}{sol.initial_value:9.2f}{noop:11.2f}"
        for p in planners:
            cell = row.get(p)
            if cell is None or not cell.regrets:
                line += f"{'n/a':>22}"
                continue
            m, ci = mean_ci(cell.regrets)
            line += f"{m:12.2f} ± {ci:6.2f}  "
        mcts = row.get("mcts")
        if mcts is not None and mcts.regrets:
            expected = sol.initial_value - statistics.fmean(mcts.regrets)
            line += f"{expected:18.2f}"
            frac = fraction(domain, expected)
            line += f"{frac:10.2f}" if frac is not None else f"{'-':>10}"
            if frac is not None:
                line += "  met" if frac >= GOAL_FRACTION else "  not met"
            else:
                floor = run_floor(row)
                if floor is not None:
                    line += "  met" if expected > floor else "  not met"
        print(line)


if __name__ == "__main__":
    sys.exit(main())
