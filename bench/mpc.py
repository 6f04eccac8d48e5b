"""The model-predictive planner's batched evaluation against the one-state step:
states stepped per second on the IPPC 2023 instances.

    python bench/mpc.py                          # instance 1 of every domain
    python bench/mpc.py --instance 5 --domains RecSim HVAC --seconds 2

For each instance the planner (`mpc`, default options, at 0.1 s a step) is
started as a session starts it, which sizes its batch (samples and horizon)
from the instance; then, for about `--seconds` each, in the same run:

* single: `Simulator.step` on one state, sampled actions (what a planner
  that steps one state at a time gets), states per second;
* batched: `search.evaluate` of a batch of sequences sampled from the plan,
  at the planner's sizes (one simulator call per step for the whole batch,
  actions decoded and checked as the planner does), states per second.

The ratio batched / single is the printed figure (machine-independent as far
as a ratio is); absolute rates depend on the machine and its load.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

DOMAINS = ["HVAC", "MarsRover", "MountainCar", "PowerGen", "RaceCar", "RecSim", "Reservoir", "UAV"]


def measure(domain: str, instance: int, seconds: float) -> dict[str, float]:
    import rddlrepository
    from ippc.planners import SessionInfo
    from ippc.planners.mpc import MPCPlanner
    from ippc.planners.mpc.search import Clock, Plan, evaluate
    from ippc.rddl import load_pair
    from ippc.rddl.simulator import Simulator

    folder = Path(rddlrepository.__file__).parent / "archive/competitions/IPPC2023" / domain
    model = load_pair(folder / "domain.rddl", folder / f"instance{instance}.rddl")
    sim = Simulator(model)
    planner = MPCPlanner(seed="0", time_per_step="0.1")
    planner.start_session(SessionInfo(model.name, model, sim, 1, 1e6, 0))
    n, h = planner.n, max(1, min(planner.h_limit, model.horizon or 1))
    rng = np.random.default_rng(0)
    state = sim.initial_state(1)
    plan = Plan(planner.space, h)

    one = plan.sample(256, rng)
    count, started = 0, time.perf_counter()
    while time.perf_counter() - started < seconds:
        acts = planner.space.actions(one.take(count % 256), 0)
        sim.step(state, acts, rng, check=False)
        count += 1
    single = count / (time.perf_counter() - started)

    stepped, started = 0, time.perf_counter()
    while time.perf_counter() - started < seconds:
        samples = plan.sample(n, rng)
        got = evaluate(
            sim,
            planner.space,
            state,
            samples,
            rng,
            model.discount,
            planner.check,
            Clock(math.inf, 0.0),
        )
        assert got is not None
        stepped += n * got.calls
    batched = stepped / (time.perf_counter() - started)
    return {"samples": n, "horizon": h, "single": single, "batched": batched}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--domains", nargs="+", default=DOMAINS)
    parser.add_argument("--instance", type=int, default=1)
    parser.add_argument("--seconds", type=float, default=1.0, help="per measurement")
    args = parser.parse_args()
    print(f"IPPC 2023 instance {args.instance}; states stepped per second")
    print(
        f"{'domain':<12} {'samples':>7} {'horizon':>7} {'single':>10} {'batched':>11} {'ratio':>7}"
    )
    for domain in args.domains:
        r = measure(domain, args.instance, args.seconds)
        print(
            f"{domain:<12} {r['samples']:>7.0f} {r['horizon']:>7.0f} {r['single']:>10,.0f} "
            f"{r['batched']:>11,.0f} {r['batched'] / r['single']:>6.1f}x"
        )


if __name__ == "__main__":
    main()
