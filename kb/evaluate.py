"""A small evaluator of deterministic RDDL expressions on one ground state.

The knowledge base needs to decide a formula on its current state (does the
goal hold?) and to ground a lifted formula over the instance's objects,
deciding the parts that read only non-fluents (which destinations does the
goal name?). The simulator (`ippc.rddl.simulator`) compiles whole steps over
batches and cannot answer "this sub-formula, with ?w bound to phdarea"; this
walks the tree instead, one binding at a time, with the simulator's
semantics: bools count as 0 and 1 in arithmetic, `/` is real division, enum
and object values compare by name. Random draws, and fluents the caller
cannot look up (actions, intermediates), raise `NotEvaluable`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

from ..rddl import ast as A
from ..rddl.model import Model, Value

# Looks up a stored fluent's value: (name, object arguments) -> value.
Lookup = Callable[[str, tuple[str, ...]], Value]
Env = Mapping[str, str]  # variable ("?x") -> object or enum value name


class NotEvaluable(Exception):
    """The expression cannot be evaluated here (a draw, an action or
    intermediate fluent, an unknown construct); the message says which."""


_FUNCTIONS: dict[str, Callable[..., Any]] = {
    "exp": math.exp,
    "ln": math.log,
    "sqrt": math.sqrt,
    "cos": math.cos,
    "sin": math.sin,
    "tan": math.tan,
    "acos": math.acos,
    "asin": math.asin,
    "atan": math.atan,
    "cosh": math.cosh,
    "sinh": math.sinh,
    "tanh": math.tanh,
    "floor": math.floor,
    "ceil": math.ceil,
    "round": round,
    "abs": abs,
    "sgn": lambda x: (x > 0) - (x < 0),
    "sign": lambda x: (x > 0) - (x < 0),
    "min": min,
    "max": max,
    "pow": math.pow,
    "log": lambda x, b: math.log(x, b),
    "hypot": math.hypot,
    "fmod": math.fmod,
    "div": lambda a, b: int(a // b),
    "mod": lambda a, b: a % b,
}


def _num(v: Value) -> float | int:
    if isinstance(v, bool):
        return int(v)
    if isinstance(v, (int, float)):
        return v
    raise NotEvaluable(f"'{v}' is not a number")


class Evaluator:
    """Evaluates expressions of one model against a lookup of stored values."""

    def __init__(self, model: Model, lookup: Lookup, stored: Callable[[str], bool]):
        self.model = model
        self.lookup = lookup
        self.stored = stored  # whether a pvariable name can be looked up

    def bindings(self, params: tuple[A.TypedVar, ...], env: Env) -> list[dict[str, str]]:
        """Every extension of `env` with a value for each typed variable."""
        out: list[dict[str, str]] = [dict(env)]
        for tv in params:
            out = [{**e, tv.name: m} for e in out for m in self.model.objects(tv.type)]
        return out

    def args(self, e: A.PVar, env: Env) -> tuple[str, ...]:
        """The object arguments of a fluent reference under `env`."""
        out = []
        for a in e.args:
            v = self(a, env)
            if not isinstance(v, str):
                raise NotEvaluable(f"argument {a} of '{e.name}' is not an object")
            out.append(v)
        return tuple(out)

    def __call__(self, e: A.Expr, env: Env) -> Value:
        if isinstance(e, A.Const):
            return e.value
        if isinstance(e, A.Var):
            if e.name not in env:
                raise NotEvaluable(f"free variable {e.name}")
            return env[e.name]
        if isinstance(e, A.EnumLit):
            return e.name
        if isinstance(e, A.ObjectLit):
            return e.name
        if isinstance(e, A.PVar):
            if e.name not in self.model.pvariables and not e.args:
                return e.name  # a bare object name
            if e.primed or not self.stored(e.name):
                p = self.model.pvariables.get(e.name)
                what = "the next state's " if e.primed else (f"{p.kind} " if p else "")
                raise NotEvaluable(f"{what}'{e.name}' is not known here")
            return self.lookup(e.name, self.args(e, env))
        if isinstance(e, A.Unary):
            v = self(e.operand, env)
            if e.op == "~":
                return not _truth(v)
            if e.op == "-":
                return -_num(v)
            return _num(v)
        if isinstance(e, A.Binary):
            return self._binary(e, env)
        if isinstance(e, A.Aggregation):
            return self._aggregation(e, env)
        if isinstance(e, A.If):
            return self(e.then if _truth(self(e.cond, env)) else e.else_, env)
        if isinstance(e, A.Switch):
            subject = self(e.subject, env)
            for case in e.cases:
                if case.label is None or self(case.label, env) == subject:
                    return self(case.value, env)
            raise NotEvaluable(f"no case of the switch at {e.loc} matches {subject!r}")
        if isinstance(e, A.Function):
            fn = _FUNCTIONS.get(e.name)
            if fn is None:
                raise NotEvaluable(f"function '{e.name}'")
            return fn(*(_num(self(a, env)) for a in e.args))  # type: ignore[no-any-return]
        if isinstance(e, A.Distribution) and e.name in ("KronDelta", "DiracDelta"):
            v = self(e.args[0], env)
            return float(_num(v)) if e.name == "DiracDelta" else v
        raise NotEvaluable(f"{type(e).__name__} at {e.loc}")

    def _binary(self, e: A.Binary, env: Env) -> Value:
        op = e.op
        # Short-circuit the connectives: a guard such as P(?x) ^ f(?x) may
        # make the right side meaningless where P is false.
        if op in ("^", "&"):
            return _truth(self(e.left, env)) and _truth(self(e.right, env))
        if op == "|":
            return _truth(self(e.left, env)) or _truth(self(e.right, env))
        if op == "=>":
            return (not _truth(self(e.left, env))) or _truth(self(e.right, env))
        a, b = self(e.left, env), self(e.right, env)
        if op == "<=>":
            return _truth(a) == _truth(b)
        if op == "==":
            return _same(a, b)
        if op == "~=":
            return not _same(a, b)
        x, y = _num(a), _num(b)
        if op == "<":
            return x < y
        if op == "<=":
            return x <= y
        if op == ">":
            return x > y
        if op == ">=":
            return x >= y
        if op == "+":
            return x + y
        if op == "-":
            return x - y
        if op == "*":
            return x * y
        if op == "/":
            if y == 0:
                raise NotEvaluable(f"division by zero at {e.loc}")
            return x / y
        raise NotEvaluable(f"operator '{op}'")

    def _aggregation(self, e: A.Aggregation, env: Env) -> Value:
        envs = self.bindings(e.params, env)
        if e.op == "forall":
            return all(_truth(self(e.body, b)) for b in envs)
        if e.op == "exists":
            return any(_truth(self(e.body, b)) for b in envs)
        values = [_num(self(e.body, b)) for b in envs]
        if e.op == "sum":
            return sum(values)
        if e.op == "prod":
            return math.prod(values)
        if e.op == "avg":
            return sum(values) / len(values) if values else 0.0
        if e.op == "min":
            return min(values)
        if e.op == "max":
            return max(values)
        raise NotEvaluable(f"aggregation '{e.op}'")


def _truth(v: Value) -> bool:
    if isinstance(v, str):
        raise NotEvaluable(f"'{v}' is not a truth value")
    return bool(v)


def _same(a: Value, b: Value) -> bool:
    if isinstance(a, str) or isinstance(b, str):
        return a == b
    return _num(a) == _num(b)
