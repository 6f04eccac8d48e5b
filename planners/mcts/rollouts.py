"""Expanding new leaves: every leaf's candidates get a heuristic value
from rollouts, all leaves' rollouts stepped together as one batch (see the
package docstring for the rollout policies and the extrapolation).

May call the simulator's `step` and the action chooser.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from ...rddl.simulator import Simulator, State
from .actions import ActionChooser
from .deadline import Deadline
from .heuristic import IDS, RewardLocks
from .options import Settings
from .stats import SearchStats
from .tree import _Node

Array = np.ndarray


class Expander:
    """Gives new leaves their candidates and first estimates: IDS on the
    most-likely determinisation (`ids`, unless it is too slow for the
    budget), else rollouts; a reward lock (`locks`) gets one candidate and
    its exact value, and is solved."""

    def __init__(
        self,
        sim: Simulator,
        chooser: ActionChooser,
        settings: Settings,
        rng: np.random.Generator,
        ids: IDS | None = None,
        locks: RewardLocks | None = None,
    ):
        self.sim = sim
        self.chooser = chooser
        self.settings = settings
        self.rng = rng
        self.ids = ids
        self.locks = locks
        self.state_names = [p.name for p in sim.state_fluents]

    def _locked(self, leaf: _Node, values: list[float]) -> bool:
        """Whether the leaf's state is a reward lock. Checked only where
        every candidate's estimate is the same (so it is where the reward
        cannot change): the check itself is slow."""
        if self.locks is None or not values or leaf.states is None or leaf.states.batch != 1:
            return False
        if not _all_equal(np.asarray(values)):
            return False
        return self.locks.check(leaf.states) is not None

    def expand(
        self,
        leaves: list[_Node],
        turn: SearchStats,
        gamma: float,
        clock: Deadline | None = None,
    ) -> None:
        """Give every leaf its candidates and their first estimates, all
        leaves' IDS searches, and all their rollouts, in one batch each
        (rollouts are cut short when `clock` says the deadline is near: at
        least the first action is always simulated)."""
        st = self.settings
        states = [leaf.states for leaf in leaves]
        assert all(s is not None for s in states)
        cands = self.chooser.candidates(states)  # type: ignore[arg-type]
        h: list[list[float]] = [[] for _ in leaves]
        use_ids = self.ids is not None and not self.ids.fallback
        by_ids = [i for i in range(len(leaves)) if len(cands[i])] if use_ids else []
        if by_ids:
            assert self.ids is not None
            q = self.ids.estimate(
                _stack_states([leaves[i].states for i in by_ids], self.state_names),
                [leaves[i].steps for i in by_ids],
                [self.chooser.lib.take(cands[i]) for i in by_ids],
                deadline=None if clock is None else clock.stop_at(),
            )
            done: set[int] = set()
            for i, qi in zip(by_ids, q, strict=True):
                finite = qi[np.isfinite(qi)]
                if len(qi) > 1 and len(finite) == len(qi) and _all_equal(finite):
                    # IDS tells these actions apart no better than a coin
                    # (its determinisation may have lost what matters, as
                    # in Traffic where no car ever comes): rollouts instead
                    continue
                # an action IDS finds illegal (it is not in the search's
                # view) ranks below every other
                low = float(finite.min()) - 1.0 if len(finite) else 0.0
                h[i] = np.where(np.isfinite(qi), qi, low).tolist()
                done.add(i)
            turn.ids_leaves += len(done)
        else:
            done = set()
        rolled = [i for i in range(len(leaves)) if len(cands[i]) and i not in done]
        if rolled:
            self._rollout_estimates(leaves, cands, rolled, h, turn, gamma, clock)
        locked = set()
        for i, leaf in enumerate(leaves):
            if self._locked(leaf, h[i]):
                # whatever is done the reward stays: one action, its exact value
                locked.add(i)
                cands[i] = cands[i][:1]
                h[i] = h[i][:1]
            elif i in done and st.heuristic_weight != 1.0:
                h[i] = [st.heuristic_weight * v for v in h[i]]
        for i, (leaf, rows) in enumerate(zip(leaves, cands, strict=True)):
            a = len(rows)
            leaf.acts = rows
            leaf.cnt = [0.0] * a
            leaf.tot = [0.0] * a
            leaf.pending = [0] * a
            leaf.nsum = st.init_weight * a
            leaf.children = [{} for _ in range(a)]
            if a:
                leaf.h = h[i]
                leaf.qv = list(leaf.h)
                leaf.value = max(leaf.h)
                if i in locked:
                    leaf.terminal = True  # solved: its value is exact
                    turn.locks += 1
            else:
                # nothing is legal here (not even noop): a dead end
                leaf.h = []
                leaf.qv = []
                leaf.terminal = True
                leaf.value = 0.0
            leaf.expanded = True
        turn.leaves += len(leaves)

    def _rollout_estimates(
        self,
        leaves: list[_Node],
        cands: list[Array],
        which: list[int],
        h: list[list[float]],
        turn: SearchStats,
        gamma: float,
        clock: Deadline | None,
    ) -> None:
        """`h[i]` for each leaf i of `which`: the mean rollout return of each
        candidate (the better policy's with `best`)."""
        st = self.settings
        m = st.rollouts
        modes = st.modes
        # rows: for each leaf, each candidate, each mode, m rollouts
        leaf_of: list[Array] = []
        first: list[Array] = []
        depth: list[Array] = []
        steps: list[Array] = []
        start: list[Array] = []
        for i in which:
            leaf, rows = leaves[i], cands[i]
            k = len(rows) * modes * m
            assert leaf.states is not None
            leaf_of.append(np.full(k, i))
            first.append(np.repeat(rows, modes * m))
            d = leaf.steps if st.rollout_depth == 0 else min(st.rollout_depth, leaf.steps)
            depth.append(np.full(k, d))
            steps.append(np.full(k, leaf.steps))
            p = leaf.states.batch
            start.append(self.rng.integers(0, p, k) if p > 1 else np.zeros(k, dtype=np.int64))
        d_all = np.concatenate(depth)
        returns, ended, reached = self.rollouts(
            leaves,
            np.concatenate(leaf_of),
            np.concatenate(start),
            np.concatenate(first),
            d_all,
            gamma,
            turn,
            clock,
        )
        # rollouts that reached a terminal state have their whole return
        factor = _horizon_factor(np.concatenate(steps), reached, gamma)
        if st.extrapolate:
            returns *= np.where(ended, 1.0, factor)
        offset = 0
        for i in which:
            a = len(cands[i])
            block = returns[offset : offset + a * modes * m].reshape(a, modes, m).mean(axis=2)
            h[i] = block.max(axis=1).tolist()
            offset += a * modes * m

    def rollouts(
        self,
        leaves: list[_Node],
        leaf_of: Array,
        start: Array,
        first: Array,
        depth: Array,
        gamma: float,
        turn: SearchStats,
        clock: Deadline | None = None,
    ) -> tuple[Array, Array, Array]:
        """Discounted returns of the rollouts (the first action given, then
        the rollout policy: noop for the rows of mode 1 when the policy is
        `best`, else `rollout_policy`), which of them reached a terminal
        state, and how many steps each simulated (`depth`, or fewer where
        it ended or the deadline came first)."""
        sim = self.sim
        st = self.settings
        n = len(first)
        per_leaf = [leaf.states for leaf in leaves]
        if all(s is not None and s.batch == 1 for s in per_leaf):
            states = _stack_states(per_leaf, self.state_names)[leaf_of]
        else:
            states = _gather_rows(per_leaf, leaf_of, start, self.state_names)
        m = st.rollouts
        if st.modes == 2:
            use_noop = (np.arange(n) // m) % 2 == 1
        elif st.rollout_policy == "noop":
            use_noop = np.ones(n, dtype=bool)
        else:
            use_noop = np.zeros(n, dtype=bool)
        returns = np.zeros(n)
        ended = np.zeros(n, dtype=bool)
        reached = np.zeros(n, dtype=np.int64)
        idx = np.arange(n)  # rows still rolling out, as rows of `returns`
        acts = self.chooser.lib.take(first)
        discount = 1.0
        t = 0
        while True:
            out = sim.step(states, acts, self.rng, check=False)
            turn.sim_steps += len(idx)
            turn.sim_calls += 1
            returns[idx] += discount * out.reward
            discount *= gamma
            t += 1
            ended[idx] = out.done
            reached[idx] = t
            alive = (~out.done) & (depth[idx] > t)
            if clock is not None:
                clock.tick()
            if not alive.any() or (clock is not None and clock.passed()):
                break
            if not alive.all():
                keep = np.flatnonzero(alive)
                idx = idx[keep]
                states = out.next_state[keep]
            else:
                states = out.next_state
            acts = self.chooser.rollout_actions(states, use_noop[idx])
        return returns, ended, reached


def _all_equal(values: Array) -> bool:
    """Whether these values are the same (to rounding)."""
    lo, hi = float(values.min()), float(values.max())
    return hi - lo <= 1e-9 * max(1.0, abs(hi))


def _horizon_factor(steps: Array, depth: Array, gamma: float) -> Array:
    """How much a return over `depth` steps is scaled to stand for `steps`
    steps at the same (discounted) mean reward per step."""
    if gamma >= 1.0:
        return steps / depth  # type: ignore[no-any-return]
    return (1.0 - gamma**steps) / (1.0 - gamma**depth)  # type: ignore[no-any-return]


def _stack_states(states: Iterable[State | None], names: list[str]) -> State:
    """One batch of the first state of each (batch-1) state."""
    listed = [s for s in states if s is not None]
    return State({k: np.concatenate([s.values[k][:1] for s in listed], axis=0) for k in names})


def _gather_rows(
    per_leaf: list[State | None], leaf_of: Array, start: Array, names: list[str]
) -> State:
    """Row `start[i]` of the states of leaf `leaf_of[i]`, for every i."""
    sizes = [0 if s is None else s.batch for s in per_leaf]
    offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    listed = [s for s in per_leaf if s is not None]
    flat = {k: np.concatenate([s.values[k] for s in listed], axis=0) for k in names}
    return State({k: v[offsets[leaf_of] + start] for k, v in flat.items()})
