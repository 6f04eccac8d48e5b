"""Reward locks: states where the reward can no longer change (PROST's
dead ends and goals), for the wave engine's leaves (option reward_locks).

Reward locks (`RewardLocks`): a state is a reward lock when the reward can
no longer change whatever happens: a dead end (the reward is at its minimum
forever) or a goal (at its maximum forever). The check is PROST's on a
*Kleene state* (each state fluent grounding holds a set of values, here an
interval [lo, hi], the hull of the set; for booleans {0}, {1} or {0, 1}):
the model's cpfs and reward are evaluated in three-valued (interval)
arithmetic, every random draw giving the hull of its support, and the
Kleene successor of a Kleene state S is S joined with every value the cpfs
can take from S. A state is a *dead end* when its reward under noop is the
minimum and, from its Kleene state to the fixpoint of the successor under
every joint action of the table, the reward's interval under every action
is that single minimum; a *goal* when its reward under noop (the goal-test
action: row 0 of the table) is the maximum and stays the single maximum to
the fixpoint of noop's successor. By default the actions of a dead-end
check are applied all at once (the hull of the table's values: one
evaluation per iteration; `per_action=True` applies them one by one as
PROST does: more precise where actions exclude each other, |table| times
the cost). The over-approximation makes both answers sound (a state
reported as a lock is one) and incomplete (some locks are missed:
intervals lose the correlations between fluents, and a goal is only found
where noop keeps it). Limits: the minimum and maximum are the reward's
interval over every value each fluent's range allows (PROST uses its
reward formula's min and max the same way), so a reward without finite
bounds (real fluents) has no locks; the preconditions are ignored (more
actions: still sound); an int or real fluent's interval is wider than
PROST's value sets, and one that keeps growing makes the check give up
after `max_iterations`; domains whose enums count as numbers (@1, @2),
vector distributions and matrix functions are not checked (no lock).
Cost: one interval evaluation of the model per iteration, about a
millisecond on IPPC 2011 instances, and one iteration per step of the
widest path the fixpoint explores; answers are cached by state.

May call the simulator's public methods; nothing of the search.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from ...rddl import ast as A
from ...rddl.model import Model
from ...rddl.simulator import Simulator, State
from .rows import row_bytes

__all__ = ["RewardLocks"]

log = logging.getLogger(__name__)

Array = np.ndarray


class _Unsupported(Exception):
    pass


class RewardLocks:
    """Dead ends and goals by PROST's check on Kleene states, in interval
    arithmetic (see the module docstring for what it finds and misses)."""

    def __init__(
        self,
        model: Model,
        table: Mapping[str, Array],
        max_iterations: int = 64,
        per_action: bool = False,
    ):
        self.model = model
        self.sim = Simulator(model)
        self.table = {k: np.asarray(v) for k, v in table.items()}
        self.per_action = per_action
        # every action of the table at once: the hull of their values
        self._hull = {
            k: (v.min(axis=0).astype(np.float64), v.max(axis=0).astype(np.float64))
            for k, v in self.table.items()
        }
        self.n_actions = next(iter(self.table.values())).shape[0] if self.table else 1
        self.max_iterations = max_iterations
        self.gamma = 1.0 if model.discount is None else float(model.discount)
        self._cache: dict[bytes, str | None] = {}
        self.max_cache = 100_000
        self.supported = True
        try:
            self._eval = _Interval(model, self.sim)
            lo, hi = self._full_reward_range()
        except _Unsupported as err:
            log.info("reward locks: %s: not checked (%s)", model.name, err)
            self.supported = False
            lo, hi = -math.inf, math.inf
        self.min_reward, self.max_reward = lo, hi

    def _full_reward_range(self) -> tuple[float, float]:
        state = {p.name: self._eval.full_range(p) for p in self.sim.state_fluents}
        acts = {p.name: self._eval.full_range(p) for p in self.sim.action_fluents}
        _, (rlo, rhi) = self._eval.transition(state, acts)
        return float(rlo), float(rhi)

    def _kleene(self, state: State) -> dict[str, tuple[Array, Array]]:
        out = {}
        for p in self.sim.state_fluents:
            v = state.values[p.name][0].astype(np.float64)
            out[p.name] = (v, v.copy())
        return out

    def _action(self, row: int) -> dict[str, tuple[Array, Array]]:
        return {
            k: (v[row].astype(np.float64), v[row].astype(np.float64)) for k, v in self.table.items()
        }

    @staticmethod
    def _join(
        a: dict[str, tuple[Array, Array]], b: dict[str, tuple[Array, Array]]
    ) -> dict[str, tuple[Array, Array]]:
        return {k: (np.minimum(a[k][0], b[k][0]), np.maximum(a[k][1], b[k][1])) for k in a}

    @staticmethod
    def _same(a: dict[str, tuple[Array, Array]], b: dict[str, tuple[Array, Array]]) -> bool:
        return all(np.array_equal(a[k][0], b[k][0]) and np.array_equal(a[k][1], b[k][1]) for k in a)

    def check(self, state: State, steps_left: int | None = None) -> str | None:
        """'dead end', 'goal' or None for one state (batch of one); the
        answers are cached by the state's bytes (and `steps_left`).

        With `steps_left`, a lock for the rest of a finite horizon: the
        reward cannot change within the next `steps_left` steps (a dead end
        is then worth the minimum reward every step left, a goal the
        maximum while noop is applied). The check then stops after that
        many successors, which is all it costs near the horizon, and finds
        more (a state that could leave the lock only later)."""
        key = row_bytes(state.values, 1).tobytes() + (
            -1 if steps_left is None else steps_left
        ).to_bytes(8, "little", signed=True)
        if key in self._cache:
            return self._cache[key]
        found = self._check(state, steps_left)
        if len(self._cache) >= self.max_cache:
            self._cache.clear()
        self._cache[key] = found
        return found

    def _check(self, state: State, steps_left: int | None) -> str | None:
        if (
            not self.supported
            or not math.isfinite(self.min_reward)
            or not math.isfinite(self.max_reward)
        ):
            return None
        if self.min_reward == self.max_reward:
            return None  # a constant reward: nothing to lock
        try:
            ks = self._kleene(state)
            _, (lo, hi) = self._eval.transition(ks, self._action(0))
            if lo == hi == self.min_reward:
                return "dead end" if self._dead_end(ks, steps_left) else None
            if lo == hi == self.max_reward:
                return "goal" if self._goal(ks, steps_left) else None
        except _Unsupported as err:
            log.debug("reward locks: %s", err)
        return None

    def _limit(self, steps_left: int | None) -> tuple[int, bool]:
        """How many successors to check, and whether checking them all
        without a change proves the lock (the horizon is within reach)."""
        if steps_left is None or steps_left > self.max_iterations:
            return self.max_iterations, False
        return max(steps_left, 1), True

    def _dead_end(self, ks: dict[str, tuple[Array, Array]], steps_left: int | None = None) -> bool:
        limit, enough = self._limit(steps_left)
        for _ in range(limit):
            merged = ks
            rows = range(self.n_actions) if self.per_action else [-1]
            for row in rows:
                acts = self._hull if row < 0 else self._action(row)
                nxt, (lo, hi) = self._eval.transition(ks, acts)
                if not (lo == hi == self.min_reward):
                    return False
                merged = self._join(merged, nxt)
            if self._same(merged, ks):
                return True
            ks = merged
        return enough

    def _goal(self, ks: dict[str, tuple[Array, Array]], steps_left: int | None = None) -> bool:
        limit, enough = self._limit(steps_left)
        for _ in range(limit):
            nxt, (lo, hi) = self._eval.transition(ks, self._action(0))
            if not (lo == hi == self.max_reward):
                return False
            merged = self._join(ks, nxt)
            if self._same(merged, ks):
                return True
            ks = merged
        return enough


_Iv = tuple[Array, Array]  # elementwise lower and upper bounds

_BOOL_OPS = ("^", "&", "|", "=>", "<=>")


def _fix(lo: Array, hi: Array) -> _Iv:
    """Bounds with NaN (inf - inf, 0 * inf) widened to the whole line."""
    lo = np.where(np.isnan(lo), -np.inf, lo)
    hi = np.where(np.isnan(hi), np.inf, hi)
    return lo, hi


def _truth(x: _Iv) -> _Iv:
    """The truth value of a number's interval: 1 where 0 is outside it, 0
    where it is exactly 0, else unknown [0, 1]."""
    lo, hi = x
    surely = (lo > 0) | (hi < 0)
    never = (lo == 0) & (hi == 0)
    return surely.astype(np.float64), (~never).astype(np.float64)


class _Interval:
    """The model's cpfs and reward in interval arithmetic over grounded
    arrays (the Kleene evaluation of `RewardLocks`): every value is a pair
    of arrays (lower, upper bounds), one axis per variable in scope. Sound:
    every value a concrete step can produce lies within the bounds.
    Constructs it cannot bound give the whole line, those it cannot
    evaluate at all raise `_Unsupported`."""

    def __init__(self, model: Model, sim: Simulator):
        from ...rddl.model import ACTION, NON_FLUENT, OBSERV, STATE

        self.model = model
        self.kinds = {"state": STATE, "action": ACTION, "observ": OBSERV}
        self.codes = {
            t: {m: i for i, m in enumerate(info.members)} for t, info in model.types.items()
        }
        self.sizes = {t: len(info.members) for t, info in model.types.items()}
        for t, info in model.types.items():
            if (
                info.kind == "enum"
                and info.members
                and all(m.startswith("@") and m[1:].lstrip("-").isdigit() for m in info.members)
            ):
                # (enums counted as numbers in arithmetic: not modelled here)
                raise _Unsupported(f"enum '{t}' with integer values")
        self.object_code: dict[str, int] = {}
        for codes in self.codes.values():
            for m, i in codes.items():
                self.object_code.setdefault(m, i)
        self.nf = {
            p.name: sim._initial_array(p).astype(np.float64) for p in model.fluents(NON_FLUENT)
        }
        self.order = sim._cpf_order
        self.defaults = {
            p.name: sim._default_array(p).astype(np.float64) for p in model.pvariables.values()
        }

    def full_range(self, p: object) -> _Iv:
        """Every value a fluent's range allows, per grounding."""
        shape = tuple(self.sizes[t] for t in p.params)  # type: ignore[attr-defined]
        rng = p.range  # type: ignore[attr-defined]
        if rng == "bool":
            lo, hi = 0.0, 1.0
        elif rng in self.sizes:
            lo, hi = 0.0, float(self.sizes[rng] - 1)
        else:
            lo, hi = -math.inf, math.inf
        return np.full(shape, lo), np.full(shape, hi)

    def transition(
        self, state: Mapping[str, _Iv], actions: Mapping[str, _Iv]
    ) -> tuple[dict[str, _Iv], tuple[float, float]]:
        """(the bounds of the next state, the bounds of the reward) from the
        bounds of the state and the actions."""
        from ...rddl.model import OBSERV, STATE

        env: dict[str, _Iv] = {**state, **actions}
        nxt: dict[str, _Iv] = {}
        for key in self.order:
            p = self.model.pvariables[key.rstrip("'")]
            if p.kind == OBSERV:
                continue
            cp = self.model.cpfs[p.name]
            scope = tuple(zip(cp.params, p.params, strict=True))
            lo, hi = self.ev(cp.expr, scope, env)
            shape = tuple(self.sizes[t] for t in p.params)
            val = (np.broadcast_to(lo, shape).copy(), np.broadcast_to(hi, shape).copy())
            if p.kind == STATE:
                nxt[p.name] = val
                env[p.name + "'"] = val
            else:
                env[p.name] = val
        if self.model.reward is None:
            return nxt, (0.0, 0.0)
        lo, hi = self.ev(self.model.reward, (), env)
        return nxt, (float(np.min(lo)), float(np.max(hi)))

    # -- expressions -------------------------------------------------------

    def _point(self, value: float, scope: tuple[tuple[str, str], ...]) -> _Iv:
        v = np.full((1,) * len(scope), float(value))
        return v, v

    def _code_of(self, name: str, hint: str | None = None) -> int:
        if hint in self.codes and name in self.codes[hint]:
            return self.codes[hint][name]  # type: ignore[index]
        if name in self.object_code:
            return self.object_code[name]
        if "@" + name in self.object_code:
            return self.object_code["@" + name]
        raise _Unsupported(f"unknown object '{name}'")

    def ev(self, e: A.Expr, scope: tuple[tuple[str, str], ...], env: Mapping[str, _Iv]) -> _Iv:
        rank = len(scope)
        if isinstance(e, A.Const):
            return self._point(float(e.value), scope)
        if isinstance(e, (A.EnumLit, A.ObjectLit)):
            return self._point(self._code_of(e.name), scope)
        if isinstance(e, A.Var):
            names = [v for v, _ in scope]
            if e.name not in names:
                raise _Unsupported(f"free variable {e.name}")
            i = max(j for j, v in enumerate(names) if v == e.name)
            shape = [1] * rank
            shape[i] = self.sizes[scope[i][1]]
            v = np.arange(shape[i], dtype=np.float64).reshape(shape)
            return v, v
        if isinstance(e, A.PVar):
            return self._pvar(e, scope, env)
        if isinstance(e, A.Unary):
            lo, hi = self.ev(e.operand, scope, env)
            if e.op == "~":
                tl, th = _truth((lo, hi))
                return 1.0 - th, 1.0 - tl
            if e.op == "-":
                return -hi, -lo
            return lo, hi
        if isinstance(e, A.Binary):
            return self._binary(e, scope, env)
        if isinstance(e, A.If):
            c = _truth(self.ev(e.cond, scope, env))
            t = self.ev(e.then, scope, env)
            f = self.ev(e.else_, scope, env)
            lo = np.where(c[0] == 1, t[0], np.where(c[1] == 0, f[0], np.minimum(t[0], f[0])))
            hi = np.where(c[0] == 1, t[1], np.where(c[1] == 0, f[1], np.maximum(t[1], f[1])))
            return lo, hi
        if isinstance(e, A.Switch):
            return self._switch(e, scope, env)
        if isinstance(e, A.Aggregation):
            return self._aggregation(e, scope, env)
        if isinstance(e, A.Function):
            return self._function(e, scope, env)
        if isinstance(e, A.Distribution):
            return self._distribution(e, scope, env)
        if isinstance(e, A.Discrete):
            codes: list[int] = []
            for case in e.cases:
                if not isinstance(case.label, (A.EnumLit, A.ObjectLit, A.PVar)):
                    raise _Unsupported("a Discrete label that is not a value")
                codes.append(self._code_of(case.label.name, e.type))
            return self._point(min(codes), scope)[0], self._point(max(codes), scope)[0]
        if isinstance(e, A.DiscreteOver):
            n = 1
            for tv in e.params:
                n *= self.sizes[tv.type]
            return self._point(0, scope)[0], self._point(n - 1, scope)[0]
        raise _Unsupported(type(e).__name__)

    def _pvar(self, e: A.PVar, scope: tuple[tuple[str, str], ...], env: Mapping[str, _Iv]) -> _Iv:
        p = self.model.pvariables.get(e.name)
        if p is None:
            return self._point(self._code_of(e.name), scope)
        rank = len(scope)
        if e.default:
            d = self.defaults[p.name]
            return self._point(float(d.flat[0]) if d.size else 0.0, scope)
        key = p.name + ("'" if e.primed else "")
        if key in env:
            lo, hi = env[key]
        elif p.name in self.nf:
            lo = hi = self.nf[p.name]
        else:
            raise _Unsupported(f"'{key}' read before it is computed")
        if not e.args:
            return lo.reshape((1,) * rank), hi.reshape((1,) * rank)
        idx = []
        for a, t in zip(e.args, p.params, strict=True):
            if isinstance(a, (A.EnumLit, A.ObjectLit)):
                idx.append(np.full((1,) * rank, self._code_of(a.name, t), dtype=np.int64))
            elif isinstance(a, A.PVar) and a.name not in self.model.pvariables:
                idx.append(np.full((1,) * rank, self._code_of(a.name, t), dtype=np.int64))
            else:
                alo, ahi = self.ev(a, scope, env)
                if not np.array_equal(alo, ahi) or not np.isfinite(alo).all():
                    # an index not known: any grounding of this argument
                    return (
                        np.full((1,) * rank, float(lo.min()) if lo.size else 0.0),
                        np.full((1,) * rank, float(hi.max()) if hi.size else 0.0),
                    )
                idx.append(alo.astype(np.int64))
        return lo[tuple(idx)], hi[tuple(idx)]

    def _binary(
        self, e: A.Binary, scope: tuple[tuple[str, str], ...], env: Mapping[str, _Iv]
    ) -> _Iv:
        a = self.ev(e.left, scope, env)
        b = self.ev(e.right, scope, env)
        op = e.op
        if op in ("^", "&", "|", "=>", "<=>"):
            x, y = _truth(a), _truth(b)
            if op in ("^", "&"):
                return np.minimum(x[0], y[0]), np.minimum(x[1], y[1])
            if op == "|":
                return np.maximum(x[0], y[0]), np.maximum(x[1], y[1])
            if op == "=>":
                return np.maximum(1 - x[1], y[0]), np.maximum(1 - x[0], y[1])
            # <=>: surely equal where both are known and equal
            known = (x[0] == x[1]) & (y[0] == y[1])
            eq = known & (x[0] == y[0])
            ne = known & (x[0] != y[0])
            return eq.astype(np.float64), (~ne).astype(np.float64)
        (alo, ahi), (blo, bhi) = a, b
        with np.errstate(all="ignore"):
            if op == "+":
                return _fix(alo + blo, ahi + bhi)
            if op == "-":
                return _fix(alo - bhi, ahi - blo)
            if op == "*":
                ps = [alo * blo, alo * bhi, ahi * blo, ahi * bhi]
                ps = [np.where(np.isnan(p), 0.0, p) for p in ps]  # 0 * inf
                return np.minimum.reduce(ps), np.maximum.reduce(ps)
            if op == "/":
                zero = (blo <= 0) & (bhi >= 0)
                qs = [alo / blo, alo / bhi, ahi / blo, ahi / bhi]
                lo, hi = _fix(np.minimum.reduce(qs), np.maximum.reduce(qs))
                return np.where(zero, -np.inf, lo), np.where(zero, np.inf, hi)
        if op == "==":
            surely = (alo == ahi) & (blo == bhi) & (alo == blo)
            never = (ahi < blo) | (bhi < alo)
            return surely.astype(np.float64), (~never).astype(np.float64)
        if op == "~=":
            surely = (ahi < blo) | (bhi < alo)
            never = (alo == ahi) & (blo == bhi) & (alo == blo)
            return surely.astype(np.float64), (~never).astype(np.float64)
        if op in ("<", "<=", ">", ">="):
            if op in (">", ">="):
                (alo, ahi), (blo, bhi) = (blo, bhi), (alo, ahi)
                op = "<" if op == ">" else "<="
            if op == "<":
                surely, never = ahi < blo, alo >= bhi
            else:
                surely, never = ahi <= blo, alo > bhi
            return surely.astype(np.float64), (~never).astype(np.float64)
        raise _Unsupported(f"operator {op}")

    def _switch(
        self, e: A.Switch, scope: tuple[tuple[str, str], ...], env: Mapping[str, _Iv]
    ) -> _Iv:
        slo, shi = self.ev(e.subject, scope, env)
        lo: Array | None = None
        hi: Array | None = None
        covered = np.zeros(np.broadcast_shapes(slo.shape, shi.shape), dtype=bool)
        default: _Iv | None = None
        for case in e.cases:
            v = self.ev(case.value, scope, env)
            if case.label is None:
                default = v
                continue
            label = case.label
            if isinstance(label, (A.EnumLit, A.ObjectLit)) or (
                isinstance(label, A.PVar) and label.name not in self.model.pvariables
            ):
                code = float(self._code_of(label.name))  # type: ignore[union-attr]
                clo = chi = self._point(code, scope)[0]
            else:
                clo, chi = self.ev(label, scope, env)
            possible = (slo <= chi) & (clo <= shi)
            covered = covered | ((slo == shi) & (clo == chi) & (slo == clo))
            cl = np.where(possible, v[0], np.inf)
            ch = np.where(possible, v[1], -np.inf)
            lo = cl if lo is None else np.minimum(lo, cl)
            hi = ch if hi is None else np.maximum(hi, ch)
        if default is not None:
            dl = np.where(covered, np.inf, default[0])
            dh = np.where(covered, -np.inf, default[1])
            lo = dl if lo is None else np.minimum(lo, dl)
            hi = dh if hi is None else np.maximum(hi, dh)
        if lo is None or hi is None:
            raise _Unsupported("an empty switch")
        # (no case possible: the step fails there; any bound will do)
        return np.where(np.isinf(lo) & (lo > 0), -np.inf, lo), np.where(
            np.isinf(hi) & (hi < 0), np.inf, hi
        )

    def _aggregation(
        self, e: A.Aggregation, scope: tuple[tuple[str, str], ...], env: Mapping[str, _Iv]
    ) -> _Iv:
        inner = scope + tuple((tv.name, tv.type) for tv in e.params)
        lo, hi = self.ev(e.body, inner, env)
        full = tuple(self.sizes[t] for _, t in inner)
        axes = tuple(range(len(scope), len(inner)))
        lo = np.broadcast_to(lo, np.broadcast_shapes(lo.shape, full))
        hi = np.broadcast_to(hi, np.broadcast_shapes(hi.shape, full))
        op = e.op
        with np.errstate(all="ignore"):
            if op == "sum":
                return _fix(lo.sum(axis=axes), hi.sum(axis=axes))
            if op == "avg":
                return _fix(lo.mean(axis=axes), hi.mean(axis=axes))
            if op in ("exists", "forall"):
                t = _truth((lo, hi))
                red = np.max if op == "exists" else np.min
                return red(t[0], axis=axes), red(t[1], axis=axes)
            if op == "min":
                return lo.min(axis=axes), hi.min(axis=axes)
            if op == "max":
                return lo.max(axis=axes), hi.max(axis=axes)
            if op == "prod" and (lo >= 0).all():
                return _fix(lo.prod(axis=axes), hi.prod(axis=axes))
        shape = tuple(self.sizes[t] for _, t in scope)
        if op in ("argmin", "argmax"):
            n = 1
            for tv in e.params:
                n *= self.sizes[tv.type]
            return np.zeros(shape), np.full(shape, float(n - 1))
        return np.full(shape, -np.inf), np.full(shape, np.inf)

    def _function(
        self, e: A.Function, scope: tuple[tuple[str, str], ...], env: Mapping[str, _Iv]
    ) -> _Iv:
        args = [self.ev(a, scope, env) for a in e.args]
        name = e.name
        f: Any
        with np.errstate(all="ignore"):
            if name in ("min", "max") and len(args) == 2:
                f = np.minimum if name == "min" else np.maximum
                return f(args[0][0], args[1][0]), f(args[0][1], args[1][1])
            if len(args) == 1:
                lo, hi = args[0]
                if name in ("exp", "floor", "ceil", "round", "atan", "sinh", "tanh"):
                    f = {"exp": np.exp, "floor": np.floor, "ceil": np.ceil, "round": np.round,
                         "atan": np.arctan, "sinh": np.sinh, "tanh": np.tanh}[name]  # fmt: skip
                    return _fix(f(lo), f(hi))
                if name == "abs":
                    a_lo = np.where((lo <= 0) & (hi >= 0), 0.0, np.minimum(abs(lo), abs(hi)))
                    return a_lo, np.maximum(abs(lo), abs(hi))
                if name == "sgn":
                    return np.sign(lo), np.sign(hi)
                if name in ("ln", "sqrt"):
                    f = np.log if name == "ln" else np.sqrt
                    ok = lo >= 0 if name == "sqrt" else lo > 0
                    return np.where(ok, f(np.where(ok, lo, 1.0)), -np.inf), np.where(
                        ok, f(np.where(ok, hi, 1.0)), np.inf
                    )
        for a in args:
            np.broadcast_shapes(a[0].shape)
        shape = np.broadcast_shapes(*(a[0].shape for a in args)) if args else (1,) * len(scope)
        return np.full(shape, -np.inf), np.full(shape, np.inf)

    def _distribution(
        self, e: A.Distribution, scope: tuple[tuple[str, str], ...], env: Mapping[str, _Iv]
    ) -> _Iv:
        args = [self.ev(a, scope, env) for a in e.args]
        name = e.name
        if name in ("KronDelta", "DiracDelta"):
            return args[0]
        if name == "Bernoulli":
            plo, phi = args[0]
            return (plo >= 1).astype(np.float64), (phi > 0).astype(np.float64)
        if name == "Uniform":
            return args[0][0], args[1][1]
        shape = np.broadcast_shapes(*(a[0].shape for a in args)) if args else (1,) * len(scope)
        if name in (
            "Poisson",
            "Binomial",
            "NegativeBinomial",
            "Geometric",
            "Exponential",
            "Gamma",
            "ChiSquare",
            "Weibull",
            "Pareto",
        ):
            lo = 0.0 if name != "Geometric" else 1.0
            hi = np.inf
            if name == "Binomial":
                return np.zeros(shape), np.broadcast_to(args[0][1], shape)
            return np.full(shape, lo), np.full(shape, hi)
        if name in ("Beta", "Kumaraswamy"):
            return np.zeros(shape), np.ones(shape)
        if name in ("Normal", "Laplace", "Cauchy", "Gumbel", "Student", "Gompertz"):
            return np.full(shape, -np.inf), np.full(shape, np.inf)
        raise _Unsupported(f"distribution {name}")
