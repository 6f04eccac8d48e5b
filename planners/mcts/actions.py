"""The action side of the search: the action library (every joint action
the search has considered, as rows of one array per action fluent), the
candidates of a new decision node, and the rollout policy's actions.

Candidates come from `ippc.rddl.legal` (every legal joint action of the
node's state when there are at most `max_actions`, else noop when legal and
a uniform sample of the others), cached by the state fluents the
constraints read; real-valued action spaces, which it cannot enumerate,
get rddlsim-style random actions (`Simulator.random_actions`) instead.
Rollouts draw uniformly from the boolean joint actions enumerated once per
session (at most `enumerate_limit`), rejecting illegal ones, else use
`Simulator.random_actions` (whose fallback finds legal actions where coin
flips cannot).

May call the simulator's public methods and `ippc.rddl.legal`.
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Iterable

import numpy as np

from ...rddl import ast as A
from ...rddl.legal import LegalActions, NoLegalAction, solver_for
from ...rddl.model import ACTION, NON_FLUENT, Model
from ...rddl.simulator import Simulator, State
from .options import Settings

log = logging.getLogger(__name__)

Array = np.ndarray


class ActionLibrary:
    """Every joint action the search has considered, as rows of one array
    per action fluent, so that the actions of a whole batch are one fancy
    index (`take`). Rows are unique; row 0 is noop."""

    def __init__(self, sim: Simulator):
        self.sim = sim
        self.names = [p.name for p in sim.action_fluents]
        noop = sim.noop(1)
        self.arrays: dict[str, Array] = {k: np.repeat(v, 16, axis=0) for k, v in noop.items()}
        self.size = 0
        self._index: dict[bytes, int] = {}
        self.add(noop)

    def _keys(self, actions: dict[str, Array], n: int) -> list[bytes]:
        return _row_keys([actions[k] for k in self.names], n)

    def add(self, actions: dict[str, Array]) -> Array:
        """The library rows of a batch of joint actions, adding new ones."""
        n = _batch_of(actions, self.names)
        keys = self._keys(actions, n)
        out = np.empty(n, dtype=np.int64)
        new: list[int] = []
        for i, key in enumerate(keys):
            row = self._index.get(key)
            if row is None:
                row = self._index[key] = self.size + len(new)
                new.append(i)
            out[i] = row
        if new:
            need = self.size + len(new)
            cap = next(iter(self.arrays.values())).shape[0] if self.arrays else need
            if need > cap:
                cap = max(need, 2 * cap)
                for k, v in self.arrays.items():
                    grown = np.empty((cap, *v.shape[1:]), dtype=v.dtype)
                    grown[: self.size] = v[: self.size]
                    self.arrays[k] = grown
            sel = np.asarray(new)
            for k in self.names:
                self.arrays[k][self.size : need] = actions[k][sel]
            self.size = need
        return out

    def take(self, rows: Array) -> dict[str, Array]:
        """The joint actions at these library rows, as a batch."""
        return {k: v[rows] for k, v in self.arrays.items()}


def _batch_of(actions: dict[str, Array], names: list[str]) -> int:
    for k in names:
        return int(actions[k].shape[0])
    return 1


def _row_keys(arrays: list[Array], n: int) -> list[bytes]:
    """One bytes key per batch row of these arrays (their raw contents)."""
    if not arrays:
        return [b""] * n
    # (the width spelled out: numpy cannot infer -1 for an empty batch)
    parts = [
        np.ascontiguousarray(a).reshape(n, int(np.prod(a.shape[1:]))).view(np.uint8) for a in arrays
    ]
    packed = np.concatenate(parts, axis=1) if len(parts) > 1 else parts[0]
    width = packed.shape[1]
    blob = np.ascontiguousarray(packed).tobytes()
    return [blob[i * width : (i + 1) * width] for i in range(n)]


def enumerate_boolean(
    sim: Simulator, limit: int, skip: Iterable[tuple[str, tuple[int, ...]]] = ()
) -> dict[str, Array] | None:
    """Every joint action of a boolean action space with at most
    max-nondef-actions groundings set (noop first), regardless of the
    preconditions, leaving the groundings in `skip` at their default; None
    when an action is not boolean or there are more than `limit`."""
    noop1 = sim.noop(1)
    left_out = set(skip)
    grounds: list[tuple[str, tuple[int, ...]]] = []
    for p in sim.action_fluents:
        if p.range != "bool":
            return None
        shape = noop1[p.name].shape[1:]
        grounds.extend((p.name, idx) for idx in np.ndindex(*shape) if (p.name, idx) not in left_out)
    limit_nondef = sim.model.max_nondef_actions
    k_max = len(grounds) if limit_nondef is None else min(limit_nondef, len(grounds))
    count = sum(math.comb(len(grounds), k) for k in range(k_max + 1))
    if count > limit:
        return None
    actions = sim.noop(count)
    row = 0
    for k in range(k_max + 1):
        for combo in itertools.combinations(range(len(grounds)), k):
            for g in combo:
                name, idx = grounds[g]
                actions[name][(row, *idx)] = not noop1[name][(0, *idx)]
            row += 1
    return actions


def pvariables_read(expr: A.Expr) -> set[str]:
    """The names of every pvariable an expression reads."""
    out: set[str] = set()
    todo = [expr]
    while todo:
        e = todo.pop()
        if isinstance(e, A.PVar):
            out.add(e.name)
        todo.extend(A.children(e))
    return out


def state_dependent(model: Model, constraints: Iterable[A.Expr]) -> bool:
    """Whether any of these constraints reads something other than actions
    and non-fluents (a state, interm or observ fluent)."""
    for expr in constraints:
        for name in pvariables_read(expr):
            p = model.pvariables.get(name)
            if p is None or p.kind not in (ACTION, NON_FLUENT):
                return True
    return False


class ActionChooser:
    """Candidates of new nodes and actions of rollouts, as library rows
    and action arrays (see the module docstring)."""

    def __init__(
        self,
        sim: Simulator,
        settings: Settings,
        rng: np.random.Generator,
        inert: Iterable[tuple[str, tuple[int, ...]]] = (),
    ) -> None:
        self.sim = sim
        self.settings = settings
        self.rng = rng
        self.lib = ActionLibrary(sim)
        inert = list(inert)
        # The groundings left out are held at their default in the solver itself, so
        # that a sample of a big space is drawn among the joint actions that can be
        # candidates: filtered after the draw, a sample of TriangleTireworld #10's 4,424
        # legal joint actions (4,236 of its groundings inert) kept about 40, seldom the
        # car's own moves, and the root looked like a sink.
        self.solver: LegalActions | None = None
        if LegalActions.supports(sim):
            self.solver = LegalActions(sim, fixed=inert) if inert else solver_for(sim)
        dom = sim.model.domain
        constraints = [*dom.action_preconditions, *dom.state_action_constraints]
        self.constrained = bool(constraints)
        self.skipped = set(inert)
        """The action groundings candidates and roll-outs leave at their default."""
        self._inert: dict[str, Array] = {}
        """Per action fluent, where its groundings never matter (`ScalarStep.inert_actions`):
        candidates and roll-out actions leave those at their default."""
        defaults = sim.noop(1)
        for name, idx in inert:
            mask = self._inert.setdefault(name, np.zeros(defaults[name].shape[1:], dtype=bool))
            mask[idx] = True
        self._projection: dict[int, int] = {}  # library row -> row with none set
        enumerated = enumerate_boolean(sim, settings.enumerate_limit, inert)
        self.pool: Array | None = None if enumerated is None else self.lib.add(enumerated)
        """Library rows the rollouts draw from (None: coin flips instead)."""
        if (
            self.pool is not None
            and self.constrained
            and not state_dependent(sim.model, constraints)
        ):
            # Constraints that read only actions and non-fluents (GameOfLife's,
            # Elevators') hold or fail alike in every state: filter the joint
            # actions once instead of in every rollout step.
            n = len(self.pool)
            ok = sim.check_actions(sim.initial_state(n), self.lib.take(self.pool))
            self.pool = self.pool[ok]
            self.constrained = False
        self._known: dict[bytes, Array] = {}  # all the legal candidates of a state key
        self.fixed_samples = False
        """Keep a state key's sample of candidates too (where there are more
        than `max_actions`), not only complete sets: the same candidates for
        the same key, and the solver asked once per key (set by the thts
        engine's C tree, which asks for every new node and IDS node)."""

    def describe(self) -> str:
        """For the log: how candidates and rollout actions are found."""
        where = "legal-action solver" if self.solver is not None else "sampled"
        pool = "coin flips" if self.pool is None else f"{len(self.pool)} enumerated"
        return f"candidates {where}, rollouts {pool}{' (constrained)' if self.constrained else ''}"

    # -- candidates ----------------------------------------------------

    def candidates(self, states: list[State]) -> list[Array]:
        """The candidate joint actions (library rows) of each new node, from
        the first of its states; noop first when it is legal."""
        if self.solver is None:
            return self._sampled(states)
        out = []
        k = self.settings.max_actions
        for state in states:
            key = self.solver.key(state, 0)
            rows = self._known.get(key)
            if rows is None:
                try:
                    arrays = self.solver.candidates(state, self.rng, k, 0)
                except NoLegalAction as err:
                    log.debug("mcts: a node without legal actions: %s", err)
                    rows = np.zeros(0, dtype=np.int64)
                else:
                    rows = self._without_inert(self.lib.add(arrays))
                    space = self.solver.space(state, 0)
                    whole = space.complete and space.count <= k
                    if (whole or self.fixed_samples) and len(self._known) < 65536:
                        self._known[key] = rows
            out.append(rows)
        return out

    def _sampled(self, states: list[State]) -> list[Array]:
        """rddlsim-style random actions in each state, deduplicated, and noop
        when it is legal (action spaces the solver cannot enumerate)."""
        sim = self.sim
        per = max(2 * self.settings.max_actions, 16)
        batch = _stack_first(states)
        many = batch[np.repeat(np.arange(len(states)), per)]
        drawn = self.lib.add(sim.random_actions(many, self.rng)).reshape(len(states), per)
        noop_ok = sim.check_actions(batch, sim.noop(len(states)))
        out = []
        for i in range(len(states)):
            rows = self._without_inert(np.unique(drawn[i]))
            if noop_ok[i] and rows[0] != 0:
                rows = np.concatenate([[0], rows])
            out.append(self._trim(rows))
        return out

    def _without_inert(self, rows: Array) -> Array:
        """`rows` less the joint actions that set a skipped grounding, each
        replaced by itself with those groundings at their default (its
        *projection*) where that one is not among `rows` already: the
        projection is worth at least as much, and legal wherever the action
        is (`relevance.removable_inert` and `useless_actions` leave out only
        groundings the constraints allow at their default), so a sampled set
        of candidates loses nothing by it. With every legal action in `rows`
        the projections are all there: the rows that set none, in order."""
        if not self._inert or len(rows) == 0:
            return rows
        todo = [int(r) for r in rows.tolist() if int(r) not in self._projection]
        if todo:
            acts = self.lib.take(np.array(todo, dtype=np.int64))
            defaults = self.sim.noop(1)
            bad = np.zeros(len(todo), dtype=bool)
            for name, mask in self._inert.items():
                differs = acts[name][:, mask] != defaults[name][:, mask]
                bad |= differs.any(axis=1)
                acts[name][:, mask] = defaults[name][:, mask]
            projected = self.lib.add(acts)
            for r, b, q in zip(todo, bad.tolist(), projected.tolist(), strict=True):
                self._projection[r] = int(q) if b else r
        listed = [int(r) for r in rows.tolist()]
        keep = [r for r in listed if self._projection[r] == r]
        present = set(keep)
        for r in listed:
            q = self._projection[r]
            if q not in present:
                present.add(q)
                keep.append(q)
        return np.array(keep, dtype=np.int64)

    def _trim(self, rows: Array) -> Array:
        """At most `max_actions` candidates: noop (row 0) if there, then a
        seeded sample of the rest."""
        k = self.settings.max_actions
        if len(rows) <= k:
            return rows
        has_noop = rows[0] == 0
        rest = rows[1:] if has_noop else rows
        keep = k - (1 if has_noop else 0)
        picked = np.sort(self.rng.choice(rest, keep, replace=False))
        return np.concatenate([rows[:1], picked]) if has_noop else picked

    # -- rollouts --------------------------------------------------------

    def rollout_actions(self, states: State, use_noop: Array) -> dict[str, Array]:
        """The rollout policy's joint actions for a batch of states: noop
        where `use_noop`, else uniform legal ones (rejection from the
        enumerated pool, else coin flips); legal wherever anything is."""
        sim = self.sim
        n = states.batch
        if use_noop.all():
            acts = sim.noop(n)
            if self.constrained:
                bad = ~sim.check_actions(states, acts)
                if bad.any():
                    acts = self._fix(states, acts, bad)
            return acts
        if self.pool is None:
            acts = self._random(states)
        else:
            pool = self.pool
            rows = pool[self.rng.integers(0, len(pool), n)]
            acts = self.lib.take(rows)
            if self.constrained:
                bad = ~sim.check_actions(states, acts)
                for _ in range(4):
                    if not bad.any():
                        break
                    which = np.flatnonzero(bad)
                    redo = pool[self.rng.integers(0, len(pool), len(which))]
                    rows[which] = redo
                    sub = self.lib.take(redo)
                    ok = sim.check_actions(states[which], sub)
                    for k, v in sub.items():
                        acts[k][which[ok]] = v[ok]
                    bad[which[ok]] = False
                if bad.any():
                    noop = sim.noop(n)
                    for k, v in noop.items():
                        acts[k][bad] = v[bad]
                    still = bad & ~sim.check_actions(states, acts)
                    if still.any():
                        acts = self._fix(states, acts, still)
        if use_noop.any():
            noop = sim.noop(1)
            for k, v in noop.items():
                acts[k][use_noop] = v[0]
            if self.constrained:
                bad = use_noop & ~sim.check_actions(states, acts)
                if bad.any():
                    acts = self._fix(states, acts, bad)
        return acts

    def _fix(self, states: State, acts: dict[str, Array], bad: Array) -> dict[str, Array]:
        """Random legal actions where the chosen ones are illegal."""
        which = np.flatnonzero(bad)
        sub = self._random(states[which])
        for k, v in sub.items():
            acts[k][which] = v
        return acts

    def _random(self, states: State) -> dict[str, Array]:
        try:
            return self.sim.random_actions(states, self.rng)
        except NoLegalAction:
            # a dead end in the batch (nothing legal at all): a rollout steps
            # without checks, so noop stands in
            return self.sim.noop(states.batch)


def _stack_first(states: Iterable[State]) -> State:
    """One batch of the first state of each state."""
    listed = list(states)
    names = list(listed[0].values)
    return State({k: np.concatenate([s.values[k][:1] for s in listed], axis=0) for k in names})
