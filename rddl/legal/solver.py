"""`LegalActions`: the legal joint actions of one instance, state by
state, with a cache keyed by the state fluents the constraints read; what
planners and the simulator call (see the package docstring).
"""

from __future__ import annotations

import logging
import math
import weakref
from collections import OrderedDict
from collections.abc import Iterable, Mapping, Sequence
from typing import Protocol

import numpy as np

from .. import ast as A
from ..model import STATE, Model, PVariable
from ..sim_types import State
from ..writer import write_expr
from .ground import Element, Grounder, variables
from .intervals import _truth, interval
from .propagate import Domain, _as_linear, _Conflict, _Linear, _Node, _Problem, _propagate
from .search import ActionSpace, LegalActionsUnsupported, NoLegalAction, _search
from .static import FALSE, Layout

log = logging.getLogger(__name__)

Array = np.ndarray

INT_SPAN = 5
"""An int action fluent whose range the constraints leave (nearly) open
takes the values within INT_SPAN of its default (as rddlsim's random policy
draws ints in 0..5)."""
_INT_VALUES = 256  # most values of an int action variable kept explicitly
_INT_LIMIT = 2**31


class SimulatorView(Protocol):
    """What the solver uses of a `Simulator` (`ippc.rddl.sim`): the model, the action and
    state fluents, noop and the batched legality check. The simulator calls the solver
    (`Simulator.random_actions`, `Simulator.legal_actions`), so the solver takes this
    interface instead of importing the class."""

    @property
    def model(self) -> Model: ...

    @property
    def action_fluents(self) -> list[PVariable]: ...

    @property
    def state_fluents(self) -> list[PVariable]: ...

    def noop(self, batch: int = 1) -> dict[str, Array]: ...

    def check_actions(self, state: State, actions: Mapping[str, Array]) -> Array: ...


