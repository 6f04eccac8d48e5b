"""`THTS`: the single-state trial-based heuristic tree search of `mcts`
(option `engine = thts`), on the grounded one-state step of
`ippc.rddl.sim.scalar` (`ScalarStep`).

One trial at a time, as in Keller & Helmert 2013 and PROST:

* A *decision node* (`TNode`) is a state (the step's tuple of scalars)
  with the steps left; all nodes live in a transposition table keyed by
  (steps left, state), kept across trials and across the turns of a round,
  so the observed state's node is the next root with what was learnt below.
* A trial descends from the root: at an expanded node it picks an action
  by UCB1 among the actions not solved yet, samples one successor of it
  through `ScalarStep.step` (a *chance node* is the action's dict of sampled
  outcomes with their counts and rewards), and goes on until it reaches a
  node not expanded yet (which it expands, PROST's one new decision node a
  trial), a solved node, or the end of the lookahead. The values are then
  backed up along the path, MaxMonteCarlo: a decision node is worth its
  best action, an action its first estimate (as `init_weight` visits)
  averaged with its outcomes' rewards and current values, weighted by
  their sample counts; an action with at most `bellman_outcomes` outcomes
  reads all of them afresh at each backup (a partial Bellman backup: with
  transpositions a node's value also changes through other paths).
* *Expansion* probes every candidate action once with two recording draw
  generators (`_Probe`): the generated step compares each uniform draw
  with its probability (`u < p`) and multiplies each normal draw by its
  standard deviation, and the probe records these. An action all of whose
  probabilities are 0 or 1 (and standard deviations 0) is *deterministic*:
  its one successor is known. Two actions with the same records and the
  same successors and rewards under both probes are *equivalent* (the same
  probabilities at every draw the step makes: the same successor
  distribution and reward): only the first (noop first) is kept. With one
  step left, an action's value is its reward, exact when both probes give
  the same reward (the last step is evaluated, not sampled, and solved).
  Otherwise each kept action gets a first estimate: its reward plus the
  discounted value of a roll-out (`rollout_policy`: random legal-at-start
  joint actions, noop, or both with the better counting) of up to
  `rollout_depth` steps from a sampled successor (from the known one when
  deterministic), cut short ones extrapolated over the steps left as the
  wave search does.
* *Solved labelling*: a node with no steps left or terminal is solved at
  0; a deterministic action whose successor is solved is solved (its value
  exact); a node whose actions are all solved is solved; trials never
  descend into solved actions, and a solved root ends the turn's search.
  With `reward_locks`, a new node where the reward can no longer change is
  solved at once (`heuristic.RewardLocks`).
* *Sinks*: a new node whose kept actions are all deterministic, none
  ending the run, each leaving the state as it is, never leaves it: it is
  solved at once, each action at its reward plus the best reward every
  step after (`_sink`). Once the session has met one, a node whose IDS
  values are all alike takes them, times `blind_weight`, instead of
  roll-outs, so that a blind estimate ranks above an exact sink.
* *Time*: the turn ends at its deadline less the slowest recent trial
  (a decaying maximum), checked between trials and between the actions of
  an expansion, so a turn ends within about one trial's time of its
  budget; with `iterations` exactly that many trials run (a seed then gives
  the same search on any machine). The root is always expanded: its IDS
  finishes, its probing stops at the deadline with the actions probed so
  far, and its actions not valued by then get their reward times the steps
  left.

The action draws of roll-outs and UCB1's tie-breaks use a Python
`random.Random` seeded from the planner's generator, and the step's draws
the planner's numpy generator: the same seed gives the same search.

With the compiled step and kernels (`ckernels.Kernels`, option `compiled`), the
probing, roll-outs, sampled steps and, for static candidates, IDS run in C
(`_cprobe`, `_cids`, `_walk`), the draws then from the C generator seeded
from the planner's; and `ctree.attach` moves the trials themselves into C
(`planners/mcts/ctree.py`, the same search node for node), after which
`root`, `search` and `start_round` hand over to it. This Python tree then
runs only without a compiler, with `compiled = no`, or with `reward_locks`.

Imports the scalar step, the tree-independent parts of the package
(`actions`, `heuristic`'s reward locks, `options`, `stats`).
"""

from __future__ import annotations

import itertools
import logging
import math
import random
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ...rddl.sim.scalar import ScalarStep
from ...rddl.simulator import Simulator
from .actions import ActionChooser, state_dependent
from .ckernels import Kernels
from .heuristic import RewardLocks
from .options import Settings
from .relevance import downward_closed
from .stats import SearchStats

log = logging.getLogger(__name__)

