"""Simulation speed of ippc.rddl.simulator against pyRDDLGym on IPPC instances.

What it measures
    Ten instances of the installed ``rddlrepository`` package (``INSTANCES``
    below; ``<Domain>_MDP_ippc20xx`` is ``IPPC20xx/<Domain>/MDP`` and
    ``<Domain>_ippc2023`` is ``IPPC2023/<Domain>``, each with its
    ``domain.rddl`` and ``instance<N>.rddl``). For each, in the same run:

    build          ours: ``load_pair(domain, instance)`` then ``Simulator(m)``
                   (which compiles the code for small batches; the code for
                   large batches is compiled on the first large batch, in
                   the batched run's warm-up here).
                   pyRDDLGym: ``pyRDDLGym.make(domain, instance)`` (read,
                   parse, lifted model, numpy simulator, gym spaces).
    build ratio    ours / pyRDDLGym build time (lower = we build faster).
    steps/s        single-state noop steps per second. Ours: ``sim.step(s,
                   noop, rng)`` on a batch of 1 with the default
                   ``check=True`` (action preconditions, state-action
                   constraints and state invariants are checked), ``noop =
                   sim.noop(1)`` built once. pyRDDLGym: ``env.step({})`` with
                   its defaults (max-nondef-actions and state invariants
                   checked, action preconditions not enforced). Both sides
                   restart from the initial state when an episode ends
                   (termination, or the instance's horizon).
    ratio          ours / pyRDDLGym steps per second (higher = we are faster).
    scalar         single-state noop steps per second of ours through
                   ``ScalarStep`` (``ippc.rddl.sim.scalar``: the transition
                   as one Python function over scalars, for tree search),
                   from the same initial state with the same restarts; it
                   checks no constraints, so the single-state figure it is
                   compared with is also timed with ``check=False``
                   (``single nc``). "-" where the model has a construct the
                   scalar step does not write.
    scalar/single  scalar steps per second / our single-state (``check=False``)
                   steps per second, in the same run.
    batched        states stepped per second by ours with ``--batch`` states
                   (default 1024) per noop step, states whose episode ended
                   restarted as above.
    batch/single   our batched states per second / our single-state steps
                   per second.

    Goals (from the issue): ratio >= 3 on every instance, and batch/single
    >= 100 on every instance (each with a PASS/FAIL column); the build
    ratio is printed, with no goal.

How
    Builds: one untimed build per side first (it also pays one-off costs
    such as grammar and parser tables, and tells whether the side fails),
    then the best of ``--repeat`` timed builds. Steps: ``--warmup`` untimed
    steps (a quarter of that for the batch), then the best of ``--repeat``
    runs of ``--steps`` steps (default 500), each timed as a whole with
    ``time.perf_counter`` and continuing from the state the previous one
    reached. The timed runs of the two sides alternate (build ours, build
    theirs, ...; steps ours, steps theirs, batched ours, ...), so that load
    from elsewhere on the machine tends to fall on both sides alike.
    ``gc.collect()`` runs before each timed run, outside the timing, and
    ``gc.freeze()`` after start-up keeps imported modules out of every
    collection (both sides alike). Random draws:
    ``numpy.random.default_rng(0)`` for us, ``env.reset(seed=0)`` for
    pyRDDLGym. pyRDDLGym's console output and warnings are silenced.

    If a side raises on an instance (while building, or stepping, e.g. a
    constraint that a noop violates), its error is shown in the instance's
    row instead of figures; the run goes on.

Usage
    python bench/sim.py [--steps N] [--batch B] [--repeat R] [--warmup W]
                        [--only TEXT] [--json]
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import importlib.util
import io
import json
import os
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from ippc.rddl import load_pair
from ippc.rddl.sim.scalar import ScalarStep, ScalarUnsupported
from ippc.rddl.simulator import Simulator, State

INSTANCES: list[tuple[str, int]] = [
    ("SysAdmin_MDP_ippc2011", 1),
    ("SysAdmin_MDP_ippc2011", 10),
    ("GameOfLife_MDP_ippc2011", 10),
    ("Elevators_MDP_ippc2011", 10),
    ("CrossingTraffic_MDP_ippc2011", 10),
    ("AcademicAdvising_MDP_ippc2014", 10),
    ("Traffic_MDP_ippc2011", 10),
    ("Wildfire_MDP_ippc2014", 10),
    ("Reservoir_ippc2023", 5),
    ("HVAC_ippc2023", 5),
]

DEFAULT_STEPS = 500
DEFAULT_BATCH = 1024
DEFAULT_REPEAT = 7
DEFAULT_WARMUP = 20
SEED = 0
GOAL_RATIO = 3.0  # ours / pyRDDLGym single-state steps per second
GOAL_BATCH = 100.0  # our batched states per second / our single-state rate


# --------------------------------------------------------------------------
# instances


@dataclass(frozen=True)
class Instance:
    name: str  # e.g. "SysAdmin_MDP_ippc2011 #10"
    domain: Path
    instance: Path


def repository_root() -> Path:
    """The folder of the installed rddlrepository package (not imported)."""
    spec = importlib.util.find_spec("rddlrepository")
    if spec is None or not spec.submodule_search_locations:
        sys.exit("rddlrepository is not installed (pip install rddlrepository)")
    return Path(next(iter(spec.submodule_search_locations)))


def resolve(root: Path, name: str, number: int) -> Instance:
    """`SysAdmin_MDP_ippc2011`, 10 -> .../IPPC2011/SysAdmin/MDP/instance10.rddl."""
    parts = name.split("_")
    domain, year = parts[0], parts[-1].removeprefix("ippc")
    folder = root / "archive" / "competitions" / f"IPPC{year}" / domain
    if len(parts) == 3:
        folder /= parts[1]  # MDP / POMDP
    return Instance(f"{name} #{number}", folder / "domain.rddl", folder / f"instance{number}.rddl")


# --------------------------------------------------------------------------
# measuring


@dataclass
class Row:
    """Every figure for one instance; None where a side failed."""

    instance: str
    build_ms_ours: float | None = None
    build_ms_theirs: float | None = None
    steps_per_s_ours: float | None = None
    steps_per_s_theirs: float | None = None
    build_ratio: float | None = None  # ours / theirs, build time
    ratio: float | None = None  # ours / theirs, single state
    batched_states_per_s: float | None = None
    batch_ratio: float | None = None  # batched / single, ours
    unchecked_steps_per_s: float | None = None  # ours, single state, check=False
    scalar_steps_per_s: float | None = None  # ScalarStep, single state
    scalar_ratio: float | None = None  # scalar / unchecked single, ours
    scalar_note: str | None = None  # why there is no scalar figure
    error_ours: str | None = None
    error_theirs: str | None = None


def describe(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text[:160]}"


def timed(run: Callable[[], object]) -> float:
    """Seconds one call of `run` takes (a collection runs first, untimed)."""
    gc.collect()
    start = time.perf_counter()
    run()
    return time.perf_counter() - start


@contextlib.contextmanager
def quiet() -> Iterator[None]:
    """Swallow pyRDDLGym's prints and warnings."""
    with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


