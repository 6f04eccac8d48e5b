"""A vectorised RDDL simulator: `Model` -> numpy.

Theory of operation. Every pvariable is a tensor with a leading batch axis
and one axis per parameter (sized by its type's members), so a whole batch
of states is stepped at once. Enum and object values are integer codes
(their index in the range type's members). Each expression is compiled once
into a closure over numpy operations; an expression is compiled in a *scope*
(the typed variables free at that point, e.g. a cpf's parameters plus those
of enclosing aggregations), and its closure returns an array of rank
1 + len(scope): axis 0 is the batch, axis 1 + i the i-th scope variable;
any axis may have size 1 where the value does not depend on it, and numpy
broadcasting does the rest. Aggregations evaluate their body in a wider
scope and reduce the extra axes. No Python loop runs over groundings at
step time.

Semantics follow rddlsim: interm and derived fluents in level order (then
declaration order), then next-state cpfs, then observations (which may read
the next state); the reward of the transition sees the current state, the
actions, the intermediates and the next state; actions not given take their
default; `/` is real division; bools count as 0/1 in arithmetic; enum values
with integer names (@1) count as that integer in arithmetic;
action-preconditions and state-action-constraints are checked on the
current state and actions before the step, max-nondef-actions counts the
actions that differ from their default, and state-invariants are checked on
the next state. `termination` (pyRDDLGym) ends an episode when it holds.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import ast as A
from .model import ACTION, DERIVED, INTERM, NON_FLUENT, OBSERV, STATE, Model, PVariable, Value

Array = np.ndarray
Fn = Callable[["_Env"], Array]


class SimulationError(Exception):
    """A step cannot be taken: a constraint is violated, or a distribution
    was given parameters outside its domain. The message names the
    constraint (with its place in the file), the grounding and the actions."""


# ------------------------------------------------------------- state


class State:
    """A batch of states: one array per state fluent, batch axis first.

    Cheap to copy (`copy`) and to index (`state[i]`, `state[mask]`).
    """

    __slots__ = ("values",)

    def __init__(self, values: dict[str, Array]):
        self.values = values

    @property
    def batch(self) -> int:
        for v in self.values.values():
            return int(v.shape[0])
        return 1

    def copy(self) -> State:
        return State({k: v.copy() for k, v in self.values.items()})

    def __getitem__(self, index: Any) -> State:
        out = {}
        for k, v in self.values.items():
            x = v[index]
            if isinstance(index, (int, np.integer)):
                x = x[None]
            out[k] = x
        return State(out)

    def __repr__(self) -> str:
        return f"State(batch={self.batch}, fluents={len(self.values)})"


@dataclass(frozen=True)
class Step:
    """The outcome of `Simulator.step` for a batch."""

    next_state: State
    reward: Array  # (batch,)
    observation: dict[str, Array] | None  # observ fluents, POMDPs only
    done: Array  # (batch,) bool: termination holds in the next state


class _Env:
    """Values visible to compiled expressions during one step."""

    __slots__ = ("values", "rng", "batch")

    def __init__(self, values: dict[str, Array], rng: np.random.Generator | None, batch: int):
        self.values = values
        self.rng = rng
        self.batch = batch


Scope = tuple[tuple[str, str], ...]  # ((var, type), ...)


def _int_enum_value(name: str) -> int | None:
    body = name[1:]
    try:
        return int(body)
    except ValueError:
        return None


# ---------------------------------------------------------- compiler


class _Compiler:
    def __init__(self, model: Model):
        self.model = model
        self.sizes = {t: len(info.members) for t, info in model.types.items()}
        self.codes = {
            t: {m: i for i, m in enumerate(info.members)} for t, info in model.types.items()
        }
        self.object_type: dict[str, str] = {}
        for t, info in model.types.items():
            if info.kind == "object" and (info.parent is None or info.parent not in model.types):
                for m in info.members:
                    self.object_type.setdefault(m, t)
        for t, info in model.types.items():
            for m in info.members:
                self.object_type.setdefault(m, t)
        # value of each enum member when used as a number (@1 -> 1), else its code
        self.numeric_of_code: dict[str, Array] = {}
        for t, info in model.types.items():
            if info.kind == "enum":
                ints = [_int_enum_value(m) for m in info.members]
                if all(v is not None for v in ints):
                    self.numeric_of_code[t] = np.array(ints, dtype=np.int64)

    # -- helpers -----------------------------------------------------

    def shape_of(self, p: PVariable) -> tuple[int, ...]:
        return tuple(self.sizes[t] for t in p.params)

    def scope_shape(self, scope: Scope) -> tuple[int, ...]:
        return tuple(self.sizes[t] for _, t in scope)

    @staticmethod
    def rank(scope: Scope) -> int:
        return 1 + len(scope)

    def const(self, value: Any, scope: Scope, dtype: Any = None) -> Fn:
        arr = np.asarray(value, dtype=dtype).reshape((1,) * self.rank(scope))
        return lambda env: arr

    def code_of(self, name: str, type_hint: str | None) -> tuple[int, str]:
        """Code and type of an enum value or object name."""
        if type_hint is not None and type_hint in self.codes and name in self.codes[type_hint]:
            return self.codes[type_hint][name], type_hint
        if name.startswith("@"):
            for t, codes in self.codes.items():
                if name in codes:
                    return codes[name], t
        owner = self.object_type.get(name)
        if owner is None:
            raise SimulationError(f"unknown object or enum value '{name}'")
        return self.codes[owner][name], owner

    # -- expressions -------------------------------------------------

    def compile(self, e: A.Expr, scope: Scope, hint: str | None = None) -> tuple[Fn, str]:
        """Closure and value type ('bool', 'int', 'real' or a type name)."""
        method = getattr(self, "_" + type(e).__name__)
        return method(e, scope, hint)  # type: ignore[no-any-return]

    def numeric(self, e: A.Expr, scope: Scope) -> tuple[Fn, str]:
        """Compile for use as a number (enum @1..@n -> their integers)."""
        fn, t = self.compile(e, scope)
        table = self.numeric_of_code.get(t)
        if table is not None:
            return (lambda env: table[fn(env)]), "int"
        return fn, t

    def _Const(self, e: A.Const, scope: Scope, hint: str | None) -> tuple[Fn, str]:
        v = e.value
        if isinstance(v, bool):
            return self.const(v, scope, np.bool_), "bool"
        if isinstance(v, int):
            return self.const(v, scope, np.int64), "int"
        return self.const(v, scope, np.float64), "real"

    def _Var(self, e: A.Var, scope: Scope, hint: str | None) -> tuple[Fn, str]:
        # A variable used as a value: the code of the object it ranges over.
        pos = [i for i, (v, _) in enumerate(scope) if v == e.name]
        i = pos[-1]
        t = scope[i][1]
        shape = [1] * self.rank(scope)
        shape[1 + i] = self.sizes[t]
        arr = np.arange(self.sizes[t], dtype=np.int64).reshape(shape)
        return (lambda env: arr), t

    def _EnumLit(self, e: A.EnumLit, scope: Scope, hint: str | None) -> tuple[Fn, str]:
        code, t = self.code_of(e.name, hint)
        return self.const(code, scope, np.int64), t

    def _ObjectLit(self, e: A.ObjectLit, scope: Scope, hint: str | None) -> tuple[Fn, str]:
        code, t = self.code_of(e.name, hint)
        return self.const(code, scope, np.int64), t

    def _PVar(self, e: A.PVar, scope: Scope, hint: str | None) -> tuple[Fn, str]:
        p = self.model.pvariables.get(e.name)
        if p is None:  # a bare object name (or an enum value without '@')
            name = e.name
            if hint in self.codes and "@" + name in self.codes[hint]:
                name = "@" + name
            return self._ObjectLit(A.ObjectLit(name, loc=e.loc), scope, hint)
        if e.default:
            default = self.model.default_of(p)
            if p.range in self.codes:
                return self.const(self.codes[p.range][default], scope, np.int64), p.range  # type: ignore[index]
            return self.const(default, scope), p.range
        key = p.name + ("'" if e.primed else "")
        n = len(scope)
        # Fast path: every argument a distinct variable -> a view.
        positions = []
        for a in e.args:
            if isinstance(a, A.Var):
                positions.append(max(i for i, (v, _) in enumerate(scope) if v == a.name))
            else:
                positions = []
                break
        if len(positions) == len(e.args) and len(set(positions)) == len(positions):
            order = sorted(range(len(positions)), key=lambda i: positions[i])
            axes = (0,) + tuple(1 + i for i in order)
            missing = tuple(1 + j for j in range(n) if j not in positions)
            if axes == tuple(range(len(axes))):
                if not missing:
                    return (lambda env: env.values[key]), p.range
                return (lambda env: np.expand_dims(env.values[key], missing)), p.range
            return (lambda env: np.expand_dims(np.transpose(env.values[key], axes), missing)), p.range
        # General path: advanced indexing with broadcast index arrays.
        index_fns: list[Callable[[_Env], Any]] = []
        for a, t in zip(e.args, p.params, strict=True):
            if isinstance(a, A.Var):
                fn, _ = self._Var(a, scope, None)
                index_fns.append(fn)
            elif isinstance(a, (A.EnumLit, A.ObjectLit)) or (
                isinstance(a, A.PVar) and a.name not in self.model.pvariables
            ):
                name = a.name
                if isinstance(a, A.PVar) and t in self.codes and "@" + name in self.codes[t]:
                    name = "@" + name
                code, _ = self.code_of(name, t)
                arr = np.full((1,) * self.rank(scope), code, dtype=np.int64)
                index_fns.append(_constant_fn(arr))
            else:
                fn, _ = self.compile(a, scope, t)
                index_fns.append(fn)
        rank = self.rank(scope)

        def gather(env: _Env) -> Array:
            base = env.values[key]
            idx = [f(env) for f in index_fns]
            if base.shape[0] == 1:
                b = np.zeros((1,) * rank, dtype=np.int64)
            else:
                b = np.arange(base.shape[0]).reshape((-1,) + (1,) * (rank - 1))
            return base[(b, *idx)]  # type: ignore[no-any-return]

        return gather, p.range

    def _Unary(self, e: A.Unary, scope: Scope, hint: str | None) -> tuple[Fn, str]:
        fn, t = self.numeric(e.operand, scope)
        if e.op == "~":
            return (lambda env: np.logical_not(fn(env))), "bool"
        if e.op == "-":
            if t == "bool":
                return (lambda env: -fn(env).astype(np.int64)), "int"
            return (lambda env: np.negative(fn(env))), t
        return fn, t

    def _Binary(self, e: A.Binary, scope: Scope, hint: str | None) -> tuple[Fn, str]:
        op = e.op
        if op in ("==", "~="):
            lf, lt = self.compile(e.left, scope)
            rf, rt = self.compile(e.right, scope, lt)
            if lt != rt and (lt in self.codes) != (rt in self.codes) or (
                lt in self.codes and rt in self.codes and lt != rt
            ):
                # mixed forms: compare as numbers where an enum is numeric
                lf, lt = self.numeric(e.left, scope)
                rf, rt = self.numeric(e.right, scope)
            if op == "==":
                return (lambda env: np.equal(lf(env), rf(env))), "bool"
            return (lambda env: np.not_equal(lf(env), rf(env))), "bool"
        lf, lt = self.numeric(e.left, scope)
        rf, rt = self.numeric(e.right, scope)
        ufunc = {
            "^": np.logical_and,
            "|": np.logical_or,
            "<": np.less,
            "<=": np.less_equal,
            ">": np.greater,
            ">=": np.greater_equal,
        }.get(op)
        if ufunc is not None:
            return (lambda env: ufunc(lf(env), rf(env))), "bool"
        if op == "=>":
            return (lambda env: np.logical_or(np.logical_not(lf(env)), rf(env))), "bool"
        if op == "<=>":
            return (lambda env: np.equal(lf(env).astype(bool), rf(env).astype(bool))), "bool"
        out = "real" if "real" in (lt, rt) or op == "/" else "int"
        if op == "+":
            if lt == rt == "bool":
                return (lambda env: lf(env).astype(np.int64) + rf(env)), "int"
            return (lambda env: np.add(lf(env), rf(env))), out
        if op == "-":
            if lt == "bool":
                return (lambda env: lf(env).astype(np.int64) - rf(env)), out
            return (lambda env: np.subtract(lf(env), rf(env))), out
        if op == "*":
            if lt == rt == "bool":
                return (lambda env: np.logical_and(lf(env), rf(env)).astype(np.int64)), "int"
            return (lambda env: np.multiply(lf(env), rf(env))), out
        if op == "/":
            return (lambda env: np.true_divide(lf(env), rf(env))), "real"
        raise SimulationError(f"{e.loc}: unknown operator '{op}'")

    def _If(self, e: A.If, scope: Scope, hint: str | None) -> tuple[Fn, str]:
        cf, _ = self.numeric(e.cond, scope)
        tf, tt = self.compile(e.then, scope, hint)
        ef, et = self.compile(e.else_, scope, hint if tt not in ("bool", "int", "real") else tt)
        t = _join(tt, et)
        return (lambda env: np.where(cf(env), tf(env), ef(env))), t

    def _Switch(self, e: A.Switch, scope: Scope, hint: str | None) -> tuple[Fn, str]:
        sf, st = self.compile(e.subject, scope)
        arms: list[tuple[Fn, Fn]] = []
        default: Fn | None = None
        t: str | None = None
        for case in e.cases:
            vf, vt = self.compile(case.value, scope, hint)
            t = vt if t is None else _join(t, vt)
            if case.label is None:
                default = vf
            else:
                lf, _ = self.compile(case.label, scope, st)
                arms.append((lf, vf))

        def switch(env: _Env) -> Array:
            subject = sf(env)
            conds = [np.equal(subject, lf(env)) for lf, _ in arms]
            values = [vf(env) for _, vf in arms]
            if default is not None:
                fallback = default(env)
            else:
                fallback = values[-1]
            return np.select(conds, values, fallback) if conds else fallback  # type: ignore[no-any-return]

        return switch, t or "real"

    def _Aggregation(self, e: A.Aggregation, scope: Scope, hint: str | None) -> tuple[Fn, str]:
        inner = scope + tuple((p.name, p.type) for p in e.params)
        bf, bt = self.numeric(e.body, inner)
        k = len(e.params)
        sizes = tuple(self.sizes[p.type] for p in e.params)
        axes = tuple(range(-k, 0))
        op = e.op

        def full(env: _Env) -> Array:
            x = bf(env)
            return np.broadcast_to(x, x.shape[: x.ndim - k] + sizes)

        if op == "sum":
            out = "int" if bt == "bool" else bt
            return (lambda env: np.sum(full(env), axis=axes)), out
        if op == "prod":
            out = "int" if bt == "bool" else bt
            return (lambda env: np.prod(full(env), axis=axes)), out
        if op == "avg":
            return (lambda env: np.mean(full(env), axis=axes)), "real"
        if op == "min":
            return (lambda env: np.min(full(env), axis=axes)), bt
        if op == "max":
            return (lambda env: np.max(full(env), axis=axes)), bt
        if op == "forall":
            return (lambda env: np.all(full(env), axis=axes)), "bool"
        if op == "exists":
            return (lambda env: np.any(full(env), axis=axes)), "bool"
        if op in ("argmax", "argmin"):
            f = np.argmax if op == "argmax" else np.argmin
            return (lambda env: f(full(env), axis=-1)), e.params[0].type
        raise SimulationError(f"{e.loc}: aggregation '{op}_' is not supported by the simulator")

    def _Function(self, e: A.Function, scope: Scope, hint: str | None) -> tuple[Fn, str]:
        args = [self.numeric(a, scope) for a in e.args]
        fns = [f for f, _ in args]
        types = [t for _, t in args]
        name = e.name
        unary: dict[str, Callable[[Array], Array]] = {
            "exp": np.exp, "ln": np.log, "sqrt": np.sqrt, "cos": np.cos, "sin": np.sin,
            "tan": np.tan, "acos": np.arccos, "asin": np.arcsin, "atan": np.arctan,
            "cosh": np.cosh, "sinh": np.sinh, "tanh": np.tanh,
        }
        if name in unary:
            g = unary[name]
            f0 = fns[0]
            return (lambda env: g(np.asarray(f0(env), dtype=np.float64))), "real"
        if name in ("floor", "ceil", "round"):
            rounding: Any = {"floor": np.floor, "ceil": np.ceil, "round": np.round}[name]
            f0 = fns[0]
            return (lambda env: rounding(f0(env)).astype(np.int64)), "int"
        if name in ("sgn", "sign"):
            f0 = fns[0]
            return (lambda env: np.sign(f0(env)).astype(np.int64)), "int"
        if name == "abs":
            f0 = fns[0]
            out = "int" if types[0] == "bool" else types[0]
            return (lambda env: np.abs(f0(env))), out
        f0, f1 = fns[0], fns[1]
        out = "real" if "real" in types else "int"
        if name == "min":
            return (lambda env: np.minimum(f0(env), f1(env))), out
        if name == "max":
            return (lambda env: np.maximum(f0(env), f1(env))), out
        if name == "pow":
            return (lambda env: np.power(np.asarray(f0(env), dtype=np.float64), f1(env))), "real"
        if name == "log":
            return (lambda env: np.log(f0(env)) / np.log(f1(env))), "real"
        if name == "hypot":
            return (lambda env: np.hypot(f0(env), f1(env))), "real"
        if name in ("mod", "fmod"):
            return (lambda env: np.fmod(f0(env), f1(env))), "real" if name == "fmod" else out
        if name == "div":
            return (lambda env: np.trunc(np.true_divide(f0(env), f1(env))).astype(np.int64)), "int"
        raise SimulationError(f"{e.loc}: function '{name}' is not supported by the simulator")

    def _Distribution(self, e: A.Distribution, scope: Scope, hint: str | None) -> tuple[Fn, str]:
        name = e.name
        if name == "KronDelta":
            return self.compile(e.args[0], scope, hint)
        if name == "DiracDelta":
            f0, _ = self.numeric(e.args[0], scope)
            return (lambda env: np.asarray(f0(env), dtype=np.float64)), "real"
        fns = [self.numeric(a, scope)[0] for a in e.args]
        where = f"{e.loc}: {name}"
        # one independent draw per batch element and per grounding of every
        # variable in scope, whatever the parameters depend on
        full = self.scope_shape(scope)

        def shape(env: _Env, *params: Array) -> tuple[int, ...]:
            return (env.batch,) + full

        def rng(env: _Env) -> np.random.Generator:
            if env.rng is None:
                raise SimulationError(f"{where}: a random draw needs a numpy Generator (rng)")
            return env.rng

        if name == "Bernoulli":
            (fp,) = fns

            def bernoulli(env: _Env) -> Array:
                p = fp(env)
                if np.any((p < 0) | (p > 1)):
                    raise SimulationError(f"{where} probability outside [0, 1]: {_bad(p, (p < 0) | (p > 1))}")
                return rng(env).random(shape(env, p)) < p  # type: ignore[no-any-return]

            return bernoulli, "bool"
        if name == "Normal":
            fm, fv = fns

            def normal(env: _Env) -> Array:
                m, v = fm(env), fv(env)
                if np.any(v < 0):
                    raise SimulationError(f"{where} variance is negative: {_bad(v, v < 0)}")
                return rng(env).normal(m, np.sqrt(v), shape(env, m, v))  # type: ignore[no-any-return]

            return normal, "real"
        if name == "Uniform":
            fl, fu = fns

            def uniform(env: _Env) -> Array:
                lo, hi = fl(env), fu(env)
                if np.any(lo > hi):
                    raise SimulationError(f"{where} lower bound above upper bound")
                return rng(env).uniform(lo, hi, shape(env, lo, hi))  # type: ignore[no-any-return]

            return uniform, "real"
        if name == "Exponential":
            (fs,) = fns

            def exponential(env: _Env) -> Array:
                s = fs(env)
                if np.any(s <= 0):
                    raise SimulationError(f"{where} mean must be positive: {_bad(s, s <= 0)}")
                return rng(env).exponential(s, shape(env, s))  # type: ignore[no-any-return]

            return exponential, "real"
        if name == "Poisson":
            (fl,) = fns

            def poisson(env: _Env) -> Array:
                lam = fl(env)
                if np.any(lam < 0):
                    raise SimulationError(f"{where} mean must not be negative: {_bad(lam, lam < 0)}")
                return rng(env).poisson(lam, shape(env, lam)).astype(np.int64)  # type: ignore[no-any-return]

            return poisson, "int"
        two: dict[str, tuple[Callable[..., Array], str, Callable[[Array, Array], Array]]] = {
            "Gamma": (lambda g, a, b, s: g.gamma(a, b, s), "real", lambda a, b: (a <= 0) | (b <= 0)),
            "Weibull": (lambda g, a, b, s: b * g.weibull(a, s), "real", lambda a, b: (a <= 0) | (b <= 0)),
            "Beta": (lambda g, a, b, s: g.beta(a, b, s), "real", lambda a, b: (a <= 0) | (b <= 0)),
            "Binomial": (lambda g, n, p, s: g.binomial(n, p, s).astype(np.int64), "int", lambda n, p: (n < 0) | (p < 0) | (p > 1)),
            "NegativeBinomial": (lambda g, n, p, s: g.negative_binomial(n, p, s).astype(np.int64), "int", lambda n, p: (n <= 0) | (p <= 0) | (p > 1)),
            "Pareto": (lambda g, a, b, s: b * (1 + g.pareto(a, s)), "real", lambda a, b: (a <= 0) | (b <= 0)),
            "Gumbel": (lambda g, a, b, s: g.gumbel(a, b, s), "real", lambda a, b: b <= 0),
            "Laplace": (lambda g, a, b, s: g.laplace(a, b, s), "real", lambda a, b: b <= 0),
            "Cauchy": (lambda g, a, b, s: a + b * g.standard_cauchy(s), "real", lambda a, b: b <= 0),
            "Gompertz": (lambda g, a, b, s: np.log(1 - np.log(1 - g.random(s)) / a) / b, "real", lambda a, b: (a <= 0) | (b <= 0)),
            "Kumaraswamy": (lambda g, a, b, s: (1 - (1 - g.random(s)) ** (1 / b)) ** (1 / a), "real", lambda a, b: (a <= 0) | (b <= 0)),
        }
        if name in two:
            draw, out, invalid = two[name]
            f1, f2 = fns

            def sample2(env: _Env) -> Array:
                a, b = f1(env), f2(env)
                bad = invalid(np.asarray(a), np.asarray(b))
                if np.any(bad):
                    raise SimulationError(f"{where} parameters outside its domain")
                return draw(rng(env), a, b, shape(env, a, b))

            return sample2, out
        one: dict[str, tuple[Callable[..., Array], str, Callable[[Array], Array]]] = {
            "Geometric": (lambda g, p, s: g.geometric(p, s).astype(np.int64), "int", lambda p: (p <= 0) | (p > 1)),
            "Student": (lambda g, d, s: g.standard_t(d, s), "real", lambda d: d <= 0),
            "ChiSquare": (lambda g, d, s: g.chisquare(d, s), "real", lambda d: d <= 0),
        }
        if name in one:
            draw1, out, invalid1 = one[name]
            (f1,) = fns

            def sample1(env: _Env) -> Array:
                a = f1(env)
                if np.any(invalid1(np.asarray(a))):
                    raise SimulationError(f"{where} parameter outside its domain")
                return draw1(rng(env), a, shape(env, a))

            return sample1, out
        raise SimulationError(f"{where} is not supported by the simulator")

    def _Discrete(self, e: A.Discrete, scope: Scope, hint: str | None) -> tuple[Fn, str]:
        if e.count is not None:
            raise SimulationError(f"{e.loc}: {e.name} is not supported by the simulator")
        t = e.type
        labels = []
        probs: list[Fn | None] = []
        for dc in e.cases:
            name = dc.label.name  # type: ignore[union-attr]
            if t in self.codes and name not in self.codes[t] and "@" + name in self.codes[t]:
                name = "@" + name
            labels.append(self.code_of(name, t)[0])
            probs.append(None if dc.prob is None else self.numeric(dc.prob, scope)[0])
        codes = np.array(labels, dtype=np.int64)
        normalise = e.name == "UnnormDiscrete"
        where = f"{e.loc}: {e.name}"
        draw_shape = self.scope_shape(scope)

        def discrete(env: _Env) -> Array:
            ps = [None if f is None else np.asarray(f(env), dtype=np.float64) for f in probs]
            known = [p for p in ps if p is not None]
            shp = (env.batch,) + draw_shape
            full = [np.broadcast_to(p, shp) if p is not None else None for p in ps]
            total_known = sum(p for p in full if p is not None) if known else np.zeros(shp)
            stacked = np.stack(
                [p if p is not None else np.maximum(1.0 - total_known, 0.0) for p in full], axis=-1
            )
            if np.any(stacked < -1e-12):
                raise SimulationError(f"{where} has a negative probability")
            return codes[_draw_categorical(stacked, normalise, where, env.rng)]  # type: ignore[no-any-return]

        return discrete, t

    def _DiscreteOver(self, e: A.DiscreteOver, scope: Scope, hint: str | None) -> tuple[Fn, str]:
        if len(e.params) != 1:
            raise SimulationError(f"{e.loc}: {e.name}_ takes one variable")
        inner = scope + ((e.params[0].name, e.params[0].type),)
        wf, _ = self.numeric(e.body, inner)
        size = self.sizes[e.params[0].type]
        normalise = e.name == "UnnormDiscrete"
        where = f"{e.loc}: {e.name}_"
        full = self.scope_shape(scope)

        def discrete_over(env: _Env) -> Array:
            w = np.asarray(wf(env), dtype=np.float64)
            w = np.broadcast_to(w, (env.batch,) + full + (size,))
            if np.any(w < 0):
                raise SimulationError(f"{where} has a negative probability")
            return _draw_categorical(w, normalise, where, env.rng)

        return discrete_over, e.params[0].type

    def _unsupported(self, e: A.Expr, scope: Scope, hint: str | None) -> tuple[Fn, str]:
        raise SimulationError(f"{e.loc}: {type(e).__name__} is not supported by the simulator")

    _MatrixOp = _unsupported
    _VectorDistribution = _unsupported


def _draw_categorical(
    weights: Array, normalise: bool, where: str, rng: np.random.Generator | None
) -> Array:
    """One index per leading position, drawn with the probabilities along the
    last axis: normalised (UnnormDiscrete) or required to sum to 1."""
    total = weights.sum(axis=-1)
    if normalise:
        weights = weights / total[..., None]
    else:
        off = np.abs(total - 1.0)
        if np.any(off > 1e-6):
            worst = float(total.flat[int(np.argmax(off))])
            raise SimulationError(f"{where} probabilities sum to {worst}, not 1")
    if rng is None:
        raise SimulationError(f"{where}: a random draw needs a numpy Generator (rng)")
    cum = np.cumsum(weights, axis=-1)
    u = rng.random(weights.shape[:-1])[..., None] * cum[..., -1:]
    return np.minimum(np.sum(cum <= u, axis=-1), weights.shape[-1] - 1)  # type: ignore[no-any-return]


def _order_cpfs(model: Model) -> list[str]:
    """Keys of every cpf ("name" or "name'" for next state) in evaluation order."""
    rank = {INTERM: 0, DERIVED: 0, STATE: 1, OBSERV: 2}
    keys: dict[str, tuple[int, int, int]] = {}
    for i, p in enumerate(model.pvariables.values()):
        if p.kind in rank and p.name in model.cpfs:
            key = p.name + ("'" if p.kind == STATE else "")
            keys[key] = (rank[p.kind], p.level if p.level is not None else 0, i)
    deps: dict[str, set[str]] = {}
    for key in keys:
        cp = model.cpfs[key.rstrip("'")]
        found = set()
        for node in A.walk(cp.expr):
            if isinstance(node, A.PVar):
                ref = node.name + ("'" if node.primed else "")
                if ref in keys and ref != key:
                    found.add(ref)
                elif node.name in keys and not node.primed and ref != key:
                    found.add(node.name)
        deps[key] = found
    order: list[str] = []
    done: set[str] = set()
    pending = sorted(keys, key=lambda k: keys[k])
    while pending:
        for k in pending:
            if deps[k] <= done:
                order.append(k)
                done.add(k)
                pending.remove(k)
                break
        else:
            cycle = ", ".join(pending)
            raise SimulationError(f"the cpfs of {cycle} depend on each other in a cycle")
    return order


_WINDOW = 64  # candidate additions tested per batched call in random_actions


def _comb(n: int, k: int) -> int:
    from math import comb

    return comb(n, k)


def _constant_fn(arr: Array) -> Fn:
    return lambda env: arr


def _text(expr: A.Expr, limit: int = 160) -> str:
    from .writer import write_expr

    text = write_expr(expr)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _join(a: str, b: str) -> str:
    if a == b:
        return a
    nums = ("bool", "int", "real")
    if a in nums and b in nums:
        return "real" if "real" in (a, b) else "int"
    return a


def _bad(values: Array, mask: Array) -> str:
    v = np.asarray(values)
    m = np.broadcast_to(mask, v.shape) if v.shape else mask
    bad = np.asarray(v)[m] if np.ndim(v) else v
    return repr(float(np.ravel(bad)[0])) if np.size(bad) else "?"


# --------------------------------------------------------- simulator


_DTYPES = {"bool": np.bool_, "int": np.int64, "real": np.float64}


class Simulator:
    """The forward model of one RDDL instance, stepping batches of states.

    >>> sim = Simulator(model)
    >>> s = sim.initial_state(batch=4)
    >>> out = sim.step(s, sim.noop(4), np.random.default_rng(0))
    """

    def __init__(self, model: Model):
        self.model = model
        c = self._c = _Compiler(model)
        self.state_fluents = model.fluents(STATE)
        self.action_fluents = model.fluents(ACTION)
        self.observ_fluents = model.fluents(OBSERV)
        self.non_fluents = model.fluents(NON_FLUENT)
        self.interm_fluents = [p for p in model.pvariables.values() if p.kind in (INTERM, DERIVED)]

        self._nf_values = {p.name: self._initial_array(p)[None] for p in self.non_fluents}
        self._defaults = {p.name: self._default_array(p) for p in self.action_fluents}

        def cpf(p: PVariable) -> Fn:
            cp = model.cpfs[p.name]
            scope = tuple(zip(cp.params, p.params, strict=True))
            fn, _ = c.compile(cp.expr, scope, p.range)
            shape = c.shape_of(p)
            dtype = self._dtype(p)

            def run(env: _Env) -> Array:
                # an owned, writable array: a broadcast view would be read-only,
                # and a cpf like KronDelta(p(?x)) would alias the current state
                return np.array(np.broadcast_to(fn(env), (env.batch,) + shape), dtype=dtype)

            return run

        # Every cpf in an order that respects what it reads: by level and
        # kind (interm, next state, observation) where possible, as rddlsim
        # does, and by dependency where a domain reads a fluent computed
        # later (pyRDDLGym's levels-free style).
        self._cpf_order = _order_cpfs(model)
        self._cpf_fns = [(key, cpf(model.pvariables[key.rstrip("'")])) for key in self._cpf_order]
        self._state_keys = {p.name + "'": p.name for p in self.state_fluents}
        self._observ_names = {p.name for p in self.observ_fluents}
        reward = model.reward
        self._reward_fn = c.numeric(reward, ())[0] if reward is not None else None
        dom = model.domain
        self._preconditions = [(e, c.numeric(e, ())[0]) for e in dom.action_preconditions]
        self._preconditions += [(e, c.numeric(e, ())[0]) for e in dom.state_action_constraints]
        self._invariants = [(e, c.numeric(e, ())[0]) for e in dom.state_invariants]
        self._terminations = [(e, c.numeric(e, ())[0]) for e in dom.termination]

    # -- values ------------------------------------------------------

    def _dtype(self, p: PVariable) -> Any:
        return _DTYPES.get(p.range, np.int64)

    def _encode(self, p: PVariable, value: Value) -> Any:
        if p.range in self._c.codes:
            return self._c.codes[p.range][value]  # type: ignore[index]
        return value

    def _default_array(self, p: PVariable) -> Array:
        shape = self._c.shape_of(p)
        return np.full(shape, self._encode(p, self.model.default_of(p)), dtype=self._dtype(p))

    def _initial_array(self, p: PVariable) -> Array:
        arr = self._default_array(p)
        values = self.model.non_fluent_values if p.kind == NON_FLUENT else self.model.init_state
        for (name, args), value in values.items():
            if name == p.name:
                idx = tuple(self._c.codes[t][a] for t, a in zip(p.params, args, strict=True))
                arr[idx] = self._encode(p, value)
        return arr

    def initial_state(self, batch: int = 1) -> State:
        """The instance's initial state, repeated `batch` times."""
        return State(
            {
                p.name: np.repeat(self._initial_array(p)[None], batch, axis=0)
                for p in self.state_fluents
            }
        )

    def noop(self, batch: int = 1) -> dict[str, Array]:
        """Every action at its default, for a batch."""
        return {k: np.repeat(v[None], batch, axis=0) for k, v in self._defaults.items()}

    # -- the step ----------------------------------------------------

    def _env(self, state: State, actions: Mapping[str, Array], rng: np.random.Generator | None) -> _Env:
        batch = state.batch
        values: dict[str, Array] = dict(self._nf_values)
        values.update(state.values)
        for p in self.action_fluents:
            a = actions.get(p.name)
            if a is None:
                a = np.broadcast_to(self._defaults[p.name], (batch,) + self._defaults[p.name].shape)
            values[p.name] = a
        return _Env(values, rng, batch)

    def count_nondefault(self, actions: Mapping[str, Array], batch: int) -> Array:
        """How many grounded actions differ from their default, per state."""
        n = np.zeros(batch, dtype=np.int64)
        for p in self.action_fluents:
            a = actions.get(p.name)
            if a is None:
                continue
            diff = np.asarray(a) != self._defaults[p.name]
            n += diff.reshape(diff.shape[0], -1).sum(axis=1)
        return n

    def check_actions(self, state: State, actions: Mapping[str, Array]) -> Array:
        """A (batch,) mask of the states where the actions are legal:
        max-nondef-actions, action-preconditions, state-action-constraints."""
        env = self._env(state, actions, None)
        ok = np.ones(state.batch, dtype=bool)
        limit = self.model.max_nondef_actions
        if limit is not None:
            ok &= self.count_nondefault(actions, state.batch) <= limit
        for _, fn in self._preconditions:
            ok &= np.broadcast_to(np.asarray(fn(env), dtype=bool).reshape(-1), (state.batch,))
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
        actions = actions or {}
        batch = state.batch
        env = self._env(state, actions, rng)
        if check:
            self._check_preconditions(env, actions, batch)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            nxt = {}
            obs: dict[str, Array] | None = {} if self._observ_names else None
            for key, fn in self._cpf_fns:
                value = env.values[key] = fn(env)
                if key in self._state_keys:
                    nxt[self._state_keys[key]] = value
                elif obs is not None and key in self._observ_names:
                    obs[key] = value
            if self._reward_fn is not None:
                reward = np.broadcast_to(np.asarray(self._reward_fn(env), dtype=np.float64).reshape(-1), (batch,)).copy()
            else:
                reward = np.zeros(batch)
            nenv = self._env(State(nxt), actions, None)
            if check:
                for expr, fn in self._invariants:
                    holds = np.broadcast_to(np.asarray(fn(nenv), dtype=bool).reshape(-1), (batch,))
                    if not holds.all():
                        raise SimulationError(
                            f"{expr.loc}: state invariant violated (state {int(np.argmin(holds))} of the batch): {_text(expr)}"
                        )
            done = np.zeros(batch, dtype=bool)
            for _, fn in self._terminations:
                done |= np.broadcast_to(np.asarray(fn(nenv), dtype=bool).reshape(-1), (batch,))
        return Step(State(nxt), reward, obs, done)

    def _check_preconditions(self, env: _Env, actions: Mapping[str, Array], batch: int) -> None:
        limit = self.model.max_nondef_actions
        if limit is not None:
            n = self.count_nondefault(actions, batch)
            if np.any(n > limit):
                i = int(np.argmax(n > limit))
                raise SimulationError(
                    f"{int(n[i])} actions differ from their default, max-nondef-actions is {limit}: "
                    f"{', '.join(self.actions_to_names(actions, i)) or 'noop'}"
                )
        for expr, fn in self._preconditions:
            holds = np.broadcast_to(np.asarray(fn(env), dtype=bool).reshape(-1), (batch,))
            if not holds.all():
                i = int(np.argmin(holds))
                acts = ", ".join(self.actions_to_names(actions, i)) or "noop"
                raise SimulationError(
                    f"{expr.loc}: constraint violated (state {i} of the batch): {_text(expr)}; actions: {acts}"
                )

    # -- action choice ---------------------------------------------

    def _groundings(self) -> list[tuple[PVariable, tuple[int, ...]]]:
        return [(p, idx) for p in self.action_fluents for _, idx in self._ground(p)]

    def _random_value(self, p: PVariable, rng: np.random.Generator, n: int) -> Array:
        """n values of action `p` that differ from its default."""
        default = self._encode(p, self.model.default_of(p))
        if p.range == "bool":
            return np.full(n, not default)
        if p.range in self._c.codes:
            size = len(self._c.codes[p.range])
            if size < 2:
                return np.full(n, default)
            draw = rng.integers(0, size - 1, n)
            return draw + (draw >= default)  # type: ignore[no-any-return]
        if p.range == "int":
            step = rng.integers(1, 6, n)
            return default + np.where(rng.random(n) < 0.5, -step, step)  # type: ignore[no-any-return]
        return default + rng.uniform(-1.0, 1.0, n)  # type: ignore[no-any-return]

    def random_actions(self, state: State, rng: np.random.Generator) -> dict[str, Array]:
        """Random legal actions for every state of the batch, as rddlsim's
        RandomConcurrentPolicy picks them: each action fluent in turn, its
        groundings in a random order; each grounding is taken with
        probability 1/2 (with a random non-default value) and kept only if
        the constraints and max-nondef-actions still hold; at most
        max-nondef-actions are taken."""
        batch = state.batch
        actions = self.noop(batch)
        limit = self.model.max_nondef_actions
        if not self._preconditions:
            return self._random_unconstrained(actions, batch, limit, rng)
        taken = np.zeros(batch, dtype=np.int64)
        for p, flat, order, heads in self._coin_flips(actions, batch, rng):
            n = flat.shape[1]
            values = self._random_value(p, rng, batch * n).reshape(batch, n)
            # Between two additions the action set does not change, so the
            # sequential rule (try each flipped grounding in order, keep it if
            # still legal) takes the first legal one: test a window of
            # candidates in one batched call instead of one call each.
            pos = np.zeros(batch, dtype=np.int64)
            while True:
                active = pos < n
                if limit is not None:
                    active &= taken < limit
                if not active.any():
                    break
                cand_b, cand_j = [], []
                for b in np.nonzero(active)[0]:
                    js = pos[b] + np.nonzero(heads[b, pos[b]: pos[b] + _WINDOW])[0]
                    if len(js) == 0:
                        pos[b] = min(n, pos[b] + _WINDOW)
                        continue
                    cand_b.extend([b] * len(js))
                    cand_j.extend(js.tolist())
                if not cand_b:
                    continue
                cb = np.array(cand_b)
                cj = np.array(cand_j)
                trial = {k: v[cb].copy() for k, v in actions.items()}
                tflat = trial[p.name].reshape(len(cb), -1)
                tflat[np.arange(len(cb)), order[cb, cj]] = values[cb, cj]
                legal = self.check_actions(state[cb], trial)
                for b in np.unique(cb):
                    mine = cb == b
                    ok = np.nonzero(legal & mine)[0]
                    if len(ok):
                        first = ok[0]
                        j = cj[first]
                        flat[b, order[b, j]] = values[b, j]
                        taken[b] += 1
                        pos[b] = j + 1
                    else:
                        pos[b] = cj[mine].max() + 1
        if not self.check_actions(state, actions).all():
            bad = int(np.argmin(self.check_actions(state, actions)))
            raise SimulationError(f"no legal action in state {bad} of the batch, not even noop")
        return actions

    def _coin_flips(
        self, actions: dict[str, Array], batch: int, rng: np.random.Generator
    ) -> Iterable[tuple[PVariable, Array, Array, Array]]:
        """Per action fluent with groundings: its flattened action array (a
        view to write into), a random order of its groundings per state, and
        a fair coin flip per grounding."""
        for p in self.action_fluents:
            flat = actions[p.name].reshape(batch, -1)
            n = flat.shape[1]
            if n == 0:
                continue
            yield p, flat, np.argsort(rng.random((batch, n)), axis=1), rng.random((batch, n)) < 0.5

    def _random_unconstrained(
        self, actions: dict[str, Array], batch: int, limit: int | None, rng: np.random.Generator
    ) -> dict[str, Array]:
        """The same choice without constraints to check, all at once: in each
        fluent's random order, the coin flips that come up, up to the limit
        (counted across fluents in declaration order)."""
        taken = np.zeros(batch, dtype=np.int64)
        for p, flat, order, heads in self._coin_flips(actions, batch, rng):
            if limit is not None:
                rank = taken[:, None] + np.cumsum(heads, axis=1)
                heads &= rank <= limit
            rows = np.nonzero(heads)
            flat[rows[0], order[rows]] = self._random_value(p, rng, len(rows[0]))
            taken += heads.sum(axis=1)
        return actions

    def legal_actions(self, state: State, index: int = 0, limit: int = 100_000) -> dict[str, Array]:
        """Every legal joint action of a boolean action space in one state,
        stacked along the batch axis (noop first when legal): all sets of at
        most max-nondef-actions groundings set to their non-default value,
        filtered by the preconditions. Raises if there are more than `limit`."""
        grounds = self._groundings()
        for p, _ in grounds:
            if p.range != "bool":
                raise SimulationError(f"legal_actions enumerates boolean actions only; '{p.name}' is {p.range}")
        k_max = len(grounds) if self.model.max_nondef_actions is None else min(self.model.max_nondef_actions, len(grounds))
        count = sum(_comb(len(grounds), k) for k in range(k_max + 1))
        if count > limit:
            raise SimulationError(f"{count} candidate joint actions, more than the limit of {limit}")
        combos = [c for k in range(k_max + 1) for c in itertools.combinations(range(len(grounds)), k)]
        actions = self.noop(len(combos))
        for row, combo in enumerate(combos):
            for g in combo:
                p, idx = grounds[g]
                actions[p.name][(row, *idx)] = not self._defaults[p.name][idx]
        one = state[index]
        many = one[[0] * len(combos)]
        ok = self.check_actions(many, actions)
        return {k: v[ok] for k, v in actions.items()}

    # -- wire form ---------------------------------------------------

    def _decode(self, p: PVariable, x: Any) -> Value:
        if p.range in self._c.codes:
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
                    out.append(f"{_wire_name(p.name, args)} = {_wire_value(self._decode(p, arr[idx]))}")
        return out

    def actions_from_names(self, named: Iterable[Mapping[tuple[str, tuple[str, ...]], Value]] | Mapping[tuple[str, tuple[str, ...]], Value]) -> dict[str, Array]:
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
                    idx = tuple(self._c.codes[t][a] for t, a in zip(p.params, args, strict=True))
                except KeyError as err:
                    raise SimulationError(f"'{name}{args}': unknown object {err}") from None
                if p.range in self._c.codes:
                    v = value if isinstance(value, str) and value in self._c.codes[p.range] else "@" + str(value).lstrip("@")
                    if v not in self._c.codes[p.range]:
                        raise SimulationError(f"'{name}': '{value}' is not a value of '{p.range}'")
                    out[name][(b, *idx)] = self._c.codes[p.range][v]
                else:
                    out[name][(b, *idx)] = value
        return out


def _wire_name(name: str, args: tuple[str, ...]) -> str:
    return f"{name}({','.join(args)})" if args else name


def _wire_value(v: Value) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    return str(v)
