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
from .options import Settings
from .stats import SearchStats
from .tree import _Node

Array = np.ndarray


class Expander:
    """Gives new leaves their candidates and rollout estimates."""

    def __init__(
        self, sim: Simulator, chooser: ActionChooser, settings: Settings, rng: np.random.Generator
    ):
        self.sim = sim
        self.chooser = chooser
        self.settings = settings
        self.rng = rng
        self.state_names = [p.name for p in sim.state_fluents]

    def expand(
        self,
        leaves: list[_Node],
        turn: SearchStats,
        gamma: float,
        clock: Deadline | None = None,
    ) -> None:
        """Give every leaf its candidates and their rollout estimates, all
        leaves' rollouts in one batch (cut short when `clock` says the
        deadline is near: at least the first action is always simulated)."""
        st = self.settings
        states = [leaf.states for leaf in leaves]
        assert all(s is not None for s in states)
        cands = self.chooser.candidates(states)  # type: ignore[arg-type]
        m = st.rollouts
        modes = st.modes
        # rows: for each leaf, each candidate, each mode, m rollouts
        leaf_of: list[Array] = []
        first: list[Array] = []
        depth: list[Array] = []
        steps: list[Array] = []
        start: list[Array] = []
        for i, (leaf, rows) in enumerate(zip(leaves, cands, strict=True)):
            k = len(rows) * modes * m
            if k == 0:
                continue
            assert leaf.states is not None
            leaf_of.append(np.full(k, i))
            first.append(np.repeat(rows, modes * m))
            d = leaf.steps if st.rollout_depth == 0 else min(st.rollout_depth, leaf.steps)
            depth.append(np.full(k, d))
            steps.append(np.full(k, leaf.steps))
            p = leaf.states.batch
            start.append(self.rng.integers(0, p, k) if p > 1 else np.zeros(k, dtype=np.int64))
        returns = np.zeros(0)
        if first:
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
            if st.extrapolate and (st.rollout_depth or (reached < d_all).any()):
                # rollouts that reached a terminal state have their whole return
                factor = _horizon_factor(np.concatenate(steps), reached, gamma)
                returns *= np.where(ended, 1.0, factor)
        offset = 0
        for leaf, rows in zip(leaves, cands, strict=True):
            a = len(rows)
            leaf.acts = rows
            leaf.cnt = [0.0] * a
            leaf.tot = [0.0] * a
            leaf.pending = [0] * a
            leaf.nsum = st.init_weight * a
            leaf.children = [{} for _ in range(a)]
            if a:
                block = returns[offset : offset + a * modes * m].reshape(a, modes, m).mean(axis=2)
                leaf.h = block.max(axis=1).tolist()
                leaf.qv = list(leaf.h)
                offset += a * modes * m
                leaf.value = max(leaf.h)
            else:
                # nothing is legal here (not even noop): a dead end
                leaf.h = []
                leaf.qv = []
                leaf.terminal = True
                leaf.value = 0.0
            leaf.expanded = True
        turn.leaves += len(leaves)

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