class OurRunner:
    """Our simulator stepping noops from the initial state, restarting
    states whose episode ended (termination or horizon)."""

    def __init__(self, sim: Simulator, horizon: int, batch: int, check: bool = True) -> None:
        self.sim = sim
        self.horizon = horizon
        self.batch = batch
        self.check = check
        self.initial = sim.initial_state(batch)
        self.noop = sim.noop(batch)
        self.rng = np.random.default_rng(SEED)
        self.state = self.initial
        self.t = 0

    def run(self, steps: int) -> None:
        sim, noop, rng, initial, check = self.sim, self.noop, self.rng, self.initial, self.check
        state, t = self.state, self.t
        for _ in range(steps):
            out = sim.step(state, noop, rng, check)
            state = out.next_state
            t += 1
            if t >= self.horizon:
                state, t = initial, 0
            elif out.done.any():
                state = restart(state, out.done, initial)
        self.state, self.t = state, t


class ScalarRunner:
    """`ScalarStep` stepping noops from the initial state, restarting as
    `OurRunner` does."""

    def __init__(self, sim: Simulator, horizon: int) -> None:
        self.fast = ScalarStep(sim)
        self.horizon = horizon
        self.initial = self.fast.encode_state(sim.initial_state(1))
        self.noop = self.fast.noop
        self.rng = np.random.default_rng(SEED)
        self.state = self.initial
        self.t = 0

    def run(self, steps: int) -> None:
        step, noop, rng, initial = self.fast.step, self.noop, self.rng, self.initial
        state, t = self.state, self.t
        for _ in range(steps):
            state, _, done = step(state, noop, rng)
            t += 1
            if t >= self.horizon or done:
                state, t = initial, 0
        self.state, self.t = state, t


