"""Search speed of mcts and of PROST on the same instances at the same time per step.

What it measures
    For each instance (default: instance 1 of SysAdmin, Elevators, CrossingTraffic and
    Navigation of IPPC 2011, MDP versions, from the installed ``rddlrepository``) and each
    time per step (default 0.1 s and 1 s), one session of ``--rounds`` rounds (default 1)
    against ``ippc.server.serve`` on 127.0.0.1 in this process, played by

    - mcts (``time_per_step`` = the budget, seed 1), through ``ippc.client.run_session``;
      its counters (``MCTSPlanner.stats``) give the trials, the decision nodes expanded
      (``leaves``) and the simulated state transitions (``sim_steps``, every row of every
      batched simulator call) per second of its turns;
    - PROST (``$PROST_BIN``, ``[Prost -s 1 -se [IPC2014 -t <budget>]]``, the IPC 2014
      configuration), through ippc's PROST launcher; PROST prints per step "Performed
      trials", "Created search nodes" (decision and chance nodes of its THTS graph) and
      "Search time", which are summed over the steps it searched (a step it decides
      without search, e.g. with one reasonable action, prints none).

    The two "nodes" are not the same unit: a PROST trial creates its decision and chance
    nodes along a whole path of the tree, an mcts trial expands one decision node and
    evaluates it with a batched rollout (whose simulated transitions are in the last
    columns). The comparable figure is trials per second, and the ratio column is PROST's
    trials/s over mcts's, both measured in this run. Without PROST_BIN the PROST rows say
    so and the ratio is left out.

    Beside it, mcts with ``compiled=no`` (the Python step and tree, the fallback where no C
    compiler is found): the "C/Python" column is the compiled engine's trials/s over the
    Python one's, measured in this run (``--no-python`` leaves it out).

    The load average is printed before and after: on a shared machine both planners
    get less than a core, and the figures are only comparable within one run.

Usage
    python bench/planner_speed.py                        # 4 instances x 0.1 s and 1 s, about 5 minutes
    python bench/planner_speed.py --budgets 0.1 --instances SysAdmin_MDP_ippc2011:1
    python bench/planner_speed.py --json speed.json
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import re
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from functools import partial
from pathlib import Path
from typing import Any

import trio
from ippc.client.session import ClientConfig, run_session
from ippc.planners import PlannerError, make_planner
from ippc.planners.mcts import MCTSPlanner
from ippc.planners.prost import PROST_BIN_ENV, ProstPlanner
from ippc.server.app import serve
from ippc.server.config import ServerConfig
from ippc.server.registry import Registry
from ippc.server.session import Services

INSTANCES = (
    "SysAdmin_MDP_ippc2011:1",
    "Elevators_MDP_ippc2011:1",
    "CrossingTraffic_MDP_ippc2011:1",
    "Navigation_MDP_ippc2011:1",
)
BUDGETS = (0.1, 1.0)

_TRIALS_RE = re.compile(r"^\s*Performed trials: (\d+)\s*$", re.M)
_NODES_RE = re.compile(r"^\s*Created search nodes: (\d+)\s*$", re.M)
_TIME_RE = re.compile(r"^\s*Search time: ([0-9.eE+-]+)\s*$", re.M)


@dataclass
class Speed:
    """One planner on one instance at one budget; rates are per second of search."""

    planner: str
    instance: str
    budget: float
    steps: int = 0  # turns searched
    seconds: float = 0.0  # search time summed over them
    trials: int = 0
    nodes: int = 0  # PROST: created search nodes; mcts: decision nodes expanded
    sim_steps: int = 0  # mcts only: simulated state transitions
    error: str | None = None

    def rate(self, count: int) -> float | None:
        return count / self.seconds if self.seconds > 0 else None


def load_instance(spec: str) -> tuple[Registry, str, int]:
    """(registry serving the one instance, its name, its horizon) for NAME:NUMBER."""
    try:
        from rddlrepository import RDDLRepoManager
    except ImportError:
        sys.exit("bench/planner_speed.py needs rddlrepository (pip install 'ippc[batch]')")
    name, _, number = spec.partition(":")
    info = RDDLRepoManager().get_problem(name)
    registry = Registry.load(info.get_domain(), info.get_instance(number or "1"))
    if len(registry) != 1:
        sys.exit(f"{spec}: cannot serve it: {registry.broken}")
    instance = registry.names()[0]
    return registry, instance, registry.get(instance).horizon or 40


async def _session(
    registry: Registry, instance: str, rounds: int, budget: float, play: Any
) -> None:
    config = ServerConfig(port=0, rounds=rounds, timeout=budget, seed=1)
    services = Services(config, registry)
    async with trio.open_nursery() as nursery:
        port = await nursery.start(partial(serve, config, registry, services=services))
        await play(port)
        nursery.cancel_scope.cancel()


def run_mcts(
    registry: Registry,
    instance: str,
    horizon: int,
    budget: float,
    rounds: int,
    compiled: str = "auto",
) -> Speed:
    out = Speed("mcts" if compiled != "no" else "mcts (Python)", instance, budget)
    planner = make_planner(
        "mcts", {"time_per_step": str(budget), "seed": "1", "compiled": compiled}
    )
    assert isinstance(planner, MCTSPlanner)
    session_budget = rounds * horizon * budget * 3 + 60

    async def play(port: int) -> None:
        client = ClientConfig(
            port=port, instance=instance, client_name="mcts", timeout=session_budget + 60
        )
        await run_session(client, planner, "mcts")

    try:
        trio.run(_session, registry, instance, rounds, session_budget, play)
    except Exception as err:
        out.error = f"{type(err).__name__}: {err}"
    s = planner.stats
    out.steps, out.seconds = s.turns, s.seconds
    out.trials, out.nodes, out.sim_steps = s.trials, s.leaves, s.sim_steps
    return out


def parse_prost_steps(text: str) -> tuple[int, float, int, int]:
    """(steps searched, search seconds, trials, created nodes) summed over PROST's
    per-step statistics."""
    trials = [int(x) for x in _TRIALS_RE.findall(text)]
    nodes = [int(x) for x in _NODES_RE.findall(text)]
    times = [float(x) for x in _TIME_RE.findall(text)]
    n = min(len(trials), len(nodes), len(times))
    return n, sum(times[:n]), sum(trials[:n]), sum(nodes[:n])


def run_prost(
    registry: Registry, instance: str, horizon: int, budget: float, rounds: int, binary: str
) -> Speed:
    out = Speed("PROST", instance, budget)
    config = f"[Prost -s 1 -se [IPC2014 -t {budget:g}]]"
    try:
        prost = make_planner("prost", {"binary": binary, "config": config})
    except PlannerError as err:
        out.error = str(err)
        return out
    assert isinstance(prost, ProstPlanner)
    session_budget = rounds * horizon * budget * 3 + 60
    fd, name = tempfile.mkstemp(prefix="planner-speed-prost-", suffix=".log")
    os.close(fd)
    log_path = Path(name)

    async def play(port: int) -> None:
        res = await trio.to_thread.run_sync(
            partial(
                prost.run_session,
                host="127.0.0.1",
                port=port,
                instance=instance,
                timeout=session_budget + 60,
                log_path=log_path,
            )
        )
        if res.error:
            out.error = res.error

    try:
        trio.run(_session, registry, instance, rounds, session_budget, play)
        out.steps, out.seconds, out.trials, out.nodes = parse_prost_steps(log_path.read_text())
    except Exception as err:
        out.error = f"{type(err).__name__}: {err}"
    finally:
        log_path.unlink(missing_ok=True)
    return out


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:,.0f}"


def print_table(rows: list[tuple[Speed, Speed | None, Speed | None]]) -> None:
    head = (
        "| instance | s/step | mcts trials/s | mcts nodes/s | mcts sim steps/s "
        "| mcts (Python) trials/s | C/Python | PROST trials/s | PROST nodes/s "
        "| PROST/mcts trials |"
    )
    print(head)
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for m, py, p in rows:
        mt = m.rate(m.trials)
        yt = py.rate(py.trials) if py is not None and py.error is None else None
        pt = p.rate(p.trials) if p is not None and p.error is None else None
        ratio = f"{pt / mt:.1f}x" if pt and mt else "-"
        c_py = f"{mt / yt:.1f}x" if mt and yt else "-"
        print(
            f"| {m.instance} | {m.budget:g} | {_fmt(mt)} | {_fmt(m.rate(m.nodes))} | "
            f"{_fmt(m.rate(m.sim_steps))} | {_fmt(yt)} | {c_py} | {_fmt(pt)} | "
            f"{_fmt(p.rate(p.nodes) if p is not None and p.error is None else None)} | {ratio} |"
        )
    for row in rows:
        for s in row:
            if s is not None and s.error:
                print(f"{s.planner} on {s.instance} at {s.budget:g} s: {s.error}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--instances", default=",".join(INSTANCES), help="NAME:NUMBER,...")
    ap.add_argument("--budgets", default=",".join(f"{b:g}" for b in BUDGETS), help="s/step,...")
    ap.add_argument("--rounds", type=int, default=1, help="rounds per session (default 1)")
    ap.add_argument("--json", type=Path, help="also write the figures here")
    ap.add_argument("--no-python", action="store_true", help="leave out mcts with compiled=no")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    budgets = [float(b) for b in args.budgets.split(",")]
    binary = os.environ.get(PROST_BIN_ENV, "").strip()
    if not binary:
        print(f"PROST part skipped: set {PROST_BIN_ENV} to PROST's search program to run it")
    load0 = os.getloadavg()
    t0 = time.monotonic()
    rows: list[tuple[Speed, Speed | None, Speed | None]] = []
    for spec in args.instances.split(","):
        registry, instance, horizon = load_instance(spec)
        for budget in budgets:
            m = run_mcts(registry, instance, horizon, budget, args.rounds)
            py = (
                None
                if args.no_python
                else run_mcts(registry, instance, horizon, budget, args.rounds, compiled="no")
            )
            p = (
                run_prost(registry, instance, horizon, budget, args.rounds, binary)
                if binary
                else None
            )
            rows.append((m, py, p))
            print(
                f"# {instance} at {budget:g} s/step: mcts {m.steps} turns, "
                + (f"PROST {p.steps} steps searched" if p is not None else "no PROST"),
                file=sys.stderr,
            )
    load1 = os.getloadavg()
    print(
        f"{args.rounds} round(s) per session; load average {load0[0]:.1f} before, "
        f"{load1[0]:.1f} after, {os.cpu_count()} cores; {time.monotonic() - t0:.0f} s"
    )
    print_table(rows)
    if args.json:
        data = [
            {
                "mcts": asdict(m),
                "mcts_python": asdict(py) if py else None,
                "prost": asdict(p) if p else None,
            }
            for m, py, p in rows
        ]
        args.json.write_text(json.dumps({"load": [load0[0], load1[0]], "rows": data}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
