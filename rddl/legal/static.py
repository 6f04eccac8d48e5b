"""Values of the parts of a constraint that read no action, in one state.

`_Static` evaluates an expression without actions over a scope of
variables with numpy (one axis per variable), with the simulator's
semantics: enum values compared by their codes (declaration order) and
used as numbers where their names are integers, bool as 0/1 in
arithmetic, `/` a real division. `Layout` numbers the action variables
(every grounding of every action fluent) and knows the codes of enum and
object values. May read the model; calls nothing of the simulator.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from .. import ast as A
from ..model import ACTION, NON_FLUENT, STATE, Model, PVariable
from ..sim_types import int_enum_value

Array = np.ndarray
Ground = tuple[Any, ...]
Scope = tuple[tuple[str, str], ...]  # (variable, type), outermost first

TRUE: Ground = ("c", 1)
FALSE: Ground = ("c", 0)
_INF = math.inf

# functions that are monotone (non-decreasing) over their domain: the
# interval rules apply them to the ends of an interval
MONOTONE = {"exp", "ln", "sqrt", "floor", "ceil", "round", "sgn", "sign", "atan", "sinh", "tanh"}
_NUMPY_FN: dict[str, Callable[..., Any]] = {
    "exp": np.exp,
    "ln": np.log,
    "sqrt": np.sqrt,
    "cos": np.cos,
    "sin": np.sin,
    "tan": np.tan,
    "acos": np.arccos,
    "asin": np.arcsin,
    "atan": np.arctan,
    "cosh": np.cosh,
    "sinh": np.sinh,
    "tanh": np.tanh,
    "floor": np.floor,
    "ceil": np.ceil,
    "round": np.round,
    "sgn": np.sign,
    "sign": np.sign,
    "abs": np.abs,
}


class NotStatic(Exception):
    """An expression the static evaluator cannot compute (internal)."""


class Layout:
    """The action variables of a model: every grounding of every action
    fluent, fluent by fluent in declaration order, each fluent's groundings
    in row-major order (as the simulator's arrays hold them)."""

    def __init__(self, model: Model) -> None:
        self.model = model
        self.codes = {
            t: {m: i for i, m in enumerate(info.members)} for t, info in model.types.items()
        }
        self.fluents: list[PVariable] = [p for p in model.pvariables.values() if p.kind == ACTION]
        self.offset: dict[str, int] = {}
        self.shape: dict[str, tuple[int, ...]] = {}
        n = 0
        for p in self.fluents:
            shape = tuple(len(model.types[t].members) for t in p.params)
            self.offset[p.name] = n
            self.shape[p.name] = shape
            n += int(np.prod(shape, dtype=np.int64)) if shape else 1
        self.size = n
        self.fluent_of: list[PVariable] = []
        for p in self.fluents:
            self.fluent_of.extend([p] * self.count(p.name))
        self.defaults: list[int | float] = [
            self.encode(p, model.default_of(p)) for p in self.fluent_of
        ]
        self.numeric_of_code: dict[str, Array] = {}
        for t, info in model.types.items():
            if info.kind == "enum":
                ints = [int_enum_value(m) for m in info.members]  # as the simulator reads them
                if all(v is not None for v in ints):
                    self.numeric_of_code[t] = np.array(ints, dtype=np.int64)

    def count(self, name: str) -> int:
        shape = self.shape[name]
        return int(np.prod(shape, dtype=np.int64)) if shape else 1

    def encode(self, p: PVariable, value: Any) -> int | float:
        """A value of `p` as a number (codes for enum and object values)."""
        if p.range in self.codes:
            return self.codes[p.range][value]
        if p.range == "bool":
            return int(bool(value))
        return int(value) if p.range == "int" else float(value)

    def var_name(self, i: int) -> str:
        """'name(arg1,arg2)' of action variable i."""
        p = self.fluent_of[i]
        idx = np.unravel_index(i - self.offset[p.name], self.shape[p.name]) if p.params else ()
        args = [self.model.types[t].members[int(k)] for t, k in zip(p.params, idx, strict=True)]
        return f"{p.name}({','.join(args)})" if args else p.name

    def code_of(self, name: str, hint: str | None) -> tuple[int, str]:
        """Code and type of an enum value or object name (as the simulator
        resolves them: the hinted type first)."""
        if hint is not None and name in self.codes.get(hint, {}):
            return self.codes[hint][name], hint
        if not name.startswith("@") and hint is not None and "@" + name in self.codes.get(hint, {}):
            return self.codes[hint]["@" + name], hint
        for t, info in self.model.types.items():
            if name in self.codes[t] and (name.startswith("@") == (info.kind == "enum")):
                return self.codes[t][name], t
        for t in self.codes:
            if name in self.codes[t]:
                return self.codes[t][name], t
        raise NotStatic(f"unknown object or enum value '{name}'")


# --------------------------------------------------------- static values


class _Static:
    """Evaluates expressions without actions over a scope: every result has
    one axis per scope variable (size 1 where it does not depend on it)."""

    def __init__(self, layout: Layout, values: Mapping[str, Array]) -> None:
        self.layout = layout
        self.model = layout.model
        self.values = values  # state and non-fluent arrays of one state, (*params)

    def size(self, t: str) -> int:
        return len(self.model.types[t].members)

    def eval(self, e: A.Expr, scope: Scope, hint: str | None = None) -> tuple[Array, str | None]:
        """(values, enum or object type of the values or None)."""
        rank = len(scope)
        one = (1,) * rank
        if isinstance(e, A.Const):
            return np.full(one, e.value), None
        if isinstance(e, (A.EnumLit, A.ObjectLit)):
            code, t = self.layout.code_of(e.name, hint)
            return np.full(one, code, dtype=np.int64), t
        if isinstance(e, A.Var):
            pos = [i for i, (v, _) in enumerate(scope) if v == e.name]
            if not pos:
                raise NotStatic(f"free variable {e.name}")
            i = pos[-1]
            t = scope[i][1]
            shape = [1] * rank
            shape[i] = self.size(t)
            return np.arange(self.size(t), dtype=np.int64).reshape(shape), t
        if isinstance(e, A.PVar):
            return self._pvar(e, scope, hint)
        if isinstance(e, A.Unary):
            x = self.numeric(e.operand, scope) if e.op != "~" else self.truth(e.operand, scope)
            if e.op == "~":
                return ~x, None
            return (-x if e.op == "-" else x), None
        if isinstance(e, A.Binary):
            return self._binary(e, scope), None
        if isinstance(e, A.Aggregation):
            return self._aggregation(e, scope)
        if isinstance(e, A.If):
            c = self.truth(e.cond, scope)
            a, ta = self.eval(e.then, scope, hint)
            b, tb = self.eval(e.else_, scope, hint or ta)
            return np.where(c, a, b), ta or tb
        if isinstance(e, A.Switch):
            subject, st = self.eval(e.subject, scope)
            out: Array | None = None
            otype: str | None = None
            default: Array | None = None
            picks: list[tuple[Array, Array]] = []
            for case in e.cases:
                val, vt = self.eval(case.value, scope, hint)
                otype = otype or vt
                if case.label is None:
                    default = val
                else:
                    lab, _ = self.eval(case.label, scope, st)
                    picks.append((subject == lab, val))
            out = default if default is not None else picks[-1][1]
            for cond, val in reversed(picks):
                out = np.where(cond, val, out)
            return out, otype
        if isinstance(e, A.Function):
            return self._function(e, scope), None
        raise NotStatic(f"{type(e).__name__} in a constraint")

    def truth(self, e: A.Expr, scope: Scope) -> Array:
        x, _ = self.eval(e, scope)
        return x if x.dtype == np.bool_ else x != 0

    def numeric(self, e: A.Expr, scope: Scope) -> Array:
        x, t = self.eval(e, scope)
        if t is not None and t in self.layout.numeric_of_code:
            return self.layout.numeric_of_code[t][x]  # type: ignore[no-any-return]
        return x.astype(np.int64) if x.dtype == np.bool_ else x

    def _pvar(self, e: A.PVar, scope: Scope, hint: str | None) -> tuple[Array, str | None]:
        p = self.model.pvariables.get(e.name)
        rank = len(scope)
        if p is None:
            if e.args:
                raise NotStatic(f"unknown pvariable {e.name}")
            code, t = self.layout.code_of(e.name, hint)
            return np.full((1,) * rank, code, dtype=np.int64), t
        etype = p.range if p.range in self.layout.codes else None
        if e.default:
            value = self.layout.encode(p, self.model.default_of(p))
            return np.full((1,) * rank, value), etype
        if p.kind not in (STATE, NON_FLUENT) or e.primed:
            raise NotStatic(f"{e.name} is not known before the step")
        arr = self.values[p.name]
        if not p.params:
            return np.asarray(arr).reshape((1,) * rank), etype
        index = [self.index_of(a, t, scope) for a, t in zip(e.args, p.params, strict=True)]
        return np.asarray(arr[tuple(index)]).reshape(_broadcast_shape(index, rank)), etype

    def index_of(self, a: A.Expr, t: str, scope: Scope) -> Array:
        """An argument as codes of type t, with the scope's rank."""
        if isinstance(a, (A.EnumLit, A.ObjectLit)) or (
            isinstance(a, A.PVar) and a.name not in self.model.pvariables
        ):
            code, _ = self.layout.code_of(a.name, t)
            return np.full((1,) * len(scope), code, dtype=np.int64)
        x, _ = self.eval(a, scope, t)
        return x.astype(np.int64)

    def _binary(self, e: A.Binary, scope: Scope) -> Array:
        op = e.op
        if op in ("^", "|", "=>", "<=>"):
            a = self.truth(e.left, scope)
            b = self.truth(e.right, scope)
            if op == "^":
                return a & b
            if op == "|":
                return a | b
            if op == "=>":
                return ~a | b
            return a == b
        if op in ("==", "~="):
            left, lt = self.eval(e.left, scope)
            right, rt = self.eval(e.right, scope, lt)
            if lt != rt:  # mixed forms compare as numbers
                left = self.numeric(e.left, scope)
                right = self.numeric(e.right, scope)
            return (left == right) if op == "==" else (left != right)
        a = self.numeric(e.left, scope)
        b = self.numeric(e.right, scope)
        with np.errstate(all="ignore"):
            if op == "+":
                return a + b
            if op == "-":
                return a - b
            if op == "*":
                return a * b
            if op == "/":
                return np.true_divide(a, b)
            if op == "<":
                return a < b
            if op == "<=":
                return a <= b
            if op == ">":
                return a > b
            if op == ">=":
                return a >= b
        raise NotStatic(f"operator {op}")

    def _aggregation(self, e: A.Aggregation, scope: Scope) -> tuple[Array, str | None]:
        inner = scope + tuple((v.name, v.type) for v in e.params)
        k = len(e.params)
        axes = tuple(range(len(scope), len(inner)))
        full = (1,) * len(scope) + tuple(self.size(v.type) for v in e.params)
        op = e.op
        if op in ("forall", "exists"):
            truth = self.truth(e.body, inner)
            body = np.broadcast_to(truth, np.broadcast_shapes(full, truth.shape))
            red = body.all(axis=axes) if op == "forall" else body.any(axis=axes)
            return np.asarray(red).reshape(red.shape[: len(scope)]), None
        if op in ("argmax", "argmin") and k == 1:
            x = self.numeric(e.body, inner)
            x = np.broadcast_to(x, np.broadcast_shapes(full, x.shape))
            red = x.argmax(axis=-1) if op == "argmax" else x.argmin(axis=-1)
            return red.astype(np.int64), e.params[0].type
        x = self.numeric(e.body, inner)
        x = np.broadcast_to(x, np.broadcast_shapes(full, x.shape))
        n = int(np.prod([self.size(v.type) for v in e.params]))
        if op == "sum":
            red = x.sum(axis=axes)
        elif op == "prod":
            red = x.prod(axis=axes)
        elif op == "min":
            red = x.min(axis=axes) if n else np.full(x.shape[: len(scope)], _INF)
        elif op == "max":
            red = x.max(axis=axes) if n else np.full(x.shape[: len(scope)], -_INF)
        elif op == "avg":
            red = x.sum(axis=axes) / max(n, 1)
        else:
            raise NotStatic(f"aggregation {op}")
        return np.asarray(red), None

    def _function(self, e: A.Function, scope: Scope) -> Array:
        args = [self.numeric(a, scope) for a in e.args]
        name = e.name
        with np.errstate(all="ignore"):
            if name in _NUMPY_FN and len(args) == 1:
                out = _NUMPY_FN[name](args[0].astype(np.float64))
                if name in ("floor", "ceil", "round", "sgn", "sign"):
                    return out.astype(np.int64)  # type: ignore[no-any-return]
                if name == "abs" and args[0].dtype != np.float64:
                    return out.astype(args[0].dtype)  # type: ignore[no-any-return]
                return out  # type: ignore[no-any-return]
            if len(args) == 2:
                a, b = args
                if name == "min":
                    return np.minimum(a, b)
                if name == "max":
                    return np.maximum(a, b)
                if name == "pow":
                    return np.power(a.astype(np.float64), b)
                if name == "log":
                    return np.log(a) / np.log(b)  # type: ignore[no-any-return]
                if name == "hypot":
                    return np.hypot(a, b)
                if name in ("mod", "fmod"):
                    return np.fmod(a, b)
                if name == "div":
                    return np.trunc(np.true_divide(a, b)).astype(np.int64)  # type: ignore[no-any-return]
        raise NotStatic(f"function {name}")


def _broadcast_shape(index: list[Array], rank: int) -> tuple[int, ...]:
    shape = np.broadcast_shapes(*(i.shape for i in index)) if index else ()
    return tuple(shape) if len(shape) == rank else (1,) * (rank - len(shape)) + tuple(shape)