def restart(state: State, done: np.ndarray, initial: State) -> State:
    """`state` with the states where `done` holds put back to `initial`."""
    if done.all():
        return initial
    out = {}
    for k, v in state.values.items():
        mask = done.reshape((-1,) + (1,) * (v.ndim - 1))
        out[k] = np.where(mask, initial.values[k], v)
    return State(out)


def build_ours(inst: Instance) -> tuple[Simulator, int]:
    m = load_pair(inst.domain, inst.instance)
    return Simulator(m), int(m.horizon or 0) or sys.maxsize


def build_theirs(inst: Instance) -> Any:
    import pyRDDLGym

    return pyRDDLGym.make(str(inst.domain), str(inst.instance))


def step_theirs(env: Any, steps: int) -> None:
    for _ in range(steps):
        env.step({})
        if env.done:
            env.reset()


class Timer:
    """Best-of timings of named runs for one side; the first exception
    ends the side and is kept as its error."""

    def __init__(self) -> None:
        self.best: dict[str, float] = {}
        self.error: str | None = None

    def time(self, label: str, run: Callable[[], object]) -> None:
        if self.error is not None:
            return
        try:
            seconds = timed(run)
        except Exception as exc:  # noqa: BLE001 - a benchmark must go on
            self.error = describe(exc)
            return
        self.best[label] = min(self.best.get(label, float("inf")), seconds)

    def setup(self, run: Callable[[], Any]) -> Any:
        """`run()`, untimed; None (and the side ended) if it raises."""
        if self.error is not None:
            return None
        try:
            return run()
        except Exception as exc:  # noqa: BLE001
            self.error = describe(exc)
            return None


