"""The simulator: `Simulator`, the forward model of one RDDL instance.

Owns the `Simulator` class: the instance's arrays (non-fluents, action
defaults, the initial state), the generated functions (compiled by `build`
when first needed and kept: the step for small batches at once, the step
for large batches and for one state, the constraint checks), `step`, the
step in two parts (`prepare` / `finish`, by `prestep`'s split of the
one-state step), the errors the generated code raises through it
(`_fail_*`), and the wire form of states and actions as names
(`state_to_names`, `actions_to_names`, `actions_from_names`). Choosing
actions (`random_actions`, `legal_actions`) is in `actions`.

May call `build`, `compiler`, `order`, `prestep`, `actions`, `code`, `runtime` and
`state`; nothing in the package calls it but through a `Simulator`.
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np

from .. import ast as A
from ..model import ACTION, DERIVED, INTERM, NON_FLUENT, OBSERV, STATE, Model, PVariable, Value
from .actions import legal_actions, random_actions
from .build import build_constraints, build_step
from .code import _DTYPES, _LARGE_BATCH
from .compiler import _Compiler
from .order import _order_cpfs
from .prestep import POST_NAME, PRE_NAME, split_step_source
from .runtime import _quietly
from .state import Array, Prepared, SimulationError, State, Step, _make_step

_UNBUILT = object()


def _text(expr: A.Expr, limit: int = 160) -> str:
    from ..writer import write_expr

    text = write_expr(expr)
    return text if len(text) <= limit else text[: limit - 3] + "..."


class Simulator:
    """The forward model of one RDDL instance, stepping batches of states.

    >>> sim = Simulator(model)
    >>> s = sim.initial_state(batch=4)
    >>> out = sim.step(s, sim.noop(4), np.random.default_rng(0))
    """

    def __init__(self, model: Model):
        self.model = model
        self._compiler = _Compiler(model)
        self.state_fluents = model.fluents(STATE)
        self.action_fluents = model.fluents(ACTION)
        self.observ_fluents = model.fluents(OBSERV)
        self.non_fluents = model.fluents(NON_FLUENT)
        self.interm_fluents = [p for p in model.pvariables.values() if p.kind in (INTERM, DERIVED)]

        self._nf_values = {p.name: self._initial_array(p)[None] for p in self.non_fluents}
        self._defaults = {p.name: self._default_array(p) for p in self.action_fluents}
        self._initial = {p.name: self._initial_array(p) for p in self.state_fluents}
        self._action_names = [p.name for p in self.action_fluents]
        self._noop_views: dict[int, dict[str, Array]] = {}

        # Every cpf in an order that respects what it reads: by level and
        # kind (interm, next state, observation) where possible, as rddlsim
        # does, and by dependency where a domain reads a fluent computed
        # later (pyRDDLGym's levels-free style).
        self._cpf_order = _order_cpfs(model)
        dom = model.domain
        self._preconditions = [*dom.action_preconditions, *dom.state_action_constraints]
        self._invariants = list(dom.state_invariants)
        self._terminations = list(dom.termination)
        self._nf_nodes = {
            p.name: (self._compiler.const(self._nf_values[p.name][0][..., None], p.range), None)
            for p in self.non_fluents
        }
        self._lock = threading.Lock()  # the compiler is not reentrant
        self._step_small = build_step(self, large=False)
        # compiled when first needed
        self._compiled: dict[str, Callable[..., Any]] = {}
        self._step_one: Callable[..., Any] | None = None  # (`_step_fn(1)`)

    # -- values ------------------------------------------------------

    def _dtype(self, p: PVariable) -> Any:
        return _DTYPES.get(p.range, np.int64)

    def _encode(self, p: PVariable, value: Value) -> Any:
        if p.range in self._compiler.codes:
            return self._compiler.codes[p.range][value]  # type: ignore[index]
        return value

    def _default_array(self, p: PVariable) -> Array:
        shape = self._compiler.shape_of(p)
        return np.full(shape, self._encode(p, self.model.default_of(p)), dtype=self._dtype(p))

    def _initial_array(self, p: PVariable) -> Array:
        arr = self._default_array(p)
        values = self.model.non_fluent_values if p.kind == NON_FLUENT else self.model.init_state
        for (name, args), value in values.items():
            if name == p.name:
                idx = tuple(self._compiler.codes[t][a] for t, a in zip(p.params, args, strict=True))
                arr[idx] = self._encode(p, value)
        return arr

    def initial_state(self, batch: int = 1) -> State:
        """The instance's initial state, repeated `batch` times."""
        # laid out batch last in memory, as `step` makes its states
        return State(
            {
                k: np.moveaxis(np.repeat(v[..., None], batch, axis=-1), -1, 0)
                for k, v in self._initial.items()
            }
        )

    def noop(self, batch: int = 1) -> dict[str, Array]:
        """Every action at its default, for a batch."""
        return {k: np.repeat(v[None], batch, axis=0) for k, v in self._defaults.items()}

    # -- compiling -----------------------------------------------------

    def _step_fn(self, batch: int) -> Callable[..., Any]:
        """The step function for this batch size (all make the same draws
        and compute the same values)."""
        if batch == 1:
            return self._step_one or self._function("_step_one")
        if batch < _LARGE_BATCH:
            return self._step_small
        return self._function("_step_large")

    def _function(self, name: str) -> Callable[..., Any]:
        """A generated function, compiled on first use: `_step_large`,
        `_step_one`, `_legal`, `_legal_large` or `_check`."""
        fn = self._compiled.get(name)
        if fn is None:
            with self._lock:
                fn = self._compiled.get(name)
                if fn is None:
                    if name == "_step_large":
                        fn = build_step(self, large=True)
                    elif name == "_step_one":
                        fn = self._step_one = build_step(self, large=False, one=True)
                    else:
                        fn = build_constraints(
                            self, name, explain=name == "_check", large=name.endswith("_large")
                        )
                    self._compiled[name] = fn
        return fn

    def _legal_fn(self, batch: int) -> Callable[..., Any]:
        """The function of the preconditions' mask for this batch size."""
        return self._function("_legal" if batch < _LARGE_BATCH else "_legal_large")

    def source(self) -> str:
        """The generated code of the step, for reading (and debugging)."""
        return "\n".join(self._compiler.sources.values())

    # -- failures (called from the generated code) ---------------------

    def _fail_nondef(self, actions: Mapping[str, Array], batch: int) -> None:
        limit = self.model.max_nondef_actions
        n = self.count_nondefault(actions, batch)
        if limit is not None and np.any(n > limit):
            i = int(np.argmax(n > limit))
            raise SimulationError(
                f"{int(n[i])} actions differ from their default, max-nondef-actions is {limit}: "
                f"{', '.join(self.actions_to_names(actions, i)) or 'noop'}"
            )

    def _fail_precondition(
        self, k: int, holds: Array, actions: Mapping[str, Array], batch: int
    ) -> None:
        expr = self._preconditions[k]
        ok = np.broadcast_to(np.asarray(holds, dtype=bool).reshape(-1), (batch,))
        i = int(np.argmin(ok))
        acts = ", ".join(self.actions_to_names(actions, i)) or "noop"
        raise SimulationError(
            f"{expr.loc}: constraint violated (state {i} of the batch): {_text(expr)}; actions: {acts}"
        )

    def _fail_invariant(self, k: int, holds: Array, batch: int) -> None:
        expr = self._invariants[k]
        ok = np.broadcast_to(np.asarray(holds, dtype=bool).reshape(-1), (batch,))
        raise SimulationError(
            f"{expr.loc}: state invariant violated (state {int(np.argmin(ok))} of the batch): {_text(expr)}"
        )

    # -- the step ----------------------------------------------------

    def _noop_view(self, batch: int) -> dict[str, Array]:
        views = self._noop_views.get(batch)
        if views is None:
            if len(self._noop_views) > 16:
                self._noop_views.clear()
            views = {k: np.broadcast_to(v, (batch, *v.shape)) for k, v in self._defaults.items()}
            self._noop_views[batch] = views
        return views

    def _actions(self, actions: Mapping[str, Array] | None, batch: int) -> dict[str, Array]:
        """Every action fluent's array, shaped (batch, *params): the given
        ones, and (read-only) defaults for the others."""
        if not actions:
            return self._noop_view(batch)
        out = {}
        views = None
        for name in self._action_names:
            a = actions.get(name)
            if a is None:
                if views is None:
                    views = self._noop_view(batch)
                a = views[name]
            elif type(a) is not np.ndarray or a.ndim == 0 or a.shape[0] != batch:
                a = np.asarray(a)
                if a.ndim and a.shape[0] != batch:
                    a = np.broadcast_to(a, (batch, *a.shape[1:]))
            out[name] = a
        return out

    def count_nondefault(self, actions: Mapping[str, Array], batch: int) -> Array:
        """How many grounded actions differ from their default, per state."""
        n = np.zeros(batch, dtype=np.int64)
        for p in self.action_fluents:
            a = actions.get(p.name)
            if a is None:
                continue
            diff = np.asarray(a) != self._defaults[p.name]
            n += diff.reshape(diff.shape[0], int(np.prod(diff.shape[1:]))).sum(axis=1)
        return n

    def check_actions(self, state: State, actions: Mapping[str, Array]) -> Array:
        """A (batch,) mask of the states where the actions are legal:
        max-nondef-actions, action-preconditions, state-action-constraints."""
        batch = state.batch
        ok = np.ones(batch, dtype=bool)
        limit = self.model.max_nondef_actions
        if limit is not None:
            ok &= self.count_nondefault(actions, batch) <= limit
        ok &= _quietly(self._legal_fn(batch), state.values, self._actions(actions, batch), batch)
        return ok

    def step(
        self,
        state: State,
        actions: Mapping[str, Array] | None,
        rng: np.random.Generator,
        check: bool = True,
    ) -> Step:
        """One transition for every state of the batch.

        `actions` maps action fluent names to arrays shaped (batch, *params)
        (missing names take their default). With `check`, an illegal action
        or a violated state invariant raises `SimulationError`.
        """
        values = state.values
        batch = 1
        for v in values.values():
            batch = v.shape[0]
            break
        # (`_step_fn` and `State.batch` written out: a small step is a few
        # microseconds, and each call costs a measurable part of it)
        if batch == 1:
            fn = self._step_one or self._function("_step_one")
        elif batch < _LARGE_BATCH:
            fn = self._step_small
        else:
            fn = self._function("_step_large")
        return _make_step(*_quietly(fn, values, self._actions(actions, batch), batch, rng, check))

    # -- a step in two parts (see `prestep`) -------------------------

    def _split_one(self) -> tuple[Callable[..., Any], Callable[..., Any]] | None:
        """The pre and post parts of the one-state step, or None."""
        got: Any = self._compiled.get("_split_one", _UNBUILT)
        if got is _UNBUILT:
            self._step_one or self._function("_step_one")
            with self._lock:
                got = self._compiled.get("_split_one", _UNBUILT)
                if got is _UNBUILT:
                    got = None
                    split = split_step_source(self._compiler.sources["_step_one"])
                    if split is not None:
                        pre_src, post_src, _ = split
                        got = (
                            self._compiler.define(PRE_NAME, pre_src),
                            self._compiler.define(POST_NAME, post_src),
                        )
                    self._compiled["_split_one"] = got
        return got  # type: ignore[no-any-return]

    def prepare(self, state: State, rng: np.random.Generator) -> Prepared | None:
        """Compute ahead what the next step of `state` (one state) does not
        need its actions for: its random draws, and every value that depends
        on the state and the draws alone. `finish` completes the step when
        the actions are known; `unprepare` gives the draws back if it never
        happens. `finish(prepare(state, rng), actions)` equals `step(state,
        actions, rng)` exactly, and leaves `rng` where the step leaves it.

        None (and `rng` untouched) for a batch of several states, when every
        part of the step needs the actions, or when the part computed ahead
        raised: `step` then computes (or raises) as usual."""
        split = self._split_one()
        if split is None or state.batch != 1:
            return None
        bitgen = rng.bit_generator
        saved = bitgen.state
        try:
            values = _quietly(split[0], state.values, 1, rng)
        except Exception:  # noqa: BLE001 - the step itself raises it, in its place
            bitgen.state = saved
            return None
        return Prepared(state, values, saved)

    def finish(
        self, prepared: Prepared, actions: Mapping[str, Array] | None, check: bool = True
    ) -> Step:
        """The step `prepared` was made for, with these actions (as `step`
        takes them). A step that raises may leave the generator further on
        than `step` would have (its draws were made ahead)."""
        split = self._split_one()
        assert split is not None
        return _make_step(
            *_quietly(
                split[1],
                prepared.state.values,
                self._actions(actions, 1),
                1,
                check,
                *prepared.values,
            )
        )

    @staticmethod
    def unprepare(prepared: Prepared, rng: np.random.Generator) -> None:
        """Put `rng` back where it was before `prepare` drew for a step that
        will not happen (so the next step draws what it would have drawn)."""
        rng.bit_generator.state = prepared.rng_state

    def _check_preconditions(self, state: State, actions: Mapping[str, Array]) -> None:
        """Raise `SimulationError` for the first constraint the actions
        violate in the states of `state` (max-nondef-actions, then the
        preconditions in order)."""
        batch = state.batch
        _quietly(self._function("_check"), state.values, self._actions(actions, batch), batch)

    # -- action choice (see `actions`) --------------------------------

    def random_actions(self, state: State, rng: np.random.Generator) -> dict[str, Array]:
        """Random legal actions for every state of the batch, in the manner of
        rddlsim's RandomConcurrentPolicy (at most max-nondef-actions and
        `RANDOM_MAX_CONCURRENT`), with a uniform legal draw where that finds
        nothing (see `sim.actions.random_actions`)."""
        return random_actions(self, state, rng)

    def legal_actions(self, state: State, index: int = 0, limit: int = 100_000) -> dict[str, Array]:
        """Every legal joint action of the state at `index` (bool, enum and
        int action fluents), stacked along the batch axis, noop first when
        legal; `TooManyActions` above `limit` (see `ippc.rddl.legal`)."""
        return legal_actions(self, state, index, limit)

    # -- wire form ---------------------------------------------------

    def _decode(self, p: PVariable, x: Any) -> Value:
        if p.range in self._compiler.codes:
            return self.model.types[p.range].members[int(x)]
        if p.range == "bool":
            return bool(x)
        if p.range == "int":
            return int(x)
        return float(x)

    def _ground(self, p: PVariable) -> Iterable[tuple[tuple[str, ...], tuple[int, ...]]]:
        members = [self.model.types[t].members for t in p.params]
        for idx in itertools.product(*(range(len(m)) for m in members)):
            yield tuple(m[i] for m, i in zip(members, idx, strict=True)), idx

    def state_to_names(self, state: State, index: int = 0) -> dict[str, Value]:
        """The state at `index` as {'name(arg1,arg2)': value} (every grounding)."""
        out: dict[str, Value] = {}
        for p in self.state_fluents:
            arr = state.values[p.name][index]
            for args, idx in self._ground(p):
                out[_wire_name(p.name, args)] = self._decode(p, arr[idx])
        return out

    def actions_to_names(self, actions: Mapping[str, Array], index: int = 0) -> list[str]:
        """The non-default actions at `index` as 'name(args) = value' strings."""
        out = []
        for p in self.action_fluents:
            a = actions.get(p.name)
            if a is None:
                continue
            arr = np.asarray(a)[index]
            default = self._defaults[p.name]
            for args, idx in self._ground(p):
                if arr[idx] != default[idx]:
                    out.append(
                        f"{_wire_name(p.name, args)} = {_wire_value(self._decode(p, arr[idx]))}"
                    )
        return out

    def actions_from_names(
        self,
        named: Iterable[Mapping[tuple[str, tuple[str, ...]], Value]]
        | Mapping[tuple[str, tuple[str, ...]], Value],
    ) -> dict[str, Array]:
        """Action arrays from {(name, (args...)): value} maps, one per batch
        element (a single map gives a batch of one)."""
        batches = [named] if isinstance(named, Mapping) else list(named)
        out = self.noop(len(batches))
        for b, mapping in enumerate(batches):
            for (name, args), value in mapping.items():
                p = self.model.pvariables.get(name)
                if p is None or p.kind != ACTION:
                    raise SimulationError(f"'{name}' is not an action fluent")
                if len(args) != p.arity:
                    raise SimulationError(f"'{name}' takes {p.arity} argument(s), not {len(args)}")
                try:
                    idx = tuple(
                        self._compiler.codes[t][a] for t, a in zip(p.params, args, strict=True)
                    )
                except KeyError as err:
                    raise SimulationError(f"'{name}{args}': unknown object {err}") from None
                if p.range in self._compiler.codes:
                    v = (
                        value
                        if isinstance(value, str) and value in self._compiler.codes[p.range]
                        else "@" + str(value).lstrip("@")
                    )
                    if v not in self._compiler.codes[p.range]:
                        raise SimulationError(f"'{name}': '{value}' is not a value of '{p.range}'")
                    out[name][(b, *idx)] = self._compiler.codes[p.range][v]
                else:
                    out[name][(b, *idx)] = value
        return out


def _wire_name(name: str, args: tuple[str, ...]) -> str:
    return f"{name}({','.join(args)})" if args else name


def _wire_value(v: Value) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    return str(v)
