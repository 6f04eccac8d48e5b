"""`THTS`: the single-state trial-based heuristic tree search of `mcts`
(option `engine = thts`), on the grounded one-state step of
`ippc.rddl.sim.scalar` compiled to C.

One trial at a time, as in Keller & Helmert 2013 and PROST:

* A *decision node* (`TNode`) is a state (the step's tuple of scalars)
  with the steps left; all nodes live in a transposition table keyed by
  (steps left, state), kept across trials and across the turns of a round,
  so the observed state's node is the next root with what was learnt below.
* A trial descends from the root: at an expanded node it picks an action
  by UCB1 among the actions not solved yet, samples one successor of it
  (a *chance node* is the action's dict of sampled
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
  vectors: the generated step compares each uniform draw
  with its probability (`u < p`) and multiplies each normal draw by its
  standard deviation, and the probe records these (`Kernels.probe`). An action all of whose
  probabilities are 0 or 1 (and standard deviations 0) is *deterministic*:
  its one successor is known. Two deterministic actions with the same
  successor and reward are *equivalent*: only the first (noop first) is
  kept. Stochastic actions are never merged: two of them can agree on both
  probes by chance (tests/data/mcts_sound/probe.rddl). With one
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

One search engine. The search is written once, in C: csrc/tree.c (the
trials, expansion, backups, labelling, sinks, the time rule) over
csrc/kernels.c (probing, IDS, the legal-action walk, roll-outs), compiled
with the instance's step (`ckernels.Kernels`) and driven by `ctree.CTree`.
This module is its Python side: the candidate actions of a state (the
chooser's, or the C legal-action walk's where it is proven to find the same
set), IDS's depth (PROST's learning phase, in C), and the turn's calls
(`root`, `search`, `best`). The draws come from the C generator seeded from
the planner's: a seed gives the same search on any machine.

Where there is no C step (no compiler, a failed build, `compiled = no`) or
`reward_locks` is asked for, the session runs the `wave` engine instead
(`planner`), and where the build is late, until it has ended (`startup`).
A pure-Python transcription of the same tree is kept as a reference for the tests only (tests/planners/thts_reference.py);
docs/architecture.md ("mcts: one search engine") says why.

Imports the kernels (`ckernels`), the chooser (`actions`), the relevance
analysis's `downward_closed`, `options` and `stats`.
"""

from __future__ import annotations

import itertools
import logging
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ...rddl.sim.scalar import ScalarStep
from ...rddl.simulator import Simulator
from .actions import ActionChooser, state_dependent
from .ckernels import Kernels
from .options import Settings
from .relevance import downward_closed
from .stats import SearchStats

log = logging.getLogger(__name__)

StateT = tuple[Any, ...]
ActT = tuple[Any, ...]

_TOKENS = itertools.count(1)  # names each search's candidates for the C IDS cache


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


