"""`MPCPlanner`: sampling-based model-predictive control over the batched
simulator, for domains with real, int, bool and enum actions.

Every turn: fit the plan (`search.Plan`, shifted from the last turn) to the
steps left in the round, up to `horizon`; size the batch so that at least
`ITERATIONS` rounds of sampling fit in the turn's time and the sampled
sequences fit in `memory_mb`; then sample, evaluate (one simulator call per
step for the whole batch, on sampled futures), refit, until the clock says
one more simulator call would end past the deadline. The action sent is the
plan's most likely first step, checked with the simulator's
`check_actions` in the real state; if it is illegal, the best evaluated
sequence's first step, the last action sent, noop, and (discrete actions)
a legal action drawn by `ippc.rddl.legal`, in that order.
"""

from __future__ import annotations

import logging
import math
import time
from typing import ClassVar

import numpy as np

from ...rddl.legal import LegalActions, solver_for
from ...rddl.simulator import SimulationError, State
from ...rddl.wire import WireCodec
from ..base import Observation, Planner, PlannerError, SessionInfo, WireFluent
from .search import METHODS, Clock, EvaluationFailed, Plan, evaluate
from .space import ActionSpace, Samples

log = logging.getLogger(__name__)

ITERATIONS = 3  # rounds of refitting a turn should have time for
MIN_SAMPLES = 16  # the fewest samples a round draws (unless memory allows fewer)
# the fewest steps planned (while the round lasts): a reward that reads the
# next state (RecSim's) shows an action's effect only a step later
MIN_HORIZON = 2
KEPT = 4  # best sequences of a turn offered again in the next one
# bytes a state or an action takes inside a step, per byte it takes at rest
# (the step's temporaries)
STEP_OVERHEAD = 16


