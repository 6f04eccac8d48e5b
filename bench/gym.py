"""Speed of ippc.gym's environments on SysAdmin (IPPC 2011) instance 10.

What it measures
    single         steps per second of one ``RDDLEnv``: ``env.step(action)``
                   with a Dict action rebooting one computer drawn at random
                   (legal: max-nondef-actions is 1), ``env.reset()`` when the
                   episode ends (the horizon, 40).
    vector         states stepped per second by one ``RDDLVectorEnv`` of
                   ``--envs`` environments (default 256): ``envs.step(action)``
                   with a batched Dict action (one random reboot per
                   environment), next-step autoreset, each state drawing from
                   its own generator (``streams="per_state"``, the default,
                   which makes environment i equal an RDDLEnv with the same
                   seed); ``vector 1 stream`` the same with one generator for
                   the batch (``streams="batch"``).
    flat           steps per second of one ``FlatRDDLEnv`` (``Discrete(11)``: noop
                   or one reboot), with the same reboots as ``single`` given
                   as indices: what the flat spaces cost.
    SB3 vector     states stepped per second by ``SB3VecEnv`` (stable-baselines3's
                   VecEnv over one RDDLVectorEnv) of ``--envs`` environments,
                   through SB3's ``step`` with an index per environment;
    SB3 dummy      the same through SB3's own ``DummyVecEnv`` over ``--envs``
                   ``FlatRDDLEnv``s (n environments stepped in a loop). Both
                   skipped, with a message, when stable-baselines3 is not
                   installed.
    pyRDDLGym      steps per second of pyRDDLGym's ``env.step(action)``
                   (``pyRDDLGym.make("SysAdmin_MDP_ippc2011", "10")``, its
                   defaults) with the same actions as ``single`` (the same
                   grounded names), ``env.reset()`` when it says done.
                   Skipped, with a message, when pyRDDLGym is not installed.

    Goals (issue 22): vector / single >= 30, and single / pyRDDLGym >= 3.

How
    The actions are drawn once, before any timing, from
    ``numpy.random.default_rng(0)``; the environments are seeded with
    ``reset(seed=0)``. Each side gets ``--warmup`` untimed steps, then the
    best of ``--repeat`` runs of ``--steps`` steps (vector: ``--steps`` //
    8 batched steps), each timed as a whole with ``time.perf_counter`` and
    continuing where the previous run stopped. The timed runs of the sides
    alternate (single, vector, vector 1 stream, pyRDDLGym, single, ...), so
    that load from elsewhere on the machine falls on all of them alike;
    ``gc.collect()`` runs before each, outside the timing. The load average
    is printed with the figures.

Usage
    python bench/gym.py [--steps N] [--envs N] [--repeat R] [--warmup W] [--json]
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import io
import json
import os
import sys
import time
import warnings
from collections.abc import Callable
from typing import Any, cast

import numpy as np
from gymnasium import spaces
from ippc.gym import FlatRDDLEnv, RDDLEnv, RDDLVectorEnv

PROBLEM, INSTANCE = "SysAdmin_MDP_ippc2011", "10"
DEFAULT_STEPS = 4000
DEFAULT_ENVS = 256
DEFAULT_REPEAT = 5
DEFAULT_WARMUP = 200
GOAL_VECTOR = 30.0  # vector states per second / single steps per second
GOAL_PEER = 3.0  # single steps per second / pyRDDLGym steps per second


def episodes(env: Any, actions: list[dict[str, Any]]) -> Callable[[int], int]:
    """A function running n steps of a Gymnasium env with the actions in turn
    (reset when an episode ends; warnings silenced); returns the steps made."""
    env.reset(seed=0)
    where = [0]

    def run(n: int) -> int:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for _ in range(n):
                a = actions[where[0] % len(actions)]
                where[0] += 1
                _, _, terminated, truncated, _ = env.step(a)
                if terminated or truncated:
                    env.reset()
        return n

    return run


def single_runner(steps: int, seed: int) -> tuple[Callable[[int], int], list[str]]:
    """A function running n steps of one RDDLEnv (returns the steps made), and
    the action names."""
    env = RDDLEnv(PROBLEM, INSTANCE)
    names = list(cast(spaces.Dict, env.action_space).spaces)
    rng = np.random.default_rng(seed)
    actions = [{names[int(k)]: 1} for k in rng.integers(0, len(names), steps)]
    return episodes(env, actions), names


def vector_runner(
    envs_n: int, batches: int, streams: str, names: list[str], seed: int
) -> Callable[[int], int]:
    """A function running n batched steps of an RDDLVectorEnv (returns the states stepped)."""
    envs = RDDLVectorEnv(PROBLEM, INSTANCE, num_envs=envs_n, streams=streams)
    rng = np.random.default_rng(seed)
    actions = []
    for _ in range(min(batches, 64)):
        choice = rng.integers(0, len(names), envs_n)
        actions.append({k: (choice == j).astype(np.int64) for j, k in enumerate(names)})
    envs.reset(seed=0)
    where = [0]

    def run(n: int) -> int:
        for _ in range(n):
            envs.step(actions[where[0] % len(actions)])
            where[0] += 1
        return n * envs_n

    return run


def peer_runner(steps: int, names: list[str], seed: int) -> Callable[[int], int] | str:
    """pyRDDLGym's env.step with the same actions, or why it cannot run."""
    try:
        import pyRDDLGym
    except ImportError:
        return "pyRDDLGym is not installed (pip install pyRDDLGym): the peer is skipped"
    with (
        contextlib.redirect_stdout(io.StringIO()),
        contextlib.redirect_stderr(io.StringIO()),
        warnings.catch_warnings(),
    ):
        warnings.simplefilter("ignore")
        env = pyRDDLGym.make(PROBLEM, INSTANCE)
    missing = set(names) - set(env.action_space.spaces)
    if missing:
        return f"pyRDDLGym names the actions otherwise ({sorted(missing)[:3]}): skipped"
    rng = np.random.default_rng(seed)
    actions = [{names[int(k)]: True} for k in rng.integers(0, len(names), steps)]
    return episodes(env, actions)