class LegalActions:
    """Legal joint actions of one instance, state by state (see the module
    docstring). Spaces are cached by the values of the state fluents the
    constraints read (once per session when they read none).

    >>> legal = LegalActions(sim)
    >>> legal.enumerate(state)          # every legal joint action, noop first
    >>> legal.sample(state, rng, 10)    # ten uniform draws
    """

    def __init__(
        self,
        sim: SimulatorView,
        node_limit: int = 2000,
        cache_size: int = 4096,
        fixed: Iterable[tuple[str, tuple[int, ...]]] = (),
    ) -> None:
        real = [p.name for p in sim.action_fluents if p.range == "real"]
        if real:
            raise LegalActionsUnsupported(
                f"real-valued action fluents cannot be enumerated: {', '.join(real)}"
            )
        self.sim = sim
        self.model = sim.model
        self.layout = Layout(sim.model)
        dom = sim.model.domain
        self.constraints = [*dom.action_preconditions, *dom.state_action_constraints]
        reads: set[str] = set()
        for expr in self.constraints:
            for node in A.walk(expr):
                if isinstance(node, A.PVar) and node.name in self.model.pvariables:
                    if self.model.pvariables[node.name].kind == STATE:
                        reads.add(node.name)
        self.reads = sorted(reads)
        """The state fluents the constraints read: the key of the cache."""
        self.node_limit = node_limit
        self.cache_size = cache_size
        self._dyn: dict[int, bool] = {}
        self._cache: OrderedDict[bytes, ActionSpace] = OrderedDict()
        self._non_fluents = self._non_fluent_arrays()
        self._dtypes = {
            p.name: np.bool_ if p.range == "bool" else np.int64 for p in self.layout.fluents
        }
        self.fixed: frozenset[int] = frozenset(
            self.layout.offset[name]
            + (int(np.ravel_multi_index(idx, self.layout.shape[name])) if idx else 0)
            for name, idx in fixed
        )
        """Action variables held at their default (a planner's groundings that can
        never matter): the spaces are those of the other variables, so a sample
        is drawn among the joint actions that leave these alone."""

    @staticmethod
    def supports(sim: SimulatorView) -> bool:
        """Whether the action space can be enumerated (no real actions)."""
        return all(p.range != "real" for p in sim.action_fluents)

    def _non_fluent_arrays(self) -> dict[str, Array]:
        out = {}
        for p in self.model.pvariables.values():
            if p.kind != "non-fluent":
                continue
            shape = tuple(len(self.model.types[t].members) for t in p.params)
            arr = np.full(shape, self.layout.encode(p, self.model.default_of(p)))
            for (name, args), value in self.model.non_fluent_values.items():
                if name == p.name:
                    idx = tuple(
                        self.layout.codes[t][a] for t, a in zip(p.params, args, strict=True)
                    )
                    arr[idx] = self.layout.encode(p, value)
            out[p.name] = arr
        return out

    # -- spaces ------------------------------------------------------

    def key(self, state: State, index: int = 0) -> bytes:
        """The cache key of state `index`: the bytes of the fluents read."""
        return b"".join(np.ascontiguousarray(state.values[n][index]).tobytes() for n in self.reads)

    def space(self, state: State, index: int = 0) -> ActionSpace:
        """The legal joint actions of state `index` of the batch."""
        key = self.key(state, index)
        got = self._cache.get(key)
        if got is not None:
            self._cache.move_to_end(key)
            return got
        got = self._build(state, index)
        self._cache[key] = got
        if len(self._cache) > self.cache_size:
            self._cache.popitem(last=False)
        return got

    def _build(self, state: State, index: int) -> ActionSpace:
        values = dict(self._non_fluents)
        for f in self.sim.state_fluents:
            values[f.name] = np.asarray(state.values[f.name][index])
        grounder = Grounder(self.layout, values, self._dyn)
        elements = list(grounder.elements(self.constraints))
        p = self._problem(elements)
        for e, el in enumerate(elements):
            if el.formula == FALSE:
                return ActionSpace(p, None, [], True, 0, self._why(p, e))
        root = _Node(list(p.domains), set(range(len(elements))), False)
        if any(not d for d in p.domains):
            v = next(i for i, d in enumerate(p.domains) if not d)
            return ActionSpace(
                p, None, [], True, 0, f"no value of {self.layout.var_name(v)} is allowed"
            )
        try:
            _propagate(p, root, range(len(elements)))
        except _Conflict as err:
            return ActionSpace(p, None, [], True, 0, self._why(p, err.element))
        leaves, complete, nodes = _search(p, root, self.node_limit)
        why = None
        if complete and not leaves:
            why = (
                "no legal joint action in this state: the constraints cannot all hold at once "
                f"(searched {nodes} nodes); noop violates {self._noop_violation(p, root)}"
            )
        return ActionSpace(p, root, leaves, complete, nodes, why)

    def _problem(self, elements: list[Element]) -> _Problem:
        n = self.layout.size
        linear = [_as_linear(el.formula) for el in elements]
        vars_ = [tuple(sorted(variables(el.formula))) for el in elements]
        watch: list[list[int]] = [[] for _ in range(n)]
        for e, vs in enumerate(vars_):
            for v in vs:
                watch[v].append(e)
        defaults = [int(d) for d in self.layout.defaults]
        domains: list[Domain] = []
        for v in range(n):
            p = self.layout.fluent_of[v]
            if v in self.fixed:
                domains.append((defaults[v],))
            elif p.range == "bool":
                domains.append((0, 1))
            elif p.range in self.layout.codes:
                domains.append(tuple(range(len(self.model.types[p.range].members))))
            else:
                domains.append(self._int_domain(v, defaults[v], linear, vars_))
        return _Problem(
            elements, linear, vars_, watch, domains, defaults, self.model.max_nondef_actions
        )

    def _int_domain(
        self, v: int, default: int, linear: list[_Linear | None], vars_: list[tuple[int, ...]]
    ) -> Domain:
        """An int action variable's values: the bounds its one-variable
        linear elements give, else INT_SPAN around its default."""
        lo, hi = -_INT_LIMIT, _INT_LIMIT - 1
        for lin, vs in zip(linear, vars_, strict=True):
            if lin is None or vs != (v,) or lin.op == "ne":
                continue
            c = lin.coefs[v]
            b = -lin.const / c  # c x + k op 0, with x op' b
            if lin.op == "eq":
                if b != math.floor(b):
                    return ()
                lo, hi = max(lo, int(b)), min(hi, int(b))
            elif lin.op == "le":
                if c > 0:
                    hi = min(hi, math.floor(b))
                else:
                    lo = max(lo, math.ceil(b))
            elif c > 0:  # lt
                hi = min(hi, math.ceil(b) - 1)
            else:
                lo = max(lo, math.floor(b) + 1)
        if hi < lo:
            return ()
        if hi - lo + 1 <= _INT_VALUES:
            return tuple(range(lo, hi + 1))
        centre = min(max(default, lo), hi)
        return tuple(range(max(lo, centre - INT_SPAN), min(hi, centre + INT_SPAN) + 1))

    def _why(self, p: _Problem, e: int | None) -> str:
        if e is None:
            return (
                "no legal joint action in this state: more than max-nondef-actions "
                f"({p.budget}) action groundings would have to differ from their default"
            )
        el = p.elements[e]
        expr = self.constraints[el.index]
        where = ", ".join(f"{v} = {o}" for v, o in el.env)
        text = write_expr(expr)
        text = text if len(text) <= 160 else text[:157] + "..."
        return (
            f"no legal joint action in this state: {expr.loc}: constraint cannot hold"
            f"{' where ' + where if where else ''}: {text}"
        )

    def _noop_violation(self, p: _Problem, root: _Node) -> str:
        lo = [float(d) for d in p.defaults]
        for el in p.elements:
            if _truth(*interval(el.formula, lo, lo))[1] == 0:
                expr = self.constraints[el.index]
                return f"{expr.loc}: {write_expr(expr)[:160]}"
        return (
            "max-nondef-actions"
            if p.budget is not None and p.budget < 0
            else "nothing (noop is legal?)"
        )

    # -- arrays --------------------------------------------------------

    def arrays(self, rows: Sequence[Sequence[int]]) -> dict[str, Array]:
        """Rows of action-variable values as the simulator's action arrays."""
        n = len(rows)
        mat = np.asarray(rows, dtype=np.int64).reshape(n, self.layout.size)
        out: dict[str, Array] = {}
        for p in self.layout.fluents:
            off = self.layout.offset[p.name]
            cnt = self.layout.count(p.name)
            out[p.name] = (
                mat[:, off : off + cnt]
                .reshape(n, *self.layout.shape[p.name])
                .astype(self._dtypes[p.name])
            )
        return out

    def _verified(self, state: State, index: int, rows: list[list[int]]) -> dict[str, Array]:
        """The rows that `Simulator.check_actions` finds legal, as arrays."""
        arrays = self.arrays(rows)
        if not rows:
            return arrays
        ok = self.sim.check_actions(state[[index] * len(rows)], arrays)
        if not ok.all():
            log.debug(
                "legal actions: the simulator refused %d of %d candidates",
                int((~ok).sum()),
                len(rows),
            )
            arrays = {k: v[ok] for k, v in arrays.items()}
        return arrays

    # -- what planners call ---------------------------------------------

    def enumerate(self, state: State, index: int = 0, limit: int = 100_000) -> dict[str, Array]:
        """Every legal joint action of state `index`, stacked along the
        batch axis, noop first when it is legal. Raises `NoLegalAction`
        when there is none, `TooManyActions` above `limit`."""
        space = self.space(state, index)
        space.require()
        return self._verified(state, index, space.rows(limit))

    def count(self, state: State, index: int = 0) -> int:
        """How many joint actions are legal in state `index` (exact when
        the space's search finished)."""
        return self.space(state, index).count

    def sample(
        self, state: State, rng: np.random.Generator, n: int = 1, index: int = 0
    ) -> dict[str, Array]:
        """n legal joint actions of state `index` drawn uniformly (with
        replacement). Raises `NoLegalAction` when there is none."""
        space = self.space(state, index)
        rows = space.sample(rng, n)
        arrays = self._verified(state, index, rows)
        got = next(iter(arrays.values())).shape[0] if arrays else n
        for _ in range(8):
            if got >= n:
                break
            more = self._verified(state, index, space.sample(rng, n - got))
            arrays = {k: np.concatenate([arrays[k], more[k]]) for k in arrays}
            got = next(iter(arrays.values())).shape[0] if arrays else n
        if got < n:
            raise NoLegalAction(
                "no legal joint action found in this state: every candidate the constraints "
                "allow was refused by the simulator"
            )
        return arrays

    def candidates(
        self, state: State, rng: np.random.Generator, limit: int, index: int = 0
    ) -> dict[str, Array]:
        """At most `limit` distinct legal joint actions of state `index`:
        all of them when there are few enough, else noop (when legal) and a
        uniform sample of the others."""
        space = self.space(state, index)
        space.require()
        if space.complete and space.count <= limit:
            return self._verified(state, index, space.rows(limit))
        noop = list(self.layout.defaults)
        rows: list[list[int]] = []
        seen: set[tuple[int, ...]] = set()
        noop_ok = bool(self.sim.check_actions(state[[index]], self.sim.noop(1))[0])
        if noop_ok:
            rows.append([int(x) for x in noop])
            seen.add(tuple(rows[0]))
        for _ in range(4):
            for row in space.sample(rng, 2 * limit):
                key = tuple(row)
                if key not in seen and len(rows) < limit:
                    seen.add(key)
                    rows.append(row)
            if len(rows) >= limit:
                break
        return self._verified(state, index, rows)

    def sample_batch(self, states: State, rng: np.random.Generator) -> dict[str, Array]:
        """One uniformly drawn legal joint action for every state of the
        batch. Raises `NoLegalAction` naming the first state without one."""
        batch = states.batch
        by_key: dict[bytes, list[int]] = {}
        for b in range(batch):
            by_key.setdefault(self.key(states, b), []).append(b)
        rows: list[list[int]] = [[] for _ in range(batch)]
        for members in by_key.values():
            space = self.space(states, members[0])
            if space.empty:
                raise NoLegalAction(f"state {members[0]} of the batch: {space.why_none}")
            for b, row in zip(members, space.sample(rng, len(members)), strict=True):
                rows[b] = row
        arrays = self.arrays(rows)
        ok = self.sim.check_actions(states, arrays)
        for bad in np.flatnonzero(~ok):
            one = self.sample(states, rng, 1, int(bad))
            for k in arrays:
                arrays[k][bad] = one[k][0]
        return arrays


_SOLVERS: weakref.WeakKeyDictionary[SimulatorView, LegalActions] = weakref.WeakKeyDictionary()


def solver_for(sim: SimulatorView) -> LegalActions:
    """The `LegalActions` of a simulator, made once and shared (with its
    cache) by everything that asks for it. Raises `LegalActionsUnsupported`
    for real-valued action fluents."""
    got = _SOLVERS.get(sim)
    if got is None:
        got = _SOLVERS[sim] = LegalActions(sim)
    return got