class THTS:
    """The search of one session (see the module docstring). `ctree.attach`
    gives it its tree (`tree`); until then `root` and `search` cannot run."""

    def __init__(
        self,
        sim: Simulator,
        scalar: ScalarStep,
        chooser: ActionChooser,
        settings: Settings,
        rng: np.random.Generator,
        gamma: float,
        kernels: Kernels,
    ) -> None:
        self.sim = sim
        self.fast = scalar
        self.chooser = chooser
        self.st = settings
        self.rng = rng
        # (drawn and unused: the seed of the Python tree's tie-breaks before the
        # search moved to C; kept so that a seed plays the actions it played)
        rng.integers(0, 2**63 - 1)
        self.gamma = gamma
        self._tuples: dict[int, ActT] = {}
        probe_rng = np.random.default_rng(int(rng.integers(0, 2**63 - 1)))
        dom = sim.model.domain
        constraints = [*dom.action_preconditions, *dom.state_action_constraints]
        self._static = not state_dependent(sim.model, constraints)
        self._static_rows: list[int] | None = None
        pool = chooser.pool
        self.pool: list[ActT] | None = (
            None if pool is None else [self._tuple(int(r)) for r in pool.tolist()]
        )
        self.ids_depth = 0  # 0: no IDS (roll-outs); set by `learn_ids` or the planner
        self.c = kernels
        # the C step's own generator, and the probes' two fixed draw vectors
        kernels.rng.value = int(rng.integers(0, 2**63 - 1))
        self._probe_draws = (
            probe_rng.random(kernels.nu).tolist(),
            probe_rng.standard_normal(kernels.nz).tolist(),
            probe_rng.random(kernels.nu).tolist(),
            probe_rng.standard_normal(kernels.nz).tolist(),
        )
        self._token = next(_TOKENS)
        self._cstatic: Any = None  # the static candidates as one C block
        self.tree: Any = None  # the trials in C (`ctree.attach`)
        self._cenum = False  # the legal candidates of a state from C (`setup_enum`)
        self._enum_keys: list[tuple[str, tuple[int, ...]]] = []
        self._enum_index: dict[tuple[str, tuple[int, ...]], int] = {}
        self._enum_vals: list[float] = []
        self._enum_rows: dict[tuple[int, ...], int] = {}
        self._enum_cache: dict[StateT, list[int]] = {}
        self._callback: Any = None  # `_candidates` as a C callback (learning IDS)

    # -- actions -------------------------------------------------------------

    def _tuple(self, row: int) -> ActT:
        t = self._tuples.get(row)
        if t is None:
            t = self._tuples[row] = self.fast.encode_actions(self.chooser.lib.take(np.array([row])))
        return t

    def setup_enum(self, states: list[StateT]) -> bool:
        """Find the legal joint actions of each state in C (`Kernels.enumerate`)
        instead of with the Python solver, where the candidates depend on the
        state, the actions are boolean and the C `legal` checks the
        constraints; kept only if on each of `states` C finds the very set
        the solver does (C's walk is complete where the constraints are
        monotone). Returns whether it is on."""
        c = self.c
        sim = self.sim
        if self._static or not c.has_legal:
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

    # -- the turn (the C tree's) -------------------------------------------------

    def start_round(self) -> None:
        self.tree.start_round()

    def root(self, state: StateT, steps: int) -> TNode:
        """The view of the node of the observed state (the tree's, with what
        was searched below it, else a new one)."""
        return self.tree.root(state, steps)  # type: ignore[no-any-return]

    def search(
        self, root: TNode, deadline: float | None, iterations: int | None, turn: SearchStats
    ) -> None:
        """Trials from `root` until the deadline (or exactly `iterations`)."""
        self.tree.search(root, deadline, iterations, turn)

    def best(self, root: TNode) -> int:
        """The index of the action to play: the best value, then the most
        samples, then the first (noop first)."""
        if not root.q:
            return -1
        top = max(root.q)
        cands = [a for a, v in enumerate(root.q) if v >= top - 1e-9 * max(1.0, abs(top))]
        return max(cands, key=lambda a: (root.n[a], -a))

    # -- IDS's depth -------------------------------------------------------------

    def learn_ids(self, states: list[StateT], steps: int, timeout: float) -> int:
        """The deepest IDS depth (at most `steps`, at most 15) whose search
        takes at most `timeout` seconds of this process's CPU time a state
        on average over `states` (PROST's learning phase; 0 when not even
        depth 2 does), with the candidates the tree will use: the static
        ones, the C walk's, or the chooser's through a callback. CPU time,
        not the wall clock: on a loaded machine the wall clock learned depth
        0 (no IDS) one session and 3 the next."""
        c = self.c
        # the candidates (and their C blocks) once, before anything is timed:
        # finding them is not part of the search an IDS depth costs
        blocks = [c.block([self._tuple(r) for r in self._candidates(s)]) for s in states]
        sizes = [len(self._candidates(s)) for s in states]
        run: Callable[[int, int], int]
        if self._static:
            if self._cstatic is None and states:
                self._cstatic = blocks[0]
            n = len(self._static_rows or [])

            def run(i: int, d: int) -> int:
                s = states[i]
                return c.ids_values(
                    s, self._cstatic, n, self._cstatic, n, d, self.gamma, self._token
                )[1]

        elif self._cenum:

            def run(i: int, d: int) -> int:
                s = states[i]
                return c.ids_values_enum(s, blocks[i], sizes[i], d, self.gamma, self._token)[1]

        else:
            if self._callback is None:
                self._callback = c.candidates_callback(self._candidates, self._tuple)

            def run(i: int, d: int) -> int:
                s = states[i]
                return c.ids_values_cb(
                    s, blocks[i], sizes[i], self._callback, d, self.gamma, self._token
                )[1]

        depth = 0
        for d in range(2, min(15, steps) + 1):
            c.ids_clear()
            t0 = time.process_time()
            for i in range(len(states)):
                run(i, d)
            took = (time.process_time() - t0) / max(1, len(states))
            if took > timeout:
                break
            depth = d
        c.ids_clear()
        self.ids_depth = depth
        return depth
