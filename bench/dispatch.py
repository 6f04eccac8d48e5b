"""Simulated runs per second of rddl-dispatch, against rddl-server in the same run.

Workload: the courier domain of the robot side's tests
(tests/data/dispatch/courier_one.rddl, a goal domain, horizon 12), one
simulated run per seed: `ippc.dispatch.run.simulate` (knowledge base,
simulated world, sensing, dispatcher, the planner over loopback TCP),
which is what `rddl-dispatch --simulate` and the print-fetching experiments
run. The reference is the same planner playing the same instance against
rddl-server's session code in the same process (`server.app.serve` plus
`client.run_session`, one round per session, no knowledge base, no world):
what a turn costs before the robot side adds anything. Both take turns
within each pass; figures are medians of `--repeat` passes.

    python bench/dispatch.py                   # random and exact, 20 runs a pass
    python bench/dispatch.py --planner noop --runs 50
"""

from __future__ import annotations

import argparse
import logging
import statistics
import time
from pathlib import Path

import trio

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "tests" / "data" / "dispatch"
DOMAIN = DATA / "courier_domain.rddl"
INSTANCE = DATA / "courier_one.rddl"


def dispatch_pass(planner: str, runs: int) -> tuple[float, int]:
    from ippc.dispatch.run import PlannerSpec, simulate

    turns = 0
    start = time.perf_counter()
    for seed in range(runs):
        turns += simulate(DOMAIN, INSTANCE, seed=seed, planner=PlannerSpec(planner), rounds=1).turns
    return time.perf_counter() - start, turns


def server_pass(planner: str, runs: int) -> tuple[float, int]:
    from ippc.client.session import ClientConfig, run_session
    from ippc.planners.base import Planner, make_planner
    from ippc.server.app import serve
    from ippc.server.config import ServerConfig
    from ippc.server.registry import Registry

    if not isinstance(make_planner(planner, {}), Planner):
        # an external planner (PROST) connects by itself: not a client-side planner
        raise SystemExit(f"--planner {planner}: the server pass needs a built-in planner")

    async def one(seed: int) -> int:
        agent = make_planner(planner, {})
        assert isinstance(agent, Planner)
        registry = Registry.load(DOMAIN, INSTANCE)
        config = ServerConfig(port=0, rounds=1, seed=seed, timeout=0, individual_session=True)
        async with trio.open_nursery() as nursery:
            port = await nursery.start(serve, config, registry)
            result = await run_session(
                ClientConfig(port=port, instance="courier_one", seed=seed),
                agent,
                planner,
            )
        return sum(r.turns for r in result.rounds)

    turns = 0
    start = time.perf_counter()
    for seed in range(runs):
        turns += trio.run(one, seed)
    return time.perf_counter() - start, turns


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--planner", nargs="+", default=["random", "exact"])
    ap.add_argument("--runs", type=int, default=20, help="runs (sessions) per pass")
    ap.add_argument("--repeat", type=int, default=3, help="passes (median)")
    args = ap.parse_args()
    logging.disable(logging.WARNING)
    print(f"workload: courier_one (horizon 12), {args.runs} runs a pass, median of {args.repeat}")
    print(f"{'planner':<8} {'what':<13} {'runs/s':>8} {'turns/s':>8} {'turns/run':>9}  ratio")
    for planner in args.planner:
        rows: dict[str, list[tuple[float, int]]] = {"rddl-dispatch": [], "rddl-server": []}
        for _ in range(args.repeat):
            rows["rddl-dispatch"].append(dispatch_pass(planner, args.runs))
            rows["rddl-server"].append(server_pass(planner, args.runs))
        rates = {}
        for what, runs in rows.items():
            seconds = statistics.median(s for s, _ in runs)
            turns = statistics.median(t for _, t in runs)
            rates[what] = args.runs / seconds
            print(
                f"{planner:<8} {what:<13} {args.runs / seconds:>8.1f} {turns / seconds:>8.0f} "
                f"{turns / args.runs:>9.1f}  "
                + (
                    ""
                    if what == "rddl-dispatch"
                    else f"rddl-dispatch at {rates['rddl-dispatch'] / rates[what]:.2f}x its runs/s"
                )
            )
    print("(a dispatcher run stops at the goal; a rddl-server session plays to the horizon)")


if __name__ == "__main__":
    main()
