"""A reference of the thts engine's search in Python, for the tests only.

The planner's search is written once, in C (planners/mcts/csrc/tree.c; the
module docstring of `ippc.planners.mcts.thts` describes it). This module
is the same algorithm from that description, transcribed over the Python
one-state step (`ScalarStep.step`) with Python's generators: the tests
check both against `exact` and against each other where they must agree
(the exact last step, solved labelling, sinks, IDS values, pruned
equivalent actions), so that a change to the C tree has a readable
statement to be held to. It is not the planner's fallback: without a C
step a session runs the wave engine (docs/architecture.md, "mcts: one
search engine").

`ReferencePlanner` is mcts with this search in place of the C tree
(`planner_on(..., compiled="no")` in test_mcts_thts.py). Left out of the
C tree's features: the C legal-action walk (the chooser's candidates
serve) and the start-up budgets.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import random
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from ippc.planners.base import SessionInfo
from ippc.planners.mcts.actions import ActionChooser, state_dependent
from ippc.planners.mcts.heuristic import training_states
from ippc.planners.mcts.options import Settings
from ippc.planners.mcts.planner import MCTSPlanner
from ippc.planners.mcts.stats import SearchStats
from ippc.planners.mcts.thts import TNode
from ippc.rddl.sim.scalar import ScalarStep
from ippc.rddl.simulator import Simulator

log = logging.getLogger(__name__)

StateT = tuple[Any, ...]
ActT = tuple[Any, ...]


class _Draw:
    """A fixed draw that records what the step does with it: a uniform the
    probability it is compared with (`u < p`), a normal the factor it is
    scaled by (kept apart from probabilities as that factor plus 2)."""

    __slots__ = ("v", "log")

    def __init__(self, v: float, record: list[float]):
        self.v = v
        self.log = record

    def __lt__(self, p: float) -> bool:
        self.log.append(float(p))
        return self.v < p

    def __gt__(self, p: float) -> bool:  # (p < u, written the other way round)
        self.log.append(float(p))
        return self.v > p

    def __rmul__(self, x: float) -> float:
        self.log.append(float(x) + 2.0)
        return x * self.v

    __mul__ = __rmul__


class _Draws:
    __slots__ = ("items",)

    def __init__(self, items: list[Any]):
        self.items = items

    def tolist(self) -> list[Any]:
        return self.items


class _Fixed:
    """A stand-in for the numpy generator `ScalarStep.step` draws from:
    the same draws at every call (made once, as many as asked for)."""

    def __init__(
        self, uniforms: Callable[[int], list[Any]], normals: Callable[[int], list[Any]]
    ) -> None:
        self._u = _Draws([])
        self._z = _Draws([])
        self._more = (uniforms, normals)

    def random(self, n: int) -> _Draws:
        return self._grow(self._u, n, self._more[0])

    def standard_normal(self, n: int) -> _Draws:
        return self._grow(self._z, n, self._more[1])

    @staticmethod
    def _grow(draws: _Draws, n: int, more: Callable[[int], list[Any]]) -> _Draws:
        if len(draws.items) < n:
            draws.items.extend(more(n - len(draws.items)))
        return draws


class _Probe(_Fixed):
    """Fixed draws from a seeded generator that record every probability
    and standard deviation the step uses (`log`)."""

    def __init__(self, rng: np.random.Generator):
        self.log: list[float] = []
        log_ = self.log
        super().__init__(
            lambda k: [_Draw(u, log_) for u in rng.random(k).tolist()],
            lambda k: [_Draw(z, log_) for z in rng.standard_normal(k).tolist()],
        )


def _likely() -> _Fixed:
    """The draws of the most-likely determinisation: every uniform 0.5 (a
    Bernoulli is true exactly when its probability is above a half; a
    Discrete takes the case where its cumulative probability passes a half,
    its median) and every normal 0 (its mean)."""
    return _Fixed(lambda k: [0.5] * k, lambda k: [0.0] * k)


def _deterministic(record: list[float]) -> bool:
    """Whether every probability recorded is 0 or 1 and every standard
    deviation 0 (the draws decided nothing)."""
    for p in record:
        if p >= 2.0:
            if p != 2.0:
                return False
        elif 0.0 < p < 1.0:
            return False
    return True


class _Stop(Exception):
    """The deadline came during an expansion."""


class THTS:
    """The search of one session (see the module docstring)."""

    def __init__(
        self,
        sim: Simulator,
        scalar: ScalarStep,
        chooser: ActionChooser,
        settings: Settings,
        rng: np.random.Generator,
        gamma: float,
    ) -> None:
        self.sim = sim
        self.fast = scalar
        self.chooser = chooser
        self.st = settings
        self.rng = rng
        self.py = random.Random(int(rng.integers(0, 2**63 - 1)))
        self.gamma = gamma
        self.table: dict[int, dict[StateT, TNode]] = {}
        self._tuples: dict[int, ActT] = {}
        probe_rng = np.random.default_rng(int(rng.integers(0, 2**63 - 1)))
        self.probes = (_Probe(probe_rng), _Probe(probe_rng))
        dom = sim.model.domain
        constraints = [*dom.action_preconditions, *dom.state_action_constraints]
        self._static = not state_dependent(sim.model, constraints)
        self._static_rows: list[int] | None = None
        pool = chooser.pool
        self.pool: list[ActT] | None = (
            None if pool is None else [self._tuple(int(r)) for r in pool.tolist()]
        )
        self.likely = _likely()
        self.ids_depth = 0  # 0: no IDS (roll-outs); set by `learn_ids`
        self._ids_cache: dict[tuple[int, StateT], float] = {}
        self.deadline: float | None = None
        self.piece = 0.0  # the slowest recent trial (decaying)
        self.turn = SearchStats()
        self._sunk = False  # a sink was met this session (see `_ids_values`)

    # -- actions -------------------------------------------------------------

    def _tuple(self, row: int) -> ActT:
        t = self._tuples.get(row)
        if t is None:
            t = self._tuples[row] = self.fast.encode_actions(self.chooser.lib.take(np.array([row])))
        return t

    def _candidates(self, state: StateT) -> list[int]:
        if self._static and self._static_rows is not None:
            return self._static_rows
        rows = self.chooser.candidates([self.fast.decode_state(state)])[0].tolist()
        if self._static:
            self._static_rows = rows
        return rows

    # -- the turn --------------------------------------------------------------

    def start_round(self) -> None:
        self.table = {}

    def root(self, state: StateT, steps: int) -> TNode:
        """The node of the observed state (the table's, with what was
        searched below it, else a new one); deeper buckets are dropped."""
        for k in [k for k in self.table if k > steps]:
            del self.table[k]
        if sum(len(b) for b in self.table.values()) > self.st.max_nodes:
            self.table = {}
        return self._node(state, steps, False)

    def _node(self, state: StateT, steps: int, done: bool) -> TNode:
        bucket = self.table.get(steps)
        if bucket is None:
            bucket = self.table[steps] = {}
        node = bucket.get(state)
        if node is None:
            node = bucket[state] = TNode(state, steps, done)
        return node

    def search(
        self, root: TNode, deadline: float | None, iterations: int | None, turn: SearchStats
    ) -> None:
        """Trials from `root` until the deadline (or exactly `iterations`)."""
        self.turn = turn
        self.deadline = deadline
        if not root.expanded and not root.solved:
            self._expand(root, root=True)  # always completes
        self.piece = 0.0
        done = 0
        clock = time.monotonic
        while not root.solved:
            if iterations is not None:
                if done >= iterations:
                    break
            elif deadline is not None and clock() + self.piece >= deadline:
                break
            t0 = clock()
            try:
                self._trial(root)
            except _Stop:
                break
            done += 1
            took = clock() - t0
            self.piece = max(took, 0.8 * self.piece)
        turn.trials += done
        self.refresh(root)

    def best(self, root: TNode) -> int:
        """The index of the action to play: the best value, then the most
        samples, then the first (noop first)."""
        if not root.q:
            return -1
        top = max(root.q)
        cands = [a for a, v in enumerate(root.q) if v >= top - 1e-9 * max(1.0, abs(top))]
        return max(cands, key=lambda a: (root.n[a], -a))

    # -- trials ----------------------------------------------------------------

    def _trial(self, root: TNode) -> None:
        path: list[tuple[TNode, int, list[Any]]] = []
        node = root
        step = self.fast.step
        rng = self.rng
        turn = self.turn
        while not node.solved:
            if not node.expanded:
                self._expand(node)
                break
            a = self._select(node)
            nxt, r, done = step(node.state, node.acts[a], rng)
            turn.sim_steps += 1
            outs = node.outs[a]
            out = outs.get(nxt)
            if out is None:
                out = outs[nxt] = [self._node(nxt, node.steps - 1, done), 0, 0.0, 0.0]
            out[1] += 1
            out[2] += r
            path.append((node, a, out))
            node = out[0]
        gamma = self.gamma
        limit = self.st.bellman_outcomes
        for node, a, out in reversed(path):
            child = out[0]
            node.n[a] += 1
            node.visits += 1
            outs = node.outs[a]
            if len(outs) <= limit:
                node.tot[a] = self._total(outs)
            else:
                c = out[2] + gamma * out[1] * child.value
                node.tot[a] += c - out[3]
                out[3] = c
            self._update(node, a, out)

    def _total(self, outs: dict[StateT, list[Any]]) -> float:
        """An action's outcomes' rewards and current values, weighted by
        their counts (each outcome keeps its share for the incremental
        backup)."""
        gamma = self.gamma
        tot = 0.0
        for o in outs.values():
            c = o[2] + gamma * o[1] * o[0].value
            o[3] = c
            tot += c
        return tot

    def _update(self, node: TNode, a: int, out: list[Any] | None) -> None:
        """The action's value from its statistics, then the node's."""
        if node.det[a] and out is not None and out[0].solved:
            node.asolved[a] = True
            node.q[a] = out[2] / out[1] + self.gamma * out[0].value
        elif not node.asolved[a]:
            w = self.st.init_weight
            node.q[a] = (w * node.h[a] + node.tot[a]) / (w + node.n[a])
        node.value = max(node.q)
        if node.asolved[a] and all(node.asolved):
            node.solved = True

    def refresh(self, node: TNode) -> None:
        """Every action of `node` from its outcomes' current values (before
        the choice: a value below may have changed through another path)."""
        for a, outs in enumerate(node.outs):
            if node.asolved[a] or not outs:
                continue
            node.tot[a] = self._total(outs)
            self._update(node, a, next(iter(outs.values())) if node.det[a] else None)

    def _select(self, node: TNode) -> int:
        """UCB1 over the unsolved actions, the exploration scaled by the
        node's largest |Q|."""
        q = node.q
        n = node.n
        w = self.st.init_weight
        scale = max(abs(max(q)), abs(min(q))) or 1.0
        c = self.st.exploration * scale
        logn = math.log(node.visits + w * len(q) + 1.0)
        best = -math.inf
        pick = -1
        ties = 0
        solved = node.asolved
        for a in range(len(q)):
            if solved[a]:
                continue
            v = q[a] + c * math.sqrt(logn / (w + n[a]))
            if v > best:
                best = v
                pick = a
                ties = 1
            elif v == best:
                ties += 1
                if self.py.random() * ties < 1.0:
                    pick = a
        return pick

    # -- expansion -------------------------------------------------------------

    def _check(self) -> None:
        if self.deadline is not None and time.monotonic() >= self.deadline:
            raise _Stop

    def _probe(self, state: StateT, act: ActT) -> tuple[Any, ...]:
        """(deterministic, signature, successor, reward, done) of an action
        under the two probes (see the module docstring)."""
        step = self.fast.step
        p, q = self.probes
        p.log.clear()
        q.log.clear()
        s1, r1, d1 = step(state, act, p)  # type: ignore[arg-type]
        self.turn.sim_steps += 1
        if _deterministic(p.log):
            # the draws decided nothing: this is the one successor
            return True, (tuple(p.log), s1, r1, d1), s1, r1, d1, True
        s2, r2, d2 = step(state, act, q)  # type: ignore[arg-type]
        self.turn.sim_steps += 1
        sig = (tuple(p.log), tuple(q.log), s1, r1, d1, s2, r2, d2)
        return False, sig, s1, r1, d1, r1 == r2

    def _expand(self, node: TNode, root: bool = False) -> None:
        """Probe, prune and first values of a new node's actions. At the
        deadline a node other than the root is left unexpanded (`_Stop`);
        the root's actions not valued yet get their reward times the steps
        left instead."""
        turn = self.turn
        state = node.state
        rows = self._candidates(state)
        seen: set[tuple[Any, ...]] = set()
        kept: list[tuple[int, ActT, bool, StateT, float, bool, bool]] = []
        whole = True  # every candidate probed
        for i, row in enumerate(rows):
            if i & 31 == 31 and self.deadline is not None and time.monotonic() >= self.deadline:
                # (hundreds of candidates: TriangleTireworld #5 has 813) a node
                # other than the root is left for a later trial; the root keeps
                # the actions probed so far (noop first)
                if not root:
                    raise _Stop
                whole = False
                break
            act = self._tuple(row)
            det, sig, s1, r1, d1, same_r = self._probe(state, act)
            if det:  # only deterministic actions merge (see ippc_probe)
                if sig in seen:
                    continue
                seen.add(sig)
            kept.append((row, act, det, s1, r1, d1, same_r))
        h: list[float] = []
        asolved: list[bool] = []
        gamma = self.gamma
        late = False
        if whole and self._sink(node, kept):
            return
        if self.ids_depth and node.steps > 1:
            try:
                # (the root's IDS always finishes: valuing its actions by their
                # reward alone lost AcademicAdvising, where every course costs
                # now and pays only at graduation)
                ids = self._ids_values(node, kept, check=not root)
            except _Stop:
                if not root:
                    raise
                ids, late = None, True
            if ids is not None:
                self._set_expanded(node, kept, ids, [False] * len(kept))
                turn.ids_leaves += 1
                return
        for _row, act, det, s1, r1, d1, same_r in kept:
            if node.steps == 1 or (det and d1):
                h.append(r1)
                asolved.append(same_r if not det else True)
                continue
            if not late and self.deadline is not None and time.monotonic() >= self.deadline:
                if not root:
                    raise _Stop
                late = True
            if late:
                h.append(r1 * self._horizon(node.steps))
                asolved.append(False)
                continue
            if det:
                nxt, r, done = s1, r1, d1
            else:
                nxt, r, done = self.fast.step(state, act, self.rng)
                turn.sim_steps += 1
            value = 0.0 if done else self._rollout(nxt, node.steps - 1)
            h.append(r + gamma * value)
            asolved.append(False)
        self._set_expanded(node, kept, h, asolved)

    def _sink(self, node: TNode, kept: list[Any]) -> bool:
        """Solve a sink at once: every kept action deterministic, none
        ending the run, each leaving the state as it is. Nothing can change
        the state again, so each action is worth its reward plus the best
        reward every step after."""
        if not kept or not all(k[2] and not k[5] and k[3] == node.state for k in kept):
            return False
        best = max(k[4] for k in kept)
        rest = best * self._horizon(node.steps - 1) if node.steps > 1 else 0.0
        self._set_expanded(node, kept, [k[4] + self.gamma * rest for k in kept], [True] * len(kept))
        self.turn.locks += 1
        self._sunk = True
        return True

    def _horizon(self, steps: int) -> float:
        """The discounted number of steps in `steps`."""
        g = self.gamma
        return float(steps) if g == 1.0 else (1.0 - g**steps) / (1.0 - g)

    def _set_expanded(
        self, node: TNode, kept: list[Any], h: list[float], asolved: list[bool]
    ) -> None:
        node.rows = [k[0] for k in kept]
        node.acts = [k[1] for k in kept]
        node.det = [k[2] for k in kept]
        node.h = h
        node.q = list(h)
        node.n = [0] * len(kept)
        node.tot = [0.0] * len(kept)
        node.outs = [{} for _ in kept]
        node.asolved = asolved
        node.expanded = True
        self.turn.leaves += 1
        if not kept:  # a dead end: nothing legal
            node.solved = True
            node.value = 0.0
            return
        node.value = max(h)
        node.solved = all(asolved)

    # -- IDS on the most-likely determinisation ---------------------------------

    def _ids_values(self, node: TNode, kept: list[Any], check: bool = True) -> list[float] | None:
        """PROST's IDS estimate of each kept action (None where it values
        them all alike, roll-outs then, unless the session met a sink: then
        times `blind_weight` instead; None too with `blind_future` where every
        action but noop costs more now than noop and the values differ only by
        that first step's reward): its reward plus the depth-(d-1)
        value of its successor on the most-likely determinisation, scaled to
        the steps left at the same reward a step, times `heuristic_weight`."""
        steps = node.steps
        upto = min(self.ids_depth, steps)
        # PROST's IDS: deepen from 2 and stop at the first depth where an action
        # beats noop (when noop is a kept action), else search at the depth learned
        noop_k = -1
        if self.st.ids_deepen and upto > 2:
            noop_k = next((i for i, k in enumerate(kept) if k[1] == self.fast.noop), -1)
        d = 2 if noop_k >= 0 else upto
        while True:
            out = self._ids_at(node.state, kept, d, check)
            if d >= upto or any(v > out[noop_k] for i, v in enumerate(out) if i != noop_k):
                break
            d += 1
        future_alike = False
        noop_at = -1
        if self.st.blind_future and d >= 2 and len(out) > 1:
            noop_at = next((i for i, k in enumerate(kept) if k[1] == self.fast.noop), -1)
        if noop_at >= 0:
            # blind too where every action but noop costs more now than noop and
            # the values differ only by that first step's reward (see ctree's expand)
            first = self._ids_at(node.state, kept, 1, check)
            futures = [v - r for v, r in zip(out, first, strict=True)]
            tol = 1e-9 * (1.0 + abs(futures[noop_at]))
            future_alike = all(
                abs(f - futures[noop_at]) <= tol and r < first[noop_at] - tol
                for i, (f, r) in enumerate(zip(futures, first, strict=True))
                if i != noop_at
            )
        if self.st.ids_smooth and d >= 3:
            # the mean of the depth-d and depth-(d-1) values a step (see ctree's expand;
            # not at depth 2, whose partner would be the immediate reward alone)
            less = self._ids_at(node.state, kept, d - 1, check)
            f = d / (d - 1.0) if self.gamma == 1.0 else 1.0
            out = [0.5 * (v + w * f) for v, w in zip(out, less, strict=True)]
        weight = self.st.heuristic_weight
        if future_alike and max(out) != min(out):
            return None  # roll-outs, even once a sink was met (see ctree's expand)
        if max(out) == min(out) and len(out) > 1:
            if not self._sunk or self.st.blind_weight <= 0:
                return None
            weight = self.st.blind_weight  # a blind estimate, once a sink was met
        scale = weight * (steps / d if self.gamma == 1.0 else 1.0)
        return [v * scale for v in out]

    def _ids_at(self, state: StateT, kept: list[Any], d: int, check: bool) -> list[float]:
        """The kept actions' depth-`d` IDS values (unscaled)."""
        out = []
        step = self.fast.step
        for _, act, _, _, _, _, _ in kept:
            if check:
                self._check()
            nxt, r, done = step(state, act, self.likely)  # type: ignore[arg-type]
            self.turn.sim_steps += 1
            out.append(r if done or d <= 1 else r + self.gamma * self._ids(nxt, d - 1))
        return out

    def _ids(self, state: StateT, depth: int) -> float:
        """The best depth-`depth` return from `state` on the determinisation
        (cached for the session)."""
        key = (depth, state)
        cache = self._ids_cache
        v = cache.get(key)
        if v is not None:
            return v
        step = self.fast.step
        best = -math.inf
        seen: set[tuple[StateT, float]] = set()
        for row in self._candidates(state):
            nxt, r, done = step(state, self._tuple(row), self.likely)  # type: ignore[arg-type]
            self.turn.sim_steps += 1
            if (nxt, r) in seen:
                continue
            seen.add((nxt, r))
            if not done and depth > 1:
                r += self.gamma * self._ids(nxt, depth - 1)
            if r > best:
                best = r
        if best == -math.inf:
            best = 0.0
        if len(cache) > 500_000:
            cache.clear()
        cache[key] = best
        return best

    def learn_ids(self, states: list[StateT], steps: int, timeout: float) -> int:
        """The deepest IDS depth (at most `steps`, at most 15) whose search
        takes at most `timeout` seconds of CPU time a state on average over
        `states` (0 when not even depth 2 does)."""
        depth = 0
        for s in states:
            self._candidates(s)
        for d in range(2, min(15, steps) + 1):
            self._ids_cache.clear()
            t0 = time.process_time()
            for s in states:
                for row in self._candidates(s):
                    act = self._tuple(row)
                    nxt, r, done = self.fast.step(s, act, self.likely)  # type: ignore[arg-type]
                    if not done:
                        self._ids(nxt, d - 1)
            took = (time.process_time() - t0) / max(1, len(states))
            if took > timeout:
                break
            depth = d
        self._ids_cache.clear()
        self.ids_depth = depth
        return depth

    def _rollout(self, state: StateT, steps: int) -> float:
        """A roll-out's return from `state` with `steps` left (see the module
        docstring)."""
        policy = self.st.rollout_policy
        if policy == "noop":
            return self._walk(state, steps, None)
        if policy == "random":
            return self._walk(state, steps, self.pool)
        return max(self._walk(state, steps, None), self._walk(state, steps, self.pool))

    def _walk(self, state: StateT, steps: int, pool: list[ActT] | None) -> float:
        depth = self.st.rollout_depth
        n = steps if depth == 0 else min(depth, steps)
        g = self.gamma
        step = self.fast.step
        rng = self.rng
        noop = self.fast.noop
        choose: Callable[[], ActT] | None = None
        if pool is not None and pool:
            pick = self.py.randrange
            size = len(pool)

            def choose() -> ActT:
                return pool[pick(size)]

        total = 0.0
        disc = 1.0
        taken = 0
        for _ in range(n):
            act = noop if choose is None else choose()
            state, r, done = step(state, act, rng)
            total += disc * r
            disc *= g
            taken += 1
            if done:
                self.turn.sim_steps += taken
                return total
        self.turn.sim_steps += taken
        if taken < steps and taken > 0 and self.st.extrapolate:
            return self._extrapolate(total, taken, steps)
        return total

    def _extrapolate(self, total: float, taken: int, steps: int) -> float:
        """A roll-out's return over `taken` steps as its mean discounted
        reward a step over all the `steps` left."""
        g = self.gamma
        if g == 1.0:
            return total * steps / taken
        full = (1.0 - g**steps) / (1.0 - g)
        part = (1.0 - g**taken) / (1.0 - g)
        return total * full / part


class ReferencePlanner(MCTSPlanner):
    """mcts with the reference search (`THTS` above) in place of the C tree:
    the same chooser (8 x max_actions, the left-out groundings) and IDS's
    depth (fixed, or learned by the Python IDS)."""

    def _start_thts(  # type: ignore[override]
        self, session: SessionInfo, scalar: ScalarStep, seed: int | None
    ) -> THTS:
        st = self.settings
        sim = session.simulator
        chooser = ActionChooser(
            sim,
            dataclasses.replace(st, max_actions=8 * st.max_actions),
            self.rng,
            inert=self._skipped(session, scalar),
        )
        self._chooser = chooser
        search = THTS(sim, scalar, chooser, st, self.rng, self._discount())
        if st.heuristic == "ids":
            fixed = st.ids_depth or (5 if st.iterations is not None else 0)
            if fixed:
                search.ids_depth = fixed
            else:
                rng = np.random.default_rng(None if seed is None else [seed, 1])
                train = training_states(sim, rng)
                states = [scalar.encode_state(train, i) for i in range(min(train.batch, 16))]
                search.learn_ids(states, session.model.horizon or 40, st.ids_timeout)
        return search
