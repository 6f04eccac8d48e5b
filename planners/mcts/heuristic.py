"""Q-value initialisation for new decision nodes of the wave engine: PROST's
iterative deepening search (IDS) on the most-likely determinisation, batched
over the vectorised simulator, with its learning phase and a fallback.

Theory of operation (after Keller & Eyerich 2012, "PROST: Probabilistic
Planning Based on UCT", and PROST's IDS; no code of it is used). The
heuristic looks ahead on the *most-likely determinisation* of the model
(`ippc.planners.determinise`: every Bernoulli is its likelier outcome,
every other draw its mode or mean), where a state and a joint action have
one successor. The depth-d value of a candidate action a in state s is

    Q_d(s, a) = r(s, a) + gamma * max_a' Q_{d-1}(s', a'),   Q_1(s, a) = r(s, a)

(s' the determinised successor; a terminal successor, or one with no steps
left, is worth 0; an action that is illegal in a state counts as absent).
IDS computes Q_2, Q_3, ... and stops at the first depth where

* the depth is the learned maximum (see below) or the steps left, or
* noop is a legal candidate and some other candidate is strictly better
  than noop (PROST's "reasonable action" test: the estimate already tells
  the actions apart), or
* the caller's deadline has passed or the next level would hold more than
  `max_rows` (state, action) pairs (then the last finished depth counts).

The estimate returned is Q_d scaled from d steps to the steps left, at the
same mean reward per step (x steps / d when undiscounted), as PROST's IDS
does, so that estimates of different depths are on one scale with the
search's own returns.

How: where PROST runs a depth-first search with a state-value cache, this
module searches breadth first, one level per call of the determinised
`Simulator`: every node of a level times every joint action of the table
is one batch (legality by `Simulator.check_actions`, then one `step`), and
the successors are deduplicated (per root) before the next level, which
is what the cache buys PROST. Many roots (the leaves a wave of the search
expands) are searched together in the same batches. Values are backed up
from the deepest level after each level is added, so each depth costs one
simulator call more than the last, not a new search.

Learning (PROST's `initSession`): `learn` runs IDS on training states
(`training_states`: states of random walks from the initial state), each
deepened without the reasonable-action test until `strict_timeout`; the
learned maximum depth is the largest d such that more than half of the
training states finished depth d and their mean time for it is under
`timeout` (the time the caller can spend on one node). When it is below
2, IDS is too slow for this budget: `fallback` is set and `estimate`
returns the depth-1 lookahead (the immediate reward on the determinisation,
scaled to the steps left, PROST's replacement of IDS by its minimal
lookahead); a caller may prefer its own random-walk estimate then.

The weight: PROST's THTS initialises a new action's value as
`weight * estimate`, counted as `initial_visits` visits (PROST's defaults
0.5 and 1); `IDS.weight` carries the first for the caller.

Interface for the search (`planner`, `rollouts`): build `IDS.for_model(model,
timeout=...)` once per session (its `table` is every boolean joint action,
noop first, or None above `enumerate_limit`), call `learn(training_states(sim,
rng), steps=horizon)` once, then for a batch of new leaves
`estimate(states, steps_left, candidates, deadline)` -> one array of Q
estimates per leaf (aligned with its candidates; -inf where illegal; the
weight to apply is `IDS.weight`); `IDS.fallback` says the learned depth was
below 2 (prefer rollouts then). The reward-lock check is `locks.RewardLocks`
(re-exported here).

May call the simulator's public methods, `ippc.planners.determinise` and
`actions.enumerate_boolean`; nothing of the search (`tree`, `planner`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ...rddl.model import Model
from ...rddl.simulator import SimulationError, Simulator, State
from ..determinise import determinise
from .actions import enumerate_boolean
from .locks import RewardLocks
from .rows import row_bytes as _row_bytes

__all__ = ["IDS", "IDSStats", "RewardLocks", "training_states"]

log = logging.getLogger(__name__)

Array = np.ndarray

# PROST's defaults: IDS's timeout per state in the learning phase (the
# budget per node) and strict timeout, THTS's heuristic weight
DEFAULT_TIMEOUT = 0.005
DEFAULT_STRICT_TIMEOUT = 0.1
DEFAULT_WEIGHT = 0.5
DEFAULT_MAX_DEPTH = 15


def _horizon_factor(steps: Array, depth: Array, gamma: float) -> Array:
    """How much a return over `depth` steps is scaled to stand for `steps`
    steps at the same (discounted) mean reward per step."""
    steps = np.asarray(steps, dtype=np.float64)
    depth = np.maximum(np.asarray(depth, dtype=np.float64), 1.0)
    if gamma >= 1.0:
        return steps / depth  # type: ignore[no-any-return]
    return (1.0 - gamma**steps) / (1.0 - gamma**depth)  # type: ignore[no-any-return]


def _take(actions: Mapping[str, Array], rows: Array) -> dict[str, Array]:
    return {k: v[rows] for k, v in actions.items()}


def _stack(states: Sequence[State]) -> State:
    names = list(states[0].values)
    return State({k: np.concatenate([s.values[k] for s in states], axis=0) for k in names})


def _unique_rows(rows: Array) -> tuple[Array, Array]:
    """(the index of the first occurrence of each distinct row, the number
    of the distinct row of every row)."""
    n = rows.shape[0]
    if n == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    packed = np.ascontiguousarray(rows)
    void = (
        packed.view(np.dtype((np.void, packed.shape[1] or 1))).reshape(n)
        if packed.shape[1]
        else np.zeros(n, dtype=np.int64)
    )
    _, first, inverse = np.unique(void, return_index=True, return_inverse=True)
    return first.astype(np.int64), inverse.reshape(n).astype(np.int64)


@dataclass
class _Level:
    """One level of the breadth-first search: its edges (a node of the
    level above, an action, the reward, the node reached) and its nodes."""

    parent: Array  # per edge: the node of the level above (the root at level 1)
    action: Array  # per edge: the action (candidate index at level 1, else table row)
    reward: Array  # per edge
    child: Array  # per edge: the node of this level it reaches
    nodes: State  # the distinct nodes of this level
    root: Array  # per node: its root
    terminal: Array  # per node: the determinised step ended the episode there


@dataclass
class IDSStats:
    """Counters of the IDS calls (per turn, or per session)."""

    calls: int = 0  # roots estimated
    depth_sum: int = 0  # their depths, summed
    sim_rows: int = 0  # (state, action) pairs stepped
    seconds: float = 0.0

    @property
    def mean_depth(self) -> float:
        return self.depth_sum / self.calls if self.calls else 0.0


@dataclass
class IDS:
    """Iterative deepening search on the most-likely determinisation of a
    model (see the module docstring).

    >>> ids = IDS.for_model(model)
    >>> ids.learn(training_states(sim, rng), steps=model.horizon)
    >>> q = ids.estimate(states, [steps_left], [candidates])[0]

    `table` holds the joint actions tried below the root (one array per
    action fluent, rows first; illegal ones are skipped per state); when it
    is None the root's own candidates are tried at every level.
    """

    model: Model
    table: dict[str, Array] | None
    timeout: float = DEFAULT_TIMEOUT
    strict_timeout: float = DEFAULT_STRICT_TIMEOUT
    max_depth: int = DEFAULT_MAX_DEPTH
    max_rows: int = 200_000
    reasonable_action: bool = True
    weight: float = DEFAULT_WEIGHT
    clock: Callable[[], float] = time.perf_counter
    stats: IDSStats = field(default_factory=IDSStats)
    fallback: bool = False
    """Set by `learn` when IDS cannot reach depth 2 within `timeout`:
    `estimate` then looks one step ahead."""
    learned: bool = False

    def __post_init__(self) -> None:
        self.det = Simulator(determinise(self.model))
        self.gamma = 1.0 if self.model.discount is None else float(self.model.discount)
        self._noop = self.det.noop(1)
        self._times: dict[int, list[float]] = {}  # learning: seconds per state, by depth

    @classmethod
    def for_model(cls, model: Model, enumerate_limit: int = 4096, **options: object) -> IDS:
        """An IDS whose table is every boolean joint action of the model
        (at most `enumerate_limit`; else the root's candidates are used)."""
        sim = Simulator(model)
        table = enumerate_boolean(sim, enumerate_limit)
        return cls(model, table, **options)  # type: ignore[arg-type]

    # -- the search ------------------------------------------------------

    def _is_noop(self, actions: Mapping[str, Array]) -> Array:
        n = next(iter(actions.values())).shape[0] if actions else 1
        out = np.ones(n, dtype=bool)
        for k, d in self._noop.items():
            a = np.asarray(actions[k])
            out &= (a.reshape(n, int(np.prod(a.shape[1:]))) == d.reshape(1, -1)).all(axis=1)
        return out

    def _expand(
        self, nodes: State, node_idx: Array, act_idx: Array, acts: dict[str, Array]
    ) -> tuple[Array, Array, Array, State, Array]:
        """Step the legal ones of the (node, action) pairs given: (their
        nodes, their actions, rewards, successor states, done flags)."""
        states = nodes[node_idx]
        legal = self.det.check_actions(states, acts)
        if not legal.all():
            keep = np.flatnonzero(legal)
            node_idx, act_idx = node_idx[keep], act_idx[keep]
            states = states[keep]
            acts = _take(acts, keep)
        if len(node_idx) == 0:
            return node_idx, act_idx, np.zeros(0), states, np.zeros(0, dtype=bool)
        out = self.det.step(states, acts, None, check=False)  # type: ignore[arg-type]
        self.stats.sim_rows += len(node_idx)
        return node_idx, act_idx, out.reward, out.next_state, out.done

    def _dedupe(self, root: Array, nxt: State, done: Array) -> tuple[Array, State, Array, Array]:
        """(the node of each successor, the distinct nodes, their roots,
        their terminal flags), distinct per root."""
        n = nxt.batch
        key = np.concatenate(
            [
                root.astype(np.int64).reshape(n, 1).view(np.uint8),
                done.reshape(n, 1).view(np.uint8),
                _row_bytes(nxt.values, n),
            ],
            axis=1,
        )
        first, inverse = _unique_rows(key)
        return inverse, nxt[first], root[first], done[first]

    def _root_q(self, levels: list[_Level], n_roots_cands: int, steps_after: list[Array]) -> Array:
        """The depth-len(levels) value of every root candidate (flat over the
        roots' candidates; -inf where illegal)."""
        gamma = self.gamma
        value: Array | None = None  # of the nodes of the level below
        for depth in range(len(levels), 0, -1):
            lv = levels[depth - 1]
            n_nodes = lv.nodes.batch
            # the value of this level's nodes with (len(levels) - depth) steps to look
            if value is None:
                node_value = np.zeros(n_nodes)
            else:
                node_value = value
            node_value = np.where(lv.terminal | (steps_after[depth - 1] <= 0), 0.0, node_value)
            q = lv.reward + gamma * node_value[lv.child]
            if depth == 1:
                out = np.full(n_roots_cands, -np.inf)
                out[lv.parent] = q  # at level 1 `parent` is the flat candidate index
                return out
            above = levels[depth - 2].nodes.batch
            v = np.full(above, -np.inf)
            np.maximum.at(v, lv.parent, q)
            # a node with no legal action is a dead end of the search: 0 from there
            value = np.where(np.isfinite(v), v, 0.0)
        raise AssertionError("no levels")

    def estimate(
        self,
        states: State,
        steps_left: Sequence[int],
        candidates: Sequence[Mapping[str, Array]],
        deadline: float | None = None,
        learning: bool = False,
    ) -> list[Array]:
        """Q-value estimates of every candidate of every root.

        `states` holds one state per root (batch = number of roots),
        `steps_left` the steps left in each, `candidates` each root's
        candidate joint actions (one array per action fluent, rows first).
        Returns one array per root, one value per candidate (-inf where
        the candidate is illegal), scaled to the root's steps left. Stops
        deepening once `deadline` (of `clock`) has passed."""
        started = self.clock()
        n_roots = states.batch
        steps = np.asarray(steps_left, dtype=np.int64)
        sizes = np.array([next(iter(c.values())).shape[0] if c else 1 for c in candidates])
        offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        flat_cands = (
            {k: np.concatenate([np.asarray(c[k]) for c in candidates], axis=0) for k in self._noop}
            if n_roots
            else {}
        )
        cand_root = np.repeat(np.arange(n_roots), sizes)
        noop_cand = self._is_noop(flat_cands) if n_roots else np.zeros(0, dtype=bool)
        max_depth = 1 if self.fallback else self.max_depth
        target = np.minimum(steps, max_depth)
        target = np.maximum(target, 1)

        # level 1: every root with every candidate
        node_idx, act_idx, reward, nxt, done = self._expand(
            states, cand_root, np.arange(len(cand_root)), flat_cands
        )
        child, nodes, node_root, terminal = self._dedupe(cand_root[act_idx], nxt, done)
        levels = [_Level(act_idx, act_idx, reward, child, nodes, node_root, terminal)]
        steps_after = [steps[node_root] - 1]
        q = self._root_q(levels, len(cand_root), steps_after)
        result = q.copy()
        depth_of = np.ones(n_roots, dtype=np.int64)
        active = target > 1
        if self.table is None:
            table_size = 0
        else:
            table_size = next(iter(self.table.values())).shape[0] if self.table else 1

        depth = 1
        while active.any():
            if deadline is not None and self.clock() >= deadline:
                break
            if learning and (self.clock() - started) / n_roots > self.strict_timeout:
                break
            lv = levels[-1]
            grow = active[lv.root] & ~lv.terminal & (steps_after[-1] > 0)
            sel = np.flatnonzero(grow)
            if self.table is not None:
                per_node = np.full(len(sel), table_size)
            else:
                per_node = sizes[lv.root[sel]]
            if int(per_node.sum()) > self.max_rows:
                break
            depth += 1
            if self.table is not None:
                ni = np.repeat(sel, table_size)
                ai = np.tile(np.arange(table_size), len(sel))
                acts = _take(self.table, ai)
            else:
                # the root's own candidates at every level
                roots = lv.root[sel]
                ni = np.repeat(sel, sizes[roots])
                ai = np.concatenate(
                    [np.zeros(0, dtype=np.int64)]
                    + [np.arange(offsets[r], offsets[r + 1]) for r in roots.tolist()]
                )
                acts = _take(flat_cands, ai)
            node_idx, act_idx, reward, nxt, done = self._expand(lv.nodes, ni, ai, acts)
            child, nodes, node_root, terminal = self._dedupe(lv.root[node_idx], nxt, done)
            levels.append(_Level(node_idx, act_idx, reward, child, nodes, node_root, terminal))
            steps_after.append(steps[node_root] - depth)
            q = self._root_q(levels, len(cand_root), steps_after)
            # roots still deepening take this depth's values
            took = active[cand_root]
            result[took] = q[took]
            depth_of[active] = depth
            if learning:
                per_root = (self.clock() - started) / n_roots
                self._times.setdefault(depth, []).extend([per_root] * n_roots)
            done_now = depth >= target
            if self.reasonable_action and not learning:
                for r in np.flatnonzero(active & ~done_now).tolist():
                    lo, hi = offsets[r], offsets[r + 1]
                    block = result[lo:hi]
                    noop = noop_cand[lo:hi] & np.isfinite(block)
                    if noop.any():
                        base = block[noop].max()
                        if (block[~noop] > base + 1e-9 * max(1.0, abs(base))).any():
                            done_now[r] = True
            active &= ~done_now

        # scale to the steps left
        factor = _horizon_factor(steps[cand_root], depth_of[cand_root], self.gamma)
        with np.errstate(invalid="ignore"):
            scaled = np.where(np.isfinite(result), result * factor, result)
        self.stats.calls += n_roots
        self.stats.depth_sum += int(depth_of.sum())
        self.stats.seconds += self.clock() - started
        return [scaled[offsets[r] : offsets[r + 1]] for r in range(n_roots)]

    # -- learning ----------------------------------------------------------

    def legal_table(self, state: State) -> dict[str, Array]:
        """The table's joint actions that are legal in `state` (one state)."""
        if self.table is None:
            return self.det.legal_actions(state)
        n = next(iter(self.table.values())).shape[0]
        ok = self.det.check_actions(state[np.zeros(n, dtype=np.int64)], self.table)
        return _take(self.table, np.flatnonzero(ok))

    def learn(self, states: State, steps: int, batch: int = 1) -> int:
        """PROST's learning phase: the largest depth whose mean time per
        state over the training `states` is under `timeout` and which more
        than half of them finished (each deepened to `max_depth`, `steps`
        steps left, stopped at `strict_timeout` per state). With `batch` >
        1 the states are searched that many at once, as a search that
        expands a wave of leaves together calls `estimate`, and each is
        charged the group's time over its size. Sets and returns
        `max_depth`; sets `fallback` when it is below 2."""
        self._times = {}
        n = states.batch
        cap = min(self.max_depth, max(1, steps))
        self.max_depth = cap
        self.fallback = False
        group: list[tuple[State, dict[str, Array]]] = []
        for i in range(n):
            s = states[i]
            try:
                cands = self.legal_table(s)
            except Exception as err:  # noqa: BLE001 - a state with nothing legal
                log.debug("ids: training state %d skipped: %s", i, err)
                continue
            if not cands or next(iter(cands.values())).shape[0] == 0:
                continue
            group.append((s, cands))
            if len(group) >= batch or i == n - 1:
                k = len(group)
                self.estimate(
                    _stack([g[0] for g in group]), [cap] * k, [g[1] for g in group], learning=True
                )
                group = []
        if group:
            k = len(group)
            self.estimate(
                _stack([g[0] for g in group]), [cap] * k, [g[1] for g in group], learning=True
            )
        learned = 1
        for d in range(2, cap + 1):
            times = self._times.get(d, [])
            if len(times) <= n // 2:
                break
            if sum(times) / len(times) >= self.timeout:
                break
            learned = d
        self.max_depth = learned
        self.fallback = learned < 2
        self.learned = True
        log.info(
            "ids: %s: learned max depth %d from %d training states (timeout %.4f s)%s",
            self.model.name,
            learned,
            n,
            self.timeout,
            "; too slow, one-step lookahead instead" if self.fallback else "",
        )
        return learned


def training_states(
    sim: Simulator, rng: np.random.Generator, count: int = 20, walk: int | None = None
) -> State:
    """`count` states of random walks from the initial state (rddlsim-style
    random actions), as PROST's training set: each walk goes a uniform
    number of steps below the horizon (or `walk`)."""
    horizon = int(sim.model.horizon or 40) if walk is None else walk
    out: list[State] = []
    for _ in range(count):
        s = sim.initial_state(1)
        for _ in range(int(rng.integers(0, max(1, horizon)))):
            try:
                acts = sim.random_actions(s, rng)
                step = sim.step(s, acts, rng, check=False)
            except SimulationError:
                break
            if bool(step.done[0]):
                break
            s = step.next_state
        out.append(s)
    return _stack(out)