StateT = tuple[Any, ...]
ActT = tuple[Any, ...]

_TOKENS = itertools.count(1)  # names each search's candidates for the C IDS cache


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


class TNode:
    """A decision node: a state, the steps left and per-action statistics."""

    __slots__ = (
        "state",
        "steps",
        "done",
        "expanded",
        "solved",
        "value",
        "rows",
        "acts",
        "h",
        "n",
        "tot",
        "q",
        "outs",
        "det",
        "asolved",
        "visits",
    )

    def __init__(self, state: StateT, steps: int, done: bool):
        self.state = state
        self.steps = steps
        self.done = done
        self.expanded = False
        self.solved = done or steps <= 0
        self.value = 0.0
        self.rows: list[int] = []  # library rows of the kept candidates
        self.acts: list[ActT] = []  # their action tuples
        self.h: list[float] = []  # first estimates
        self.n: list[int] = []  # samples
        self.tot: list[float] = []  # sum over outcomes of rsum + gamma count value
        self.q: list[float] = []
        # per action: successor state -> [node, count, reward sum, contribution]
        self.outs: list[dict[StateT, list[Any]]] = []
        self.det: list[bool] = []
        self.asolved: list[bool] = []
        self.visits = 0


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
        locks: RewardLocks | None = None,
        cstep: Kernels | None = None,
    ) -> None:
        self.sim = sim
        self.fast = scalar
        self.chooser = chooser
        self.st = settings
        self.rng = rng
        self.py = random.Random(int(rng.integers(0, 2**63 - 1)))
        self.gamma = gamma
        self.locks = locks
        self.table: dict[int, dict[StateT, TNode]] = {}
        self._tuples: dict[int, ActT] = {}
        probe_rng = np.random.default_rng(int(rng.integers(0, 2**63 - 1)))
        self.probes = (_Probe(probe_rng), _Probe(probe_rng))
        dom = sim.model.domain
        constraints = [*dom.action_preconditions, *dom.state_action_constraints]
        self._static = not state_dependent(sim.model, constraints)
        self._static_rows: list[int] | None = None
        self._lock_cache: dict[tuple[int, StateT], str | None] = {}
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
        self.locked = 0
        self._sunk = False  # a sink was met this session (see `_ids_values`)
        self.c = cstep
        if cstep is not None:
            # the C step's own generator, and the probes' two fixed draw vectors
            cstep.rng.value = int(rng.integers(0, 2**63 - 1))
            probe_draws = (
                probe_rng.random(cstep.nu).tolist(),
                probe_rng.standard_normal(cstep.nz).tolist(),
                probe_rng.random(cstep.nu).tolist(),
                probe_rng.standard_normal(cstep.nz).tolist(),
            )
            self._cdraws = (
                *cstep.draw_block(probe_draws[0], probe_draws[1]),
                *cstep.draw_block(probe_draws[2], probe_draws[3]),
            )
            self._token = next(_TOKENS)
            self._cpool = None if not self.pool else cstep.block(self.pool)
            self._cstatic: Any = None  # the static candidates as one C block
            self._probe_draws = probe_draws
        self.tree: Any = None  # the trials in C (`ctree.attach`)
        self._cenum = False  # the legal candidates of a state from C (`setup_enum`)
        self._enum_keys: list[tuple[str, tuple[int, ...]]] = []
        self._enum_index: dict[tuple[str, tuple[int, ...]], int] = {}
        self._enum_vals: list[float] = []
        self._enum_rows: dict[tuple[int, ...], int] = {}
        self._enum_cache: dict[StateT, list[int]] = {}

    # -- actions -------------------------------------------------------------

    def _tuple(self, row: int) -> ActT:
        t = self._tuples.get(row)
        if t is None:
            t = self._tuples[row] = self.fast.encode_actions(self.chooser.lib.take(np.array([row])))
        return t

    def setup_enum(self, states: list[StateT]) -> bool:
        """Find the legal joint actions of each state in C (`CStep.enumerate`)
        instead of with the Python solver, where the candidates depend on the
        state, the actions are boolean and the C `legal` checks the
        constraints; kept only if on each of `states` C finds the very set
        the solver does (C's walk is complete where the constraints are
        monotone). Returns whether it is on."""
        c = self.c
        sim = self.sim
        if c is None or self._static or not c.has_legal:
            return False
        if any(p.range != "bool" for p in sim.action_fluents) or self.chooser.solver is None:
            return False
        inert = self.chooser.skipped
        if not downward_closed(self.fast, inert):
            return False  # the walk could miss legal joint actions in other states
        noop = self.fast.noop
        keys = [(i, key) for i, key in enumerate(self.fast.action_keys) if key not in inert]
        grounds = [(i, 0.0 if noop[i] else 1.0) for i, _ in keys]
        n_max = sim.model.max_nondef_actions
        k = len(grounds) if n_max is None else min(n_max, len(grounds))
        cap = self.chooser.settings.max_actions
        c.enum_setup(grounds, k, cap)
        self._enum_keys = [key for _, key in keys]
        self._enum_index = {key: g for g, key in enumerate(self._enum_keys)}
        self._enum_vals = [v for _, v in grounds]
        checked = 0
        for s in states:
            n, combos = c.enumerate(s, cap)
            if n < 0 or n > cap:
                continue
            decoded = self.fast.decode_state(s)
            space = self.chooser.solver.space(decoded, 0) if self.chooser.solver else None
            if space is None or not space.complete or space.count > cap:
                continue
            rows = self.chooser.candidates([decoded])[0]
            acts = self.chooser.lib.take(rows)
            defaults = sim.noop(1)
            theirs = set()
            for r in range(len(rows)):
                on = []
                for name, arr in acts.items():
                    for idx in np.argwhere(arr[r : r + 1] != defaults[name]):
                        on.append(self._enum_index.get((name, tuple(int(x) for x in idx[1:])), -1))
                theirs.add(tuple(sorted(on)))
            if theirs != set(combos):
                return False
            checked += 1
        self._cenum = checked > 0
        return self._cenum

    def _combo_row(self, combo: tuple[int, ...]) -> int:
        """The library row of the joint action setting these groundings."""
        row = self._enum_rows.get(combo)
        if row is None:
            acts = self.sim.noop(1)
            for g in combo:
                name, idx = self._enum_keys[g]
                acts[name][(0, *idx)] = self._enum_vals[g]
            row = self._enum_rows[combo] = int(self.chooser.lib.add(acts)[0])
        return row

    def _candidates(self, state: StateT) -> list[int]:
        if self._static and self._static_rows is not None:
            return self._static_rows
        if self._cenum:
            got = self._enum_cache.get(state)
            if got is not None:
                return got
            assert self.c is not None
            n, combos = self.c.enumerate(state, self.chooser.settings.max_actions)
            if 0 <= n <= self.chooser.settings.max_actions:
                got = [self._combo_row(cb) for cb in combos]
                if len(self._enum_cache) >= 65536:
                    self._enum_cache.clear()
                self._enum_cache[state] = got
                return got
        rows = self.chooser.candidates([self.fast.decode_state(state)])[0].tolist()
        if self._static:
            self._static_rows = rows
        return rows

    # -- the turn --------------------------------------------------------------

    def start_round(self) -> None:
        self.table = {}
        if self.tree is not None:
            self.tree.start_round()

    def root(self, state: StateT, steps: int) -> TNode:
        """The node of the observed state (the table's, with what was
        searched below it, else a new one); deeper buckets are dropped."""
        if self.tree is not None:
            return self.tree.root(state, steps)  # type: ignore[no-any-return]
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
        if self.tree is not None:
            self.tree.search(root, deadline, iterations, turn)
            return
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
        sample = None if self.c is None else self.c.sample
        while not node.solved:
            if not node.expanded:
                self._expand(node)
                break
            a = self._select(node)
            if sample is not None:
                nxt, r, done = sample(node.state, node.acts[a])
            else:
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
        if self.locks is not None and self._lock(node):
            return
        rows = self._candidates(state)
        seen: set[tuple[Any, ...]] = set()
        kept: list[tuple[int, ActT, bool, StateT, float, bool, bool]] = []
        if self.c is not None:
            kept = self._cprobe(state, rows)
            rows = []
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
            elif self.c is not None:
                nxt, r, done = self.c.sample(state, act)
                turn.sim_steps += 1
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

    def _cprobe(
        self, state: StateT, rows: list[int]
    ) -> list[tuple[int, ActT, bool, StateT, float, bool, bool]]:
        """`_probe` of every candidate at once in C, the equivalent ones
        dropped (the same test: the same probabilities at every draw site
        reached, the same successors, rewards and ends under both probes)."""
        c = self.c
        assert c is not None
        acts = [self._tuple(r) for r in rows]
        if self._static and rows is self._static_rows:
            if self._cstatic is None:
                self._cstatic = c.block(acts)
            block = self._cstatic
        else:
            block = c.block(acts)
        probed = c.probe(state, block, len(acts), self._cdraws)
        # (a deterministic action is stepped once, the others twice)
        self.turn.sim_steps += len(acts) + sum(1 for p in probed if not p[1])
        return [
            (rows[i], acts[i], det, s1, r1, d1, same_r) for i, det, s1, r1, d1, same_r in probed
        ]

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
        if self.c is not None and (self._static or self._cenum):
            if check:
                self._check()
            return self._cids(state, [k[1] for k in kept], d)
        out = []
        step = self.fast.step
        if self.c is not None:
            state = self.c.typed(state)  # the Python step indexes tables by values
        for _, act, _, _, _, _, _ in kept:
            if check:
                self._check()
            nxt, r, done = step(state, act, self.likely)  # type: ignore[arg-type]
            self.turn.sim_steps += 1
            out.append(r if done or d <= 1 else r + self.gamma * self._ids(nxt, d - 1))
        return out

    def _cids(self, state: StateT, acts: list[ActT], depth: int) -> list[float]:
        """`acts`' IDS values in C (static candidates only)."""
        c = self.c
        assert c is not None
        if self._cenum:
            values, made = c.ids_values_enum(
                state, c.block(acts), len(acts), depth, self.gamma, self._token
            )
            self.turn.sim_steps += made
            return values
        if self._cstatic is None:
            rows = self._candidates(state)
            self._cstatic = c.block([self._tuple(r) for r in rows])
        n = len(self._static_rows or [])
        values, made = c.ids_values(
            state, c.block(acts), len(acts), self._cstatic, n, depth, self.gamma, self._token
        )
        self.turn.sim_steps += made
        return values

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
        takes at most `timeout` seconds of this process's CPU time a state
        on average over `states` (PROST's learning phase; 0 when not even
        depth 2 does). CPU time, not the wall clock: on a loaded machine the
        wall clock learned depth 0 (no IDS) one session and 3 the next."""
        depth = 0
        c_static = self.c is not None and self._static
        for s in states:
            # the candidates (and, in C, their block) once, before anything is timed:
            # finding them is not part of the search an IDS depth costs
            self._candidates(s)
        if c_static and states:
            self._cids(states[0], [], 0)
        blocks = {}
        if self.c is not None and self._cenum:
            blocks = {
                i: self.c.block([self._tuple(r) for r in self._candidates(s)])
                for i, s in enumerate(states)
            }
        for d in range(2, min(15, steps) + 1):
            self._ids_cache.clear()
            t0 = time.process_time()
            if c_static:
                assert self.c is not None
                self.c.ids_clear()
                n = len(self._static_rows or [])
                for s in states:
                    _, made = self.c.ids_values(
                        s, self._cstatic, n, self._cstatic, n, d, self.gamma, self._token
                    )
                    self.turn.sim_steps += made
            elif blocks:
                assert self.c is not None
                self.c.ids_clear()
                for i, s in enumerate(states):
                    n = len(self._candidates(s))
                    _, made = self.c.ids_values_enum(s, blocks[i], n, d, self.gamma, self._token)
                    self.turn.sim_steps += made
            else:
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
        if self.c is not None:
            self.c.ids_clear()
        self.ids_depth = depth
        return depth

    def _lock(self, node: TNode) -> bool:
        """Solve a reward lock at once (with `reward_locks`)."""
        assert self.locks is not None
        key = (node.steps, node.state)
        kind = self._lock_cache.get(key, "?")
        if kind == "?":
            try:
                kind = self.locks.check(self.fast.decode_state(node.state), node.steps)
            except Exception as err:  # noqa: BLE001 - the check is an optimisation
                log.debug("mcts: reward-lock check failed: %s", err)
                kind = None
            if len(self._lock_cache) < 100_000:
                self._lock_cache[key] = kind
        if kind is None:
            return False
        if self.c is not None:
            _, r, _ = self.c.sample(node.state, self.fast.noop)
        else:
            _, r, _ = self.fast.step(node.state, self.fast.noop, self.rng)
        g = self.gamma
        value = r * node.steps if g == 1.0 else r * (1.0 - g**node.steps) / (1.0 - g)
        node.rows = [0]
        node.acts = [self.fast.noop]
        node.det = [True]
        node.h = [value]
        node.q = [value]
        node.n = [0]
        node.tot = [0.0]
        node.outs = [{}]
        node.asolved = [True]
        node.expanded = True
        node.solved = True
        node.value = value
        self.turn.locks += 1
        self.turn.leaves += 1
        return True

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
        if self.c is not None:
            block = None if pool is None or not pool else self._cpool
            total, taken, ended = self.c.walk(state, n, block, len(pool or ()) if block else 0, g)
            self.turn.sim_steps += taken
            if not ended and taken < steps and taken > 0 and self.st.extrapolate:
                return self._extrapolate(total, taken, steps)
            return total
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