def measure(inst: Instance, steps: int, batch: int, repeat: int, warmup: int) -> Row:
    """Every figure for `inst`. The timed runs of the two sides alternate
    (build ours, build theirs, ..., steps ours, steps theirs, batched ours,
    steps ours, ...), so that load from elsewhere on the machine falls on
    both sides alike rather than on whichever ran during it."""
    ours, theirs = Timer(), Timer()
    with quiet():
        built = ours.setup(lambda: build_ours(inst))
        env = theirs.setup(lambda: build_theirs(inst))
        for _ in range(repeat):
            ours.time("build", lambda: build_ours(inst))
            theirs.time("build", lambda: build_theirs(inst))

        single = many = unchecked = scalar = None
        scalar_timer = Timer()
        if built is not None:
            sim, horizon = built
            single = ours.setup(lambda: OurRunner(sim, horizon, 1))
            many = ours.setup(lambda: OurRunner(sim, horizon, batch))
            unchecked = ours.setup(lambda: OurRunner(sim, horizon, 1, check=False))
            ours.setup(lambda: single.run(warmup) if single else None)
            ours.setup(lambda: many.run(max(1, warmup // 4)) if many else None)
            ours.setup(lambda: unchecked.run(warmup) if unchecked else None)
            try:
                scalar = ScalarRunner(sim, horizon)
            except ScalarUnsupported as exc:
                scalar_timer.error = describe(exc)
            scalar_timer.setup(lambda: scalar.run(warmup) if scalar else None)
        if env is not None:
            theirs.setup(lambda: env.reset(seed=SEED))
            theirs.setup(lambda: step_theirs(env, warmup))
        for _ in range(repeat):
            if single is not None:
                ours.time("single", lambda: single.run(steps))
            if env is not None:
                theirs.time("single", lambda: step_theirs(env, steps))
            if many is not None:
                ours.time("batched", lambda: many.run(steps))
            if unchecked is not None:
                ours.time("unchecked", lambda: unchecked.run(steps))
            if scalar is not None:
                scalar_timer.time("scalar", lambda: scalar.run(steps))

    row = Row(inst.name, error_ours=ours.error, error_theirs=theirs.error)
    if "build" in ours.best:
        row.build_ms_ours = ours.best["build"] * 1e3
    if "build" in theirs.best:
        row.build_ms_theirs = theirs.best["build"] * 1e3
    if ours.error is None and "single" in ours.best:
        row.steps_per_s_ours = steps / ours.best["single"]
    if theirs.error is None and "single" in theirs.best:
        row.steps_per_s_theirs = steps / theirs.best["single"]
    if ours.error is None and "batched" in ours.best:
        row.batched_states_per_s = steps * batch / ours.best["batched"]
    if row.build_ms_ours and row.build_ms_theirs:
        row.build_ratio = row.build_ms_ours / row.build_ms_theirs
    if row.steps_per_s_ours and row.steps_per_s_theirs:
        row.ratio = row.steps_per_s_ours / row.steps_per_s_theirs
    if row.steps_per_s_ours and row.batched_states_per_s:
        row.batch_ratio = row.batched_states_per_s / row.steps_per_s_ours
    if ours.error is None and "unchecked" in ours.best:
        row.unchecked_steps_per_s = steps / ours.best["unchecked"]
    if scalar_timer.error is None and "scalar" in scalar_timer.best:
        row.scalar_steps_per_s = steps / scalar_timer.best["scalar"]
    row.scalar_note = scalar_timer.error
    if row.scalar_steps_per_s and row.unchecked_steps_per_s:
        row.scalar_ratio = row.scalar_steps_per_s / row.unchecked_steps_per_s
    return row


# --------------------------------------------------------------------------
# output


def fmt(value: float | None, spec: str) -> str:
    """`value` formatted by `spec` ("8.1f"), or "-" in the same width."""
    if value is None:
        return format("-", ">" + spec.split(".")[0])
    return format(value, spec)


def mark(value: float | None, goal: float) -> str:
    if value is None:
        return "-"
    return "PASS" if value >= goal else "FAIL"


def goal_line(rows: list[Row], key: str, goal: float, what: str) -> str:
    values = [(r.instance, getattr(r, key)) for r in rows]
    measured = [(n, v) for n, v in values if v is not None]
    met = sum(v >= goal for _, v in measured)
    verdict = "PASS" if values and met == len(values) else "FAIL"
    line = f"{verdict}  {what} >= {goal:g}x: {met}/{len(values)} instances meet it"
    if measured:
        worst = min(measured, key=lambda nv: nv[1])
        line += f" (lowest {worst[1]:.2f}x, {worst[0]})"
    missing = len(values) - len(measured)
    if missing:
        line += f"; {missing} not measured"
    return line


def print_table(rows: list[Row], args: argparse.Namespace, elapsed: float) -> None:
    print(
        f"noop steps: {args.steps} timed per run, best of {args.repeat}, after {args.warmup} "
        f"warm-up; batched: {args.batch} states per step"
    )
    print()
    head = (
        f"{'instance':34} {'build ms':>8} {'':>8} {'build':>6}  {'steps/s':>8} {'':>8}  "
        f"{'ratio':>6} {'goal 1':>6}  {'batched':>10} {'batch/':>7} {'goal 2':>6}  "
        f"{'single nc':>9} {'scalar':>9} {'scalar/':>7}"
    )
    sub = (
        f"{'':34} {'ours':>8} {'theirs':>8} {'ratio':>6}  {'ours':>8} {'theirs':>8}  "
        f"{'':>6} {'>=3':>6}  {'states/s':>10} {'single':>7} {'>=100':>6}"
    )
    print(head)
    print(sub)
    print("-" * len(sub))
    for r in rows:
        line = (
            f"{r.instance:34} {fmt(r.build_ms_ours, '8.1f')} {fmt(r.build_ms_theirs, '8.1f')} "
            f"{fmt(r.build_ratio, '6.2f')}  "
            f"{fmt(r.steps_per_s_ours, '8.0f')} {fmt(r.steps_per_s_theirs, '8.0f')}  "
            f"{fmt(r.ratio, '6.2f')} {mark(r.ratio, GOAL_RATIO):>6}  "
            f"{fmt(r.batched_states_per_s, '10.0f')} {fmt(r.batch_ratio, '7.1f')} "
            f"{mark(r.batch_ratio, GOAL_BATCH):>6}  "
            f"{fmt(r.unchecked_steps_per_s, '9.0f')} {fmt(r.scalar_steps_per_s, '9.0f')} "
            f"{fmt(r.scalar_ratio, '7.1f')}"
        )
        print(line.rstrip())
        if r.scalar_note:
            print(f"{'':36}no scalar step: {r.scalar_note}")
        if r.error_ours:
            print(f"{'':36}ours failed: {r.error_ours}")
        if r.error_theirs:
            print(f"{'':36}pyRDDLGym failed: {r.error_theirs}")
    print()
    print("goals:")
    print("  1. " + goal_line(rows, "ratio", GOAL_RATIO, "single-state steps/s, ours/pyRDDLGym"))
    print(
        "  2. "
        + goal_line(rows, "batch_ratio", GOAL_BATCH, "batched states/s / our single-state steps/s")
    )
    scalars = [r.scalar_ratio for r in rows if r.scalar_ratio is not None]
    line4 = "  4. scalar / numpy single-state steps/s (check=False): printed (no goal)"
    if scalars:
        line4 += f"; from {min(scalars):.1f}x to {max(scalars):.1f}x on {len(scalars)}/{len(rows)}"
    builds = [r.build_ratio for r in rows if r.build_ratio is not None]
    line = "  3. build time, ours/pyRDDLGym: printed (no goal)"
    if builds:
        line += f"; from {min(builds):.2f}x to {max(builds):.2f}x (lower = we build faster)"
    print(line)
    print(line4)
    print()
    print(f"run took {elapsed:.1f} s")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    ap.add_argument(
        "--steps",
        type=int,
        default=DEFAULT_STEPS,
        metavar="N",
        help="noop steps per timed run (default %(default)s)",
    )
    ap.add_argument(
        "--batch",
        type=int,
        default=DEFAULT_BATCH,
        metavar="B",
        help="states per batched step (default %(default)s)",
    )
    ap.add_argument(
        "--repeat",
        type=int,
        default=DEFAULT_REPEAT,
        metavar="R",
        help="best of R timed runs (default %(default)s)",
    )
    ap.add_argument(
        "--warmup",
        type=int,
        default=DEFAULT_WARMUP,
        metavar="W",
        help="untimed steps before timing (default %(default)s)",
    )
    ap.add_argument(
        "--only", metavar="TEXT", default=None, help="only instances whose name contains TEXT"
    )
    ap.add_argument(
        "--json", action="store_true", help="print one JSON object instead of the table"
    )
    args = ap.parse_args(argv)
    if min(args.steps, args.batch, args.repeat) < 1 or args.warmup < 0:
        ap.error("--steps, --batch and --repeat must be at least 1, --warmup at least 0")

    started = time.perf_counter()
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    with quiet():
        import pyRDDLGym  # noqa: F401 - imported here so its start-up is silenced
    root = repository_root()
    chosen = [resolve(root, n, i) for n, i in INSTANCES]
    if args.only:
        chosen = [c for c in chosen if args.only.lower() in c.name.lower()]
    gc.collect()
    gc.freeze()
    rows = [measure(c, args.steps, args.batch, args.repeat, args.warmup) for c in chosen]
    elapsed = time.perf_counter() - started

    if args.json:
        out = {
            "steps": args.steps,
            "batch": args.batch,
            "repeat": args.repeat,
            "warmup": args.warmup,
            "goals": {"ratio": GOAL_RATIO, "batch_ratio": GOAL_BATCH, "build_ratio": None},
            "rows": [asdict(r) for r in rows],
            "elapsed_s": elapsed,
        }
        print(json.dumps(out, indent=2))
    else:
        print_table(rows, args, elapsed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
