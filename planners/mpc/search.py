"""The receding-horizon plan and one round of its refinement: sample action
sequences around the plan, evaluate them all in batched simulator calls on
sampled futures, refit the plan to the best of them.

The plan is a distribution over sequences of `h` steps, one factor per step
and per column of the action space (`space.ActionSpace`): a normal
(mean, std) for each number, clipped to its bounds; a probability for each
flag; a categorical for each choice group. `refit` weighs the samples by
their return, either the cross-entropy method (`cem`: the best `ELITE`
fraction, alike) or MPPI (`mppi`: every sample by exp(return / temperature),
the temperature `TEMPERATURE` times the spread of the returns), and moves
the plan `SMOOTHING` of the way to the weighted fit. Between turns the
plan shifts by one step (`shift`) and widens back halfway to its initial
spread, so that what it learnt is kept and it can still move.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ...rddl.simulator import SimulationError, Simulator, State
from .space import ActionSpace, Samples

Array = np.ndarray

ELITE = 0.1  # cem: the fraction of samples refitted to
TEMPERATURE = 0.1  # mppi: weights exp((R - max R) / (TEMPERATURE * std R))
SMOOTHING = 0.8  # how far a refit moves the plan
MIN_STD = 0.01  # of a bounded number's range (or of its initial spread)
KEEP = 0.9  # how much of the learnt spread a shift keeps
GROWTH = 2.0  # the spread of an unbounded number that moved by more than it

METHODS = ("cem", "mppi")


class Plan:
    """A distribution over action sequences of `h` steps."""

    def __init__(self, space: ActionSpace, h: int) -> None:
        self.space = space
        self.h = h
        lo, hi = space.lower, space.upper
        span = hi - lo
        finite = np.isfinite(span)
        scale = np.maximum(1.0, np.abs(space.number_default))
        for side in (lo, hi):
            scale = np.where(np.isfinite(side), np.maximum(scale, np.abs(side)), scale)
        self.init_mean = np.clip(space.number_default, lo, hi)
        self.init_std = np.where(finite, span / 4.0, scale)
        self.min_std = MIN_STD * self.init_std
        self.unbounded = ~finite
        self.init_prob = np.full(space.n_flags, 0.5)
        self.init_probs = [
            np.full((ch.groups, ch.options), 1.0 / ch.options) for ch in space.choices
        ]
        self.mean = np.tile(self.init_mean, (h, 1))
        self.std = np.tile(self.init_std, (h, 1))
        self.prob = np.tile(self.init_prob, (h, 1))
        self.probs = [np.tile(p, (h, 1, 1)) for p in self.init_probs]
        self.fitted = False  # refitted at least once

    def shift(self, h: int) -> None:
        """Drop the step just played, widen back, and fit the plan to `h` steps
        (a fresh step at the end, or the tail cut where the round ends sooner)."""

        def roll(x: Array, init: Array, widen: bool) -> Array:
            body = x[1 : 1 + h]
            if widen:
                body = KEEP * body + (1 - KEEP) * init
            if len(body) < h:
                body = np.concatenate([body, np.tile(init, (h - len(body),) + (1,) * init.ndim)])
            return body

        self.mean = roll(self.mean, self.init_mean, False)
        self.std = roll(self.std, self.init_std, True)
        self.prob = roll(self.prob, self.init_prob, True)
        self.probs = [roll(p, i, True) for p, i in zip(self.probs, self.init_probs, strict=True)]
        self.h = h

    def sample(self, n: int, rng: np.random.Generator, keep: Samples | None = None) -> Samples:
        """`n` sequences: the plan's most likely one first, then `keep`'s
        (earlier good sequences), then draws."""
        h, space = self.h, self.space
        numbers = self.mean + self.std * rng.standard_normal((n, h, space.n_numbers))
        numbers[0] = self.mean
        flags = rng.random((n, h, space.n_flags)) < self.prob
        flags[0] = self.prob > 0.5
        choices = []
        for p in self.probs:
            cdf = np.cumsum(p, axis=-1)
            u = rng.random((n, h, p.shape[1], 1)) * cdf[..., -1:]
            drawn = np.minimum((cdf < u).sum(axis=-1), p.shape[-1] - 1)
            drawn[0] = p.argmax(axis=-1)
            choices.append(drawn)
        out = Samples(numbers, flags, choices)
        if keep is not None and keep.count and n > 1:
            m = min(keep.count, n - 1)
            out.numbers[1 : 1 + m] = keep.numbers[:m]
            out.flags[1 : 1 + m] = keep.flags[:m]
            for c, k in zip(out.choices, keep.choices, strict=True):
                c[1 : 1 + m] = k[:m]
        space.clip(out.numbers)
        space.limit_nondefault(out)
        return out

    def refit(self, samples: Samples, returns: Array, method: str) -> None:
        """Move the plan towards the samples, weighted by their returns."""
        w = weights(returns, method)
        if w is None:
            return
        a = SMOOTHING
        wn = w[:, None, None]
        mean = (wn * samples.numbers).sum(axis=0)
        var = (wn * (samples.numbers - mean) ** 2).sum(axis=0)
        moved = np.abs(mean - self.mean) > 0.5 * self.std
        std = np.maximum(a * np.sqrt(var) + (1 - a) * self.std, self.min_std)
        # an unbounded number whose best samples lie a spread away: its scale
        # was guessed too small, so the spread grows instead of shrinking
        grow = moved & self.unbounded
        self.std = np.where(grow, GROWTH * self.std, std)
        self.mean = a * mean + (1 - a) * self.mean
        self.prob = a * (wn * samples.flags).sum(axis=0) + (1 - a) * self.prob
        for i, (drawn, p) in enumerate(zip(samples.choices, self.probs, strict=True)):
            n, h, g = drawn.shape
            k = p.shape[-1]
            cell = (np.arange(h)[:, None] * g + np.arange(g)[None, :]) * k
            flat = (cell[None] + drawn).reshape(-1)
            freq = np.bincount(flat, weights=np.repeat(w, h * g), minlength=h * g * k)
            self.probs[i] = a * freq.reshape(h, g, k) + (1 - a) * p
        self.fitted = True

    def first(self, rng: np.random.Generator) -> Samples:
        """The plan's most likely first action (a batch of one, one step). A
        plan never refitted (no round of sampling fitted in the turns so far)
        has no most likely flags and choices: they are drawn instead, so that
        a planner out of time acts like a random baseline in them rather than
        always sending their defaults; its numbers stay at their means."""
        space = self.space
        if not self.fitted:
            drawn = self.sample(2, rng).take(1)
            drawn.numbers[:] = self.mean[None]
            space.clip(drawn.numbers)
            out = Samples(
                drawn.numbers[:, :1], drawn.flags[:, :1], [c[:, :1] for c in drawn.choices]
            )
            space.limit_nondefault(out)
            return out
        numbers = self.mean[None, :1].copy()
        space.clip(numbers)
        out = Samples(
            numbers, (self.prob[None, :1] > 0.5), [p[None, :1].argmax(axis=-1) for p in self.probs]
        )
        space.limit_nondefault(out)
        return out


def weights(returns: Array, method: str) -> Array | None:
    """The samples' weights (summing to 1), or None when none is finite or
    every finite return is the same."""
    finite = np.isfinite(returns)
    if not finite.any():
        return None
    r = np.where(finite, returns, -np.inf)
    if np.ptp(r[finite]) == 0:
        return None  # all alike: nothing to learn (and no tie may favour the first sample)
    if method == "cem":
        k = max(1, math.ceil(ELITE * int(finite.sum())))
        top = np.argsort(-r, kind="stable")[:k]
        w = np.zeros(len(r))
        w[top] = 1.0 / k
        return w
    best = r.max()
    spread = float(r[finite].std()) or 1.0
    w = np.exp((r - best) / (TEMPERATURE * spread))
    return w / w.sum()  # type: ignore[no-any-return]


@dataclass
class Evaluation:
    """What evaluating a batch of sequences found."""

    returns: Array  # (n,): discounted return over the plan's steps; -inf where illegal
    illegal: int  # sequences with an action the constraints forbid, even repaired
    repaired: int  # sampled steps that broke a checked precondition and were repaired
    calls: int  # simulator calls made


def evaluate(
    sim: Simulator,
    space: ActionSpace,
    state: State,
    samples: Samples,
    rng: np.random.Generator,
    discount: float,
    check: bool,
    clock: Clock,
) -> Evaluation | None:
    """Every sequence played from `state` on one sampled future each, in one
    simulator call per step; None when the clock says the deadline would
    pass before the next call (asked before every call). Raises
    `EvaluationFailed` when the simulator refuses the batch."""
    n, h = samples.count, samples.numbers.shape[1]
    states = state[np.zeros(n, dtype=np.int64)]
    total = np.zeros(n)
    alive = np.ones(n, dtype=bool)
    legal = np.ones(n, dtype=bool)
    repaired = 0
    scale = 1.0
    calls = 0
    for t in range(h):
        if clock.passed():
            return None
        acts = space.actions(samples, t)
        if check:
            ok = sim.check_actions(states, acts)
            if not ok.all():
                repaired += int((~ok).sum())
                acts, ok = repair(sim, space, states, samples, t, ok)
                legal &= ok
        try:
            step = sim.step(states, acts, rng, check=False)
        except (SimulationError, FloatingPointError, ValueError) as err:
            raise EvaluationFailed(str(err)) from err
        calls += 1
        reward = step.reward
        total += np.where(alive, scale * np.where(reward == reward, reward, -np.inf), 0.0)
        alive &= ~step.done
        scale *= discount
        states = step.next_state
        if not alive.any():
            break
    total[~legal] = -np.inf
    return Evaluation(total, int((~legal).sum()), repaired, calls)


REPAIR_HALVINGS = 6  # bisection steps of a repair: within 1/64 of the way


def repair(
    sim: Simulator, space: ActionSpace, states: State, samples: Samples, t: int, ok: Array
) -> tuple[dict[str, Array], Array]:
    """Step `t` of the sequences that break a checked precondition (`~ok`),
    repaired in place: their numbers moved back towards their defaults,
    as little as bisection finds legal; where that is not enough, the whole
    step set to noop; where noop is illegal too, left as it is and
    reported (the returned mask is False there, and the caller plays noop
    in that row so that the batch stays one call)."""
    bad = np.flatnonzero(~ok)
    sub = states[bad]
    x = samples.numbers[bad, t].copy()
    d = np.broadcast_to(space.number_default, x.shape)
    fixed = np.zeros(len(bad), dtype=bool)
    if space.n_numbers:
        lo, hi = np.zeros(len(bad)), np.ones(len(bad))
        for _ in range(REPAIR_HALVINGS):
            mid = (lo + hi) / 2
            samples.numbers[bad, t] = _towards(space, d, x, mid)
            good = sim.check_actions(sub, space.actions(samples.take(bad), t))
            lo = np.where(good, mid, lo)
            hi = np.where(good, hi, mid)
        samples.numbers[bad, t] = _towards(space, d, x, lo)
        fixed = sim.check_actions(sub, space.actions(samples.take(bad), t))
    rest = bad[~fixed]
    if len(rest):
        noop = space.noop(len(rest), 1)
        samples.numbers[rest, t] = noop.numbers[:, 0]
        samples.flags[rest, t] = noop.flags[:, 0]
        for c, nc in zip(samples.choices, noop.choices, strict=True):
            c[rest, t] = nc[:, 0]
    acts = space.actions(samples, t)
    ok = ok.copy()
    ok[bad] = True
    if len(rest):
        ok[rest] = sim.check_actions(states[rest], space.actions(samples.take(rest), t))
    return acts, ok


def _towards(space: ActionSpace, d: Array, x: Array, share: Array) -> Array:
    """d + share * (x - d), ints rounded towards d (a step back stays legal)."""
    out = d + share[:, None] * (x - d)
    if space.integral.any():
        out[:, space.integral] = (d + np.trunc(out - d))[:, space.integral]
    return out


class EvaluationFailed(Exception):
    """The simulator refused a batch of sampled sequences (a distribution's
    parameters out of their domain for some sampled action)."""


class Clock:
    """The turn's deadline (a `time.monotonic()` value) and the cost of one
    simulator call with its share of the work around it: the time between
    two questions, or more while recent ones were slower (it decays by a
    fifth a question)."""

    def __init__(self, stop: float, call: float) -> None:
        self.stop = stop
        self.call = call
        self.reserve = 0.0
        """Seconds the work after the last call takes (a refit, a sampling)."""
        self._last = time.monotonic()

    def passed(self) -> bool:
        """Whether one more call, and the work after it, would end past the
        deadline (the time since the last question counts as one call)."""
        now = time.monotonic()
        self.call = max(now - self._last, 0.8 * self.call)
        self._last = now
        return now + 1.5 * self.call + self.reserve >= self.stop

    def left(self) -> float:
        return self.stop - time.monotonic()