def flat_runner(steps: int, names: list[str], seed: int) -> Callable[[int], int]:
    """One FlatRDDLEnv with the reboots of `single_runner` as Discrete indices."""
    env = FlatRDDLEnv(PROBLEM, INSTANCE)
    rng = np.random.default_rng(seed)
    # index j + 1 reboots the j-th computer in the Dict's key order
    return episodes(env, [int(k) + 1 for k in rng.integers(0, len(names), steps)])


def sb3_runners(
    envs_n: int, batches: int, names: list[str], seed: int
) -> tuple[Callable[[int], int], Callable[[int], int]] | str:
    """SB3VecEnv's and DummyVecEnv's step over n environments, or why they cannot run."""
    try:
        from ippc.gym.baselines import SB3VecEnv
        from stable_baselines3.common.vec_env import DummyVecEnv
    except ImportError:
        return "stable-baselines3 is not installed (pip install 'ippc[rl]'): SB3 is skipped"
    rng = np.random.default_rng(seed)
    actions = [rng.integers(0, len(names), envs_n) + 1 for _ in range(min(batches, 64))]

    def runner(vec: Any) -> Callable[[int], int]:
        vec.seed(0)
        vec.reset()
        where = [0]

        def run(n: int) -> int:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                for _ in range(n):
                    vec.step(actions[where[0] % len(actions)])
                    where[0] += 1
            return n * envs_n

        return run

    ours = SB3VecEnv(PROBLEM, INSTANCE, num_envs=envs_n)
    theirs = DummyVecEnv([lambda: FlatRDDLEnv(PROBLEM, INSTANCE) for _ in range(envs_n)])
    return runner(ours), runner(theirs)


