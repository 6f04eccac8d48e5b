"""Box bounds of int and real fluents, read from the domain's constraints.

A `Box` (or a bounded `Discrete` for an int) needs bounds, which RDDL gives
only through constraints: `action-preconditions` bound the actions
(`forall_{?r : res} [release(?r) <= MAX_RELEASE(?r)]`) and `state-invariants`
the states. As pyRDDLGym does, a bound is read from a comparison (`<=`, `<`,
`>=`, `>`) between a fluent and an expression of constants and non-fluents,
at the top of a constraint, under conjunctions (`^`) and under `forall`
(each grounding of the quantified variables gives one bound). Everything
else (a comparison of two fluents, a disjunction, an implication) bounds
nothing, and the fluent stays unbounded on that side. `<` and `>` bound an
int by the next integer and a real by the value itself (a Box is closed).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping

import numpy as np

from ..rddl import ast as A
from ..rddl.model import NON_FLUENT, Model, PVariable

__all__ = ["fluent_bounds"]

# groundings of a forall's variables walked at most (a bound is a cheap
# nicety; a huge quantifier is left unread rather than slow to build)
_MAX_BINDINGS = 200_000

_FLIP = {"<=": ">=", "<": ">", ">=": "<=", ">": "<"}


def fluent_bounds(
    model: Model, constraints: Iterable[A.Expr], fluents: Iterable[PVariable]
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{name: (low, high)} for the int and real fluents given, arrays shaped by
    their parameters (-inf and inf where the constraints say nothing)."""
    targets = {p.name: p for p in fluents if p.range in ("int", "real")}
    shapes = {n: tuple(len(model.objects(t)) for t in p.params) for n, p in targets.items()}
    out = {n: (np.full(s, -np.inf), np.full(s, np.inf)) for n, s in shapes.items()}
    reader = _Reader(model, targets, out)
    for expr in constraints:
        reader.walk(expr, {})
    return out


class _Reader:
    def __init__(
        self,
        model: Model,
        targets: Mapping[str, PVariable],
        out: dict[str, tuple[np.ndarray, np.ndarray]],
    ) -> None:
        self.model = model
        self.targets = targets
        self.out = out
        self.index = {
            t: {m: i for i, m in enumerate(info.members)} for t, info in model.types.items()
        }

    def walk(self, e: A.Expr, env: dict[str, str]) -> None:
        if isinstance(e, A.Aggregation) and e.op == "forall":
            members = [self.model.objects(v.type) for v in e.params]
            if math.prod(len(m) for m in members) > _MAX_BINDINGS:
                return
            names = [v.name for v in e.params]
            for combo in itertools.product(*members):
                self.walk(e.body, {**env, **dict(zip(names, combo, strict=True))})
        elif isinstance(e, A.Binary) and e.op == "^":
            self.walk(e.left, env)
            self.walk(e.right, env)
        elif isinstance(e, A.Binary) and e.op in _FLIP:
            if self._target(e.left):
                self._bound(e.left, e.op, e.right, env)
            elif self._target(e.right):
                self._bound(e.right, _FLIP[e.op], e.left, env)

    def _target(self, e: A.Expr) -> bool:
        return isinstance(e, A.PVar) and not e.primed and e.name in self.targets

    def _bound(self, var: A.Expr, op: str, other: A.Expr, env: dict[str, str]) -> None:
        assert isinstance(var, A.PVar)
        p = self.targets[var.name]
        idx = self._index(p, var.args, env)
        value = self._constant(other, env)
        if idx is None or value is None or math.isnan(value):
            return
        low, high = self.out[p.name]
        integral = p.range == "int"
        if op in ("<=", "<"):
            if integral:
                value = math.floor(value) - (1 if op == "<" and value == math.floor(value) else 0)
            high[idx] = min(high[idx], value)
        else:
            if integral:
                value = math.ceil(value) + (1 if op == ">" and value == math.ceil(value) else 0)
            low[idx] = max(low[idx], value)

    def _index(
        self, p: PVariable, args: tuple[A.Expr, ...], env: dict[str, str]
    ) -> tuple[int, ...] | None:
        if len(args) != p.arity:
            return None
        idx = []
        for a, t in zip(args, p.params, strict=True):
            name = self._object(a, env)
            if name is None or name not in self.index.get(t, {}):
                return None
            idx.append(self.index[t][name])
        return tuple(idx)

    @staticmethod
    def _object(a: A.Expr, env: dict[str, str]) -> str | None:
        if isinstance(a, A.Var):
            return env.get(a.name)
        if isinstance(a, A.ObjectLit | A.EnumLit):
            return a.name
        return None

    def _constant(self, e: A.Expr, env: dict[str, str]) -> float | None:
        """The value of an expression of constants and non-fluents, or None."""
        if isinstance(e, A.Const):
            return float(e.value)
        if isinstance(e, A.Unary) and e.op in ("-", "+"):
            v = self._constant(e.operand, env)
            return None if v is None else (-v if e.op == "-" else v)
        if isinstance(e, A.Binary) and e.op in ("+", "-", "*", "/"):
            a, b = self._constant(e.left, env), self._constant(e.right, env)
            if a is None or b is None:
                return None
            if e.op == "+":
                return a + b
            if e.op == "-":
                return a - b
            if e.op == "*":
                return a * b
            return a / b if b != 0 else None
        if isinstance(e, A.PVar) and not e.primed:
            p = self.model.pvariables.get(e.name)
            if p is None or p.kind != NON_FLUENT or p.range not in ("int", "real", "bool"):
                return None
            args = [self._object(a, env) for a in e.args]
            if any(a is None for a in args) or len(args) != p.arity:
                return None
            return float(self.model.value_of(e.name, tuple(a for a in args if a is not None)))
        return None
