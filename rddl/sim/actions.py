"""Choosing actions: `random_actions` and `legal_actions`.

Owns the action side of a `Simulator` (its methods of the same names call
these): `random_actions` picks random legal actions for every state of a
batch in the manner of rddlsim's RandomConcurrentPolicy (each fluent in
declaration order, each grounding in a random order, `_Order`, taken on a
coin flip if the actions stay legal, at most max-nondef-actions and
`RANDOM_MAX_CONCURRENT` of them; rddlsim's exact policy, with its order
and its random numbers, is `ippc.planners.rddlsim_random`), testing a
window of candidates per state in one batched legality check
(`_take_legal`), and where that finds nothing legal (noop illegal, the
legal actions needing several groundings at once) draws uniformly from the
legal joint actions (`ippc.rddl.legal`); `legal_actions` enumerates every
legal joint action of one state with `ippc.rddl.legal`.

May call the simulator's public methods (`noop`, `check_actions`) and its
model, action defaults and codes, and `ippc.rddl.legal`; nothing of the
compiler.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from ..model import PVariable
from .parts import SimulatorParts
from .state import Array, SimulationError, State

_WINDOW = 32  # candidates per state tested in one batched call in random_actions
_TRIAL_BUDGET = 4_000_000  # action values copied per state and batched call, at most
# rddlsim's RandomConcurrentPolicy takes at most this many actions (its
# MAX_CONCURRENT_ACTIONS), whatever max-nondef-actions allows
RANDOM_MAX_CONCURRENT = 20


class _Order:
    """A random order of n items for each state of a batch: the items by
    increasing random key (ties by index), found only as far as it is read
    (a partial sort), as the random policy reads few of them."""

    def __init__(self, keys: Array):
        self.keys = keys
        self.known = np.zeros((keys.shape[0], 0), dtype=np.intp)

    def at(self, rows: Any, positions: Any) -> Any:
        """The items at `positions` of the order of the states `rows`."""
        needed = int(np.max(positions)) + 1 if np.size(positions) else 0
        if needed > self.known.shape[1]:
            n = self.keys.shape[1]
            m = min(n, max(needed, 2 * self.known.shape[1], 64))
            if m >= n:
                self.known = np.argsort(self.keys, axis=1, kind="stable")
            else:
                part = np.argpartition(self.keys, m - 1, axis=1)[:, :m]
                within = np.lexsort((part, np.take_along_axis(self.keys, part, axis=1)), axis=-1)
                self.known = np.take_along_axis(part, within, axis=1)
        return self.known[rows, positions]


def _groundings(sim: SimulatorParts) -> list[tuple[PVariable, tuple[int, ...]]]:
    return [(p, idx) for p in sim.action_fluents for _, idx in sim._ground(p)]


def _random_value(sim: SimulatorParts, p: PVariable, rng: np.random.Generator, n: int) -> Array:
    """n values of action `p` that differ from its default."""
    default = sim._encode(p, sim.model.default_of(p))
    if p.range == "bool":
        return np.full(n, not default)
    if p.range in sim._compiler.codes:
        size = len(sim._compiler.codes[p.range])
        if size < 2:
            return np.full(n, default)
        draw = rng.integers(0, size - 1, n)
        return draw + (draw >= default)  # type: ignore[no-any-return]
    if p.range == "int":
        step = rng.integers(1, 6, n)
        return default + np.where(rng.random(n) < 0.5, -step, step)  # type: ignore[no-any-return]
    return default + rng.uniform(-1.0, 1.0, n)  # type: ignore[no-any-return]


def random_actions(sim: SimulatorParts, state: State, rng: np.random.Generator) -> dict[str, Array]:
    """Random legal actions for every state of the batch, in the manner of
    rddlsim's RandomConcurrentPolicy: each action fluent in turn, its
    groundings in a random order; each grounding is taken with
    probability 1/2 (with a random non-default value) and kept only if
    the constraints and max-nondef-actions still hold; at most
    max-nondef-actions are taken, and (as rddlsim's policy does, for
    max-nondef-actions = pos-inf) at most `RANDOM_MAX_CONCURRENT`. A state
    where that leaves the actions illegal gets a uniform draw from its
    legal joint actions (`ippc.rddl.legal`); `NoLegalAction` when it has none."""
    batch = state.batch
    actions = sim.noop(batch)
    limit = RANDOM_MAX_CONCURRENT
    if sim.model.max_nondef_actions is not None:
        limit = min(limit, sim.model.max_nondef_actions)
    if not sim._preconditions:
        return _random_unconstrained(sim, actions, batch, limit, rng)
    taken = np.zeros(batch, dtype=np.int64)
    for p, flat, order, heads in _coin_flips(sim, actions, batch, rng):
        n = flat.shape[1]
        values = _random_value(sim, p, rng, batch * n).reshape(batch, n)
        candidates = [np.nonzero(heads[b])[0] for b in range(batch)]  # positions in the order
        _take_legal(sim, state, actions, p, flat, order, values, candidates, taken, limit)
    ok = sim.check_actions(state, actions)
    if not ok.all():
        # noop is illegal there and the coin flips found nothing (ChromaticDice's
        # five dice at once): a uniform draw from what the constraints allow
        from ..legal import LegalActionsUnsupported, solver_for

        bad = np.flatnonzero(~ok)
        try:
            fill = solver_for(sim).sample_batch(state[bad], rng)
        except LegalActionsUnsupported:
            raise SimulationError(
                f"no legal action in state {int(bad[0])} of the batch, not even noop"
            ) from None
        for k, v in fill.items():
            actions[k][bad] = v
    return actions


def _take_legal(
    sim: SimulatorParts,
    state: State,
    actions: dict[str, Array],
    p: PVariable,
    flat: Array,
    order: _Order,
    values: Array,
    candidates: list[Array],
    taken: Array,
    limit: int,
) -> None:
    """The sequential rule (try each candidate in turn, keep it if the
    actions taken so far plus it are legal), a window of candidates per
    state at a time, every state's window in one batched legality test.

    A state's window is tested one of two ways. While candidates are
    refused the set of actions does not change, so each candidate is
    tested alone against it and the first legal one is the one taken
    ("scan"). While candidates are taken the set after k of them is the
    k-th prefix, so the prefixes are tested and the first illegal one is
    the first candidate refused ("run"). A state switches to the other
    way when its window ends the way the other one handles better.
    """
    batch = len(candidates)
    pos = np.zeros(batch, dtype=np.int64)
    run = np.zeros(batch, dtype=bool)
    # every trial copies every action array: fewer candidates per window
    # where they are large
    per_state = sum(int(v[0].size) for v in actions.values())
    width = max(2, min(_WINDOW, _TRIAL_BUDGET // max(1, per_state)))
    scan_width = max(2, min(2 * _WINDOW, _TRIAL_BUDGET // max(1, per_state)))
    while True:
        active = [b for b in range(batch) if pos[b] < len(candidates[b]) and taken[b] < limit]
        if not active:
            return
        rows_b, set_row, set_pos = [], [], []
        windows: list[Array] = []
        first = 0
        for b in active:
            js = candidates[b][pos[b] : pos[b] + (width if run[b] else scan_width)]
            m = len(js)
            windows.append(js)
            rows_b.append(np.full(m, b))
            if run[b]:  # row i: the first i + 1 candidates
                r, c = np.tril_indices(m)
                set_row.append(first + r)
                set_pos.append(js[c])
            else:  # row i: candidate i alone
                set_row.append(first + np.arange(m))
                set_pos.append(js)
            first += m
        rb = np.concatenate(rows_b)
        sr, sp = np.concatenate(set_row), np.concatenate(set_pos)
        trial = {k: v[rb] for k, v in actions.items()}  # (fancy indexing copies)
        tflat = trial[p.name].reshape(len(rb), -1)
        tflat[sr, order.at(rb[sr], sp)] = values[rb[sr], sp]
        legal = sim.check_actions(state[rb], trial)
        start = 0
        for b, js in zip(active, windows, strict=True):
            m = len(js)
            ok = legal[start : start + m]
            start += m
            if run[b]:
                refused = np.nonzero(~ok)[0]
                k = int(refused[0]) if len(refused) else m
                k_taken = min(k, limit - int(taken[b]))
                for j in js[:k_taken]:
                    flat[b, order.at(b, j)] = values[b, j]
                taken[b] += k_taken
                pos[b] += k + 1 if k < m else k
                run[b] = k == m
            else:
                found = np.nonzero(ok)[0]
                if len(found):
                    j = js[found[0]]
                    flat[b, order.at(b, j)] = values[b, j]
                    taken[b] += 1
                    pos[b] += found[0] + 1
                    run[b] = True
                else:
                    pos[b] += m


def _coin_flips(
    sim: SimulatorParts, actions: dict[str, Array], batch: int, rng: np.random.Generator
) -> Iterable[tuple[PVariable, Array, _Order, Array]]:
    """Per action fluent with groundings: its flattened action array (a
    view to write into), a random order of its groundings per state, and
    a fair coin flip per position in that order."""
    for p in sim.action_fluents:
        flat = actions[p.name].reshape(batch, -1)
        n = flat.shape[1]
        if n == 0:
            continue
        yield p, flat, _Order(rng.random((batch, n))), rng.random((batch, n)) < 0.5


def _random_unconstrained(
    sim: SimulatorParts,
    actions: dict[str, Array],
    batch: int,
    limit: int | None,
    rng: np.random.Generator,
) -> dict[str, Array]:
    """The same choice without constraints to check, all at once: in each
    fluent's random order, the coin flips that come up, up to the limit
    (counted across fluents in declaration order)."""
    taken = np.zeros(batch, dtype=np.int64)
    for p, flat, order, heads in _coin_flips(sim, actions, batch, rng):
        if limit is not None:
            rank = taken[:, None] + np.cumsum(heads, axis=1)
            heads &= rank <= limit
        rows = np.nonzero(heads)
        flat[rows[0], order.at(rows[0], rows[1])] = _random_value(sim, p, rng, len(rows[0]))
        taken += heads.sum(axis=1)
    return actions


def legal_actions(
    sim: SimulatorParts, state: State, index: int = 0, limit: int = 100_000
) -> dict[str, Array]:
    """Every legal joint action in one state, stacked along the batch axis
    (noop first when legal), found by `ippc.rddl.legal` (bool, enum and int
    action fluents). Raises `NoLegalAction` when there is none and
    `TooManyActions` when there are more than `limit`."""
    from ..legal import solver_for

    return solver_for(sim).enumerate(state, index, limit)