def best_rate(run: Callable[[int], int], n: int, times: list[float]) -> float:
    """One timed run of n; appends its items per second to `times`; the best so far."""
    gc.collect()
    start = time.perf_counter()
    items = run(n)
    times.append(items / (time.perf_counter() - start))
    return max(times)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=DEFAULT_STEPS)
    parser.add_argument("--envs", type=int, default=DEFAULT_ENVS)
    parser.add_argument("--repeat", type=int, default=DEFAULT_REPEAT)
    parser.add_argument("--warmup", type=int, default=DEFAULT_WARMUP)
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = parser.parse_args(argv)

    single, names = single_runner(args.steps, 0)
    batches = max(1, args.steps // 8)
    sides: dict[str, tuple[Callable[[int], int], int]] = {
        "single": (single, args.steps),
        "vector": (vector_runner(args.envs, batches, "per_state", names, 0), batches),
        "vector 1 stream": (vector_runner(args.envs, batches, "batch", names, 0), batches),
    }
    sides["flat"] = (flat_runner(args.steps, names, 0), args.steps)
    sb3 = sb3_runners(args.envs, batches, names, 0)
    if isinstance(sb3, str):
        print(sb3, file=sys.stderr)
    else:
        sides["SB3 vector"] = (sb3[0], batches)
        sides["SB3 dummy"] = (sb3[1], batches)
    peer = peer_runner(args.steps, names, 0)
    if isinstance(peer, str):
        print(peer, file=sys.stderr)
    else:
        sides["pyRDDLGym"] = (peer, args.steps)
    for run, n in sides.values():
        run(max(1, args.warmup // (8 if n == batches else 1)))
    gc.freeze()
    load_before = os.getloadavg()[0]
    rates: dict[str, list[float]] = {k: [] for k in sides}
    for _ in range(args.repeat):
        for name, (run, n) in sides.items():
            best_rate(run, n, rates[name])
    best = {k: max(v) for k, v in rates.items()}
    figures: dict[str, Any] = {
        "instance": f"{PROBLEM} #{INSTANCE}",
        "envs": args.envs,
        "steps_per_second": best,
        "vector_over_single": best["vector"] / best["single"],
        "one_stream_over_single": best["vector 1 stream"] / best["single"],
        "single_over_pyrddlgym": best["single"] / best["pyRDDLGym"]
        if "pyRDDLGym" in best
        else None,
        "flat_over_single": best["flat"] / best["single"],
        "sb3_vector_over_dummy": best["SB3 vector"] / best["SB3 dummy"]
        if "SB3 vector" in best
        else None,
        "load_average": [round(load_before, 2), round(os.getloadavg()[0], 2)],
    }
    if args.json:
        print(json.dumps(figures, indent=2))
        return 0
    print(f"{figures['instance']}, best of {args.repeat} runs, load average "
          f"{figures['load_average'][0]} -> {figures['load_average'][1]}")  # fmt: skip
    print(f"{'side':<16}{'per second':>14}")
    for name, rate in best.items():
        vector = name.startswith(("vector", "SB3"))
        unit = f"states ({args.envs} envs)" if vector else "steps"
        print(f"{name:<16}{rate:>14.0f}  {unit}")

    def verdict(value: float, goal: float) -> str:
        return "PASS" if value >= goal else "FAIL"

    r = figures["vector_over_single"]
    print(
        f"vector / single          {r:7.1f}x  goal >= {GOAL_VECTOR:g}x  {verdict(r, GOAL_VECTOR)}"
    )
    r = figures["one_stream_over_single"]
    print(
        f"vector 1 stream / single {r:7.1f}x  goal >= {GOAL_VECTOR:g}x  {verdict(r, GOAL_VECTOR)}"
    )
    r = figures["flat_over_single"]
    print(f"flat / single            {r:7.2f}x")
    r = figures["sb3_vector_over_dummy"]
    if r is None:
        print("SB3 vector / SB3 dummy   skipped (stable-baselines3 is not installed)")
    else:
        print(f"SB3 vector / SB3 dummy   {r:7.1f}x")
    r = figures["single_over_pyrddlgym"]
    if r is None:
        print("single / pyRDDLGym       skipped (pyRDDLGym is not installed)")
    else:
        print(
            f"single / pyRDDLGym       {r:7.1f}x  goal >= {GOAL_PEER:g}x  {verdict(r, GOAL_PEER)}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