class MPCPlanner(Planner):
    """Sampling-based model-predictive control (CEM or MPPI) over a receding
    horizon, every candidate evaluated in batched simulator calls."""

    name: ClassVar[str] = "mpc"
    options: ClassVar[dict[str, str]] = {
        "method": "cem (the best tenth of the samples, the default) or mppi (all, weighted)",
        "horizon": "steps planned ahead (default 20; fewer when the round ends sooner)",
        "samples": "sequences sampled per round of refitting, at most (default 256)",
        "time_per_step": "seconds a turn may take (default: the client's share of the session)",
        "memory_mb": "megabytes the sampled sequences and their states may take (default 256)",
        "seed": "integer seed (default: the client's --seed, else unseeded)",
        "iterations": "rounds of refitting a turn, whatever the clock says, each of `samples` "
        "sequences over `horizon` steps (default: as many as time allows); the actions then "
        "depend on the seed alone, not on the machine's speed (tests, comparing variants)",
    }

    def __init__(self, **options: str) -> None:
        super().__init__(**options)
        method = (self.str_option("method", "cem") or "cem").strip().lower()
        if method not in METHODS:
            raise self._option_error("method", method, "one of " + ", ".join(METHODS))
        self.method = method
        self.horizon: int = self.int_option("horizon", 20, minimum=1) or 20
        self.samples: int = self.int_option("samples", 256, minimum=2) or 256
        self.time_per_step = self.float_option("time_per_step", None, minimum=0.0)
        self.memory = int((self.float_option("memory_mb", 256.0, minimum=1.0) or 256.0) * 2**20)
        self.seed = self.int_option("seed")
        self.iterations = self.int_option("iterations", None, minimum=1)
        self.stats: dict[str, int] = {}
        """Counts of the session: turns, late turns, refits, repaired and illegal sampled
        steps, fallbacks."""
        self._plan: Plan | None = None
        self._kept: Samples | None = None
        self._last: Samples | None = None

    # -- session -------------------------------------------------------

    def start_session(self, session: SessionInfo) -> None:
        super().start_session(session)
        sim = session.simulator
        self.space = ActionSpace(sim)
        self.codec = WireCodec(sim)
        self.rng = np.random.default_rng(self.seed if self.seed is not None else session.seed)
        self.initial = sim.initial_state(1)
        self.check = bool(self.space.unhandled)
        for text in self.space.unhandled:
            log.info("mpc: %s is not satisfied by construction; samples are checked", text)
        state_bytes = sum(v.nbytes for v in self.initial.values.values())
        action_bytes = sum(v.nbytes for v in sim.noop(1).values())
        step = self.space.bytes_per_step()
        plan = self.space.plan_bytes_per_step()
        fixed = STEP_OVERHEAD * (state_bytes + action_bytes)
        # a horizon short enough that the plan and MIN_SAMPLES sequences fit
        fits = (self.memory - MIN_SAMPLES * fixed) // max(1, MIN_SAMPLES * step + plan)
        if fits < self.horizon:
            log.warning(
                "mpc: %s: a step of the plan and its samples takes %d bytes; memory_mb allows "
                "a horizon of %d (asked %d)",
                session.instance,
                MIN_SAMPLES * step + plan,
                max(1, fits),
                self.horizon,
            )
            self.horizon = max(1, int(fits))
        self.per_sample = self.horizon * step + fixed
        left = self.memory - self.horizon * plan
        self.cap = max(1, min(self.samples, left // max(1, self.per_sample)))
        self.stats = dict.fromkeys(
            ("turns", "late", "refits", "repaired", "illegal", "fallbacks"), 0
        )
        if self.iterations is None:
            self._measure()
        else:
            # fixed rounds: the batch and the horizon are the options', whatever
            # the machine's speed; nothing here reads a clock or draws from
            # the planner's generator, so a seed fixes every action sent
            self.fixed, self.each = 1e-4, 1e-6
            self.n, self.h_limit = self.cap, self.horizon
            self._compile()

    def _compile(self) -> None:
        """Compile the step and the legality check for a batch (on a generator
        of their own: the planner's draws do not depend on whether this ran)."""
        sim = self.session.simulator if self.session else None
        assert sim is not None
        try:
            states = self.initial[np.zeros(2, dtype=np.int64)]
            sim.step(states, sim.noop(2), np.random.default_rng(0), check=False)
            sim.check_actions(states, sim.noop(2))
            sim.check_actions(self.initial, sim.noop(1))
        except SimulationError as err:
            log.info("mpc: noop cannot be simulated from the initial state (%s)", err)

    def _measure(self) -> None:
        """The first batch size: what `ITERATIONS` rounds of a full horizon in
        the expected turn time allow, by the cost of a simulator call
        (`fixed` + `each` x batch, the fastest of three at 2 and at 32
        states, compiling the step for both sizes on the way). Later turns
        correct it by the rounds they managed (`_adapt`)."""
        sim = self.session.simulator if self.session else None
        assert sim is not None
        self.fixed, self.each = 1e-4, 1e-6
        sizes = (2, min(self.cap, 32)) if self.cap > 2 else (2,)
        cost = {}
        timing = np.random.default_rng(0)  # not the planner's: its draws stay the seed's
        try:
            for n in sizes:
                states = self.initial[np.zeros(n, dtype=np.int64)]
                noop = sim.noop(n)
                sim.step(states, noop, timing, check=False)  # compiles
                times = []
                for _ in range(3):
                    t0 = time.perf_counter()
                    sim.step(states, noop, timing, check=False)
                    times.append(time.perf_counter() - t0)
                cost[n] = min(times)
                sim.check_actions(states, noop)  # compiles the legality check too
            sim.check_actions(self.initial, sim.noop(1))
        except SimulationError as err:
            log.info("mpc: noop cannot be simulated from the initial state (%s)", err)
        if len(cost) == 2:
            (n1, c1), (n2, c2) = sorted(cost.items())
            self.each = max((c2 - c1) / (n2 - n1), 1e-7)
            self.fixed = max(c1 - n1 * self.each, 1e-5)
        elif cost:
            self.fixed = self.each = max(cost[2] / 2, 1e-5)
        session = self.session
        assert session is not None
        turns = max(1, session.rounds * (session.model.horizon or 100))
        turn = self.time_per_step or 0.9 * session.time_allowed / turns
        n, self.h_limit = self._size(self.horizon, turn)
        self.n = max(n, min(MIN_SAMPLES, self.cap))
        log.debug(
            "mpc: a call costs %.2g s + %.2g s a state; %d samples", self.fixed, self.each, self.n
        )

    def _adapt(self, rounds: int) -> None:
        """Fewer samples after a turn in which not one round of refitting
        fitted (then, at `MIN_SAMPLES`, a shorter horizon); more samples, or
        the horizon back, after one that managed twice `ITERATIONS`. A turn
        with few rounds is kept as it is: the plan carries over from turn to
        turn, and a simulator call's cost hardly depends on the batch at
        these sizes (most of it is the call's fixed part)."""
        if rounds == 0:
            if self.n > MIN_SAMPLES:
                self.n = max(MIN_SAMPLES, self.n // 2)
            else:
                self.h_limit = max(MIN_HORIZON, int(self.h_limit * 0.7))
        elif rounds >= 2 * ITERATIONS:
            if self.h_limit < self.horizon:
                self.h_limit = min(self.horizon, self.h_limit + max(1, self.h_limit // 2))
            else:
                self.n = min(self.cap, max(self.n + 1, int(self.n * 1.3)))

    def start_round(self, round_num: int) -> None:
        self._plan = None
        self._kept = None
        self._last = None

    # -- a turn --------------------------------------------------------

    def act(self, obs: Observation) -> list[WireFluent]:
        if self.session is None:
            raise PlannerError("mpc: act() called before start_session()")
        started = time.monotonic()
        deadline = obs.deadline
        if self.time_per_step is not None:
            deadline = min(deadline, started + self.time_per_step)
        budget = max(0.0, deadline - started)
        stop = deadline - max(0.002, 0.1 * budget)
        state = obs.state if obs.state is not None else self.initial
        self.stats["turns"] += 1
        best = self._search(state, obs.steps_left, stop)
        chosen = self._legal(state, best)
        if time.monotonic() > deadline:
            self.stats["late"] += 1
        return chosen

    def _size(self, steps_left: int, budget: float) -> tuple[int, int]:
        """(samples, horizon) for this turn's time and the memory budget (at
        least `MIN_HORIZON` steps while the round lasts)."""
        h = max(1, min(self.horizon, steps_left))
        per_call = budget / (ITERATIONS * h)
        n = int((per_call - self.fixed) / self.each) if per_call > self.fixed else 0
        n = min(n, self.cap)
        if n >= MIN_SAMPLES:
            return n, h
        # too little time for a full horizon: shorten it rather than sample fewer
        n = min(MIN_SAMPLES, self.cap)
        h = int(budget / (ITERATIONS * (self.fixed + self.each * n)))
        return n, max(1, min(max(h, MIN_HORIZON), self.horizon, steps_left))

    def _search(self, state: State, steps_left: int, stop: float) -> Samples | None:
        """Refine the plan until `stop` (or `iterations` times); the best
        evaluated sequence."""
        if self.iterations is not None:
            n, h, stop = self.cap, max(1, min(self.horizon, steps_left)), math.inf
        else:
            n, h = self.n, max(1, min(self.h_limit, steps_left))
        sim = self.session.simulator  # type: ignore[union-attr]
        if self._plan is None:
            self._plan = Plan(self.space, h)
        else:
            self._plan.shift(h)
        kept = _resize(self._kept, h)
        best: Samples | None = None
        best_return = -math.inf
        returns: np.ndarray | None = None
        if n == 0:
            return None
        clock = Clock(stop, self.fixed + self.each * n)
        discount = self.session.model.discount  # type: ignore[union-attr]
        rounds = refits = 0
        while self.iterations is None or rounds < self.iterations:
            rounds += 1
            t_sample = time.monotonic()
            samples = self._plan.sample(n, self.rng, kept)
            t0 = time.monotonic()
            try:
                got = evaluate(
                    sim, self.space, state, samples, self.rng, discount, self.check, clock
                )
            except EvaluationFailed as err:
                log.info("mpc: the simulator refused a batch of samples: %s", err)
                break
            if got is None:
                break
            if self.iterations is None:
                self._learn_cost(n, (time.monotonic() - t0) / max(1, got.calls))
            self.stats["illegal"] += got.illegal
            self.stats["repaired"] += got.repaired
            returns = got.returns
            t_refit = time.monotonic()
            self._plan.refit(samples, returns, self.method)
            self.stats["refits"] += 1
            refits += 1
            clock.reserve = max(0.8 * clock.reserve, time.monotonic() - t_refit + t0 - t_sample)
            order = np.argsort(-returns, kind="stable")[:KEPT]
            order = order[np.isfinite(returns[order])]
            kept = samples.take(order)
            if len(order) and returns[order[0]] > best_return:
                best_return = float(returns[order[0]])
                best = samples.take(int(order[0]))
        self._kept = _shifted(kept) if kept is not None else None
        if self.iterations is None:
            self._adapt(refits)
        return best

    def _learn_cost(self, n: int, per_call: float) -> None:
        # the batch's share of a call, the fixed part as measured at the start
        each = max((per_call - self.fixed) / n, 1e-7)
        self.each = 0.5 * self.each + 0.5 * each

    def _legal(self, state: State, best: Samples | None) -> list[WireFluent]:
        """The first legal one of: the plan's first step, the best sequence's,
        the last action sent, noop; then a legal action drawn by the solver."""
        sim = self.session.simulator  # type: ignore[union-attr]
        assert self._plan is not None
        candidates = [self._plan.first(self.rng)]
        if best is not None:
            candidates.append(best)
        if self._last is not None:
            candidates.append(self._last)
        for i, cand in enumerate(candidates):
            acts = self.space.actions(cand, 0)
            if bool(sim.check_actions(state, acts)[0]):
                if i:
                    self.stats["fallbacks"] += 1
                self._last = Samples(
                    cand.numbers[:1, :1], cand.flags[:1, :1], [c[:1, :1] for c in cand.choices]
                )
                return self.codec.actions(acts, 0)
        self.stats["fallbacks"] += 1
        noop = sim.noop(1)
        if bool(sim.check_actions(state, noop)[0]):
            return []
        if LegalActions.supports(sim):
            try:
                return self.codec.actions(solver_for(sim).sample(state, self.rng, 1), 0)
            except SimulationError as err:
                log.warning("mpc: no legal action found: %s", err)
        log.warning("mpc: no legal action found in this state; sending noop")
        return []


def _shifted(kept: Samples) -> Samples:
    """Sequences one step on: the first step dropped, the last repeated."""

    def roll(x: np.ndarray) -> np.ndarray:
        return np.concatenate([x[:, 1:], x[:, -1:]], axis=1)

    return Samples(roll(kept.numbers), roll(kept.flags), [roll(c) for c in kept.choices])


def _resize(kept: Samples | None, h: int) -> Samples | None:
    """Sequences cut or padded (the last step repeated) to `h` steps."""
    if kept is None or kept.count == 0:
        return None

    def fit(x: np.ndarray) -> np.ndarray:
        if x.shape[1] >= h:
            return x[:, :h]
        pad = np.repeat(x[:, -1:], h - x.shape[1], axis=1)
        return np.concatenate([x, pad], axis=1)

    return Samples(fit(kept.numbers), fit(kept.flags), [fit(c) for c in kept.choices])
