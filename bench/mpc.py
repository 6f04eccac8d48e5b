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

With `--play`, it plays whole rounds in-process instead (no server, no
clock): the planners named (noop, random, mpc with `--option`s, by default
at fixed `iterations`, so that the figures depend on the seed alone and not
on the machine's speed or load) against the simulator, every action checked
as the server checks it, the same sampled futures for every planner
(common random numbers), and prints each one's mean round reward:

    python bench/mpc.py --play --domains HVAC --instance 3 --rounds 2 \
        --option iterations=3 --option samples=64 --planners noop random mpc
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


def play(
    domain: str, instance: int, planner_name: str, options: dict[str, str], rounds: int, seed: int
) -> tuple[list[float], float]:
    """Rounds of one planner in-process against the simulator: the round
    totals and the seconds taken."""
    import rddlrepository
    from ippc.planners import Observation, SessionInfo, make_planner
    from ippc.rddl import load_pair
    from ippc.rddl.simulator import Simulator
    from ippc.rddl.wire import WireCodec

    folder = Path(rddlrepository.__file__).parent / "archive/competitions/IPPC2023" / domain
    model = load_pair(folder / "domain.rddl", folder / f"instance{instance}.rddl")
    sim = Simulator(model)
    opts = {"seed": str(seed)} if planner_name == "random" else {}
    if planner_name == "mpc":
        opts = {"seed": str(seed), **options}
    planner = make_planner(planner_name, opts)
    started = time.perf_counter()
    planner.start_session(SessionInfo(model.name, model, sim, rounds, 1e9, seed))
    codec = WireCodec(sim)
    horizon = model.horizon or 100
    totals = []
    for r in range(rounds):
        rng = np.random.default_rng([seed, r])  # the same futures for every planner
        planner.start_round(r + 1)
        state, total = sim.initial_state(1), 0.0
        for t in range(horizon):
            obs = Observation(None, state, t + 1, horizon - t, 1e9, 0.0, math.inf)
            decoded = codec.actions_from(planner.act(obs))
            if decoded.illegal or not bool(sim.check_actions(state, decoded.arrays)[0]):
                raise AssertionError(f"{planner_name} sent an illegal action at turn {t + 1}")
            step = sim.step(state, decoded.arrays, rng, check=True)
            total += float(step.reward[0]) * (model.discount**t)
            state = step.next_state
            if bool(step.done[0]):
                break
        totals.append(total)
    return totals, time.perf_counter() - started


def main_play(args: argparse.Namespace) -> None:
    options = dict(o.split("=", 1) for o in args.option)
    if "time_per_step" not in options:
        options.setdefault("iterations", "3")
    print(f"IPPC 2023 instance {args.instance}, {args.rounds} rounds, seed {args.seed}, {options}")
    for domain in args.domains:
        cells = []
        for name in args.planners:
            totals, secs = play(domain, args.instance, name, options, args.rounds, args.seed)
            cells.append(f"{name} {np.mean(totals):,.4g} ({secs:.0f} s)")
        print(f"{domain} #{args.instance}: " + "; ".join(cells), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--domains", nargs="+", default=DOMAINS)
    parser.add_argument("--instance", type=int, default=1)
    parser.add_argument("--seconds", type=float, default=1.0, help="per measurement")
    parser.add_argument("--play", action="store_true", help="play rounds in-process")
    parser.add_argument("--planners", nargs="+", default=["noop", "random", "mpc"])
    parser.add_argument("--option", action="append", default=[], help="mpc's KEY=VALUE")
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if args.play:
        main_play(args)
        return
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
