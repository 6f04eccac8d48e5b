"""Ground the action constraints of one state into small formulas over the
action groundings (for `ippc.rddl.legal`).

The action preconditions and state-action constraints of a domain are
lifted: `forall_{?r : ranger} (sum_{?a : area} defend(?a, ?r)) == 1`. In a
given state every part that reads no action is a known value, so each
constraint becomes a handful of small *ground formulas* over the *action
variables* (one per grounding of each action fluent): here one
`defend(a1, r) + defend(a2, r) + ... == 1` per ranger r. `Grounder`
does this:

* Parts without actions are evaluated with numpy, vectorised over their
  free variables, once per state (`_Static`), with the simulator's
  semantics (enum values compared by code, used as numbers where their
  names are integers, `/` real division).
* Parts with actions are expanded over the objects: `forall` and `^` split a
  constraint into separate formulas (*elements*), `exists`, `sum`, `prod`,
  `min` and `max` become n-ary nodes, and every constructor folds
  constants, so `take-course(?c) => ~passed(?c)` leaves `~take-course(c1)`
  where c1 is passed and nothing where it is not.
* What cannot be judged before a step (an interm, derived or observ
  fluent; an action used as an object argument; a function the interval
  rules do not know) becomes an *opaque* node whose value is only bounded
  (`("u", lo, hi)`); `ippc.rddl.legal` then leaves the final word to
  `Simulator.check_actions`.

A ground formula is a tuple: `("c", value)`, `("x", var)`, `("u", lo, hi)`,
or `(op, child, ...)` with op one of and, or, not, add, neg, mul, div, eq,
ne, lt, le, gt, ge, ite, min, max, abs and `fn` (`("fn", name, child...)`,
for the monotone functions). Values are numbers: bool as 0/1, enum and
object values as their codes (declaration order), ints and reals as such.
This module reads the model and the state; it calls nothing of the
simulator.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import ast as A
from ..model import ACTION, NON_FLUENT, STATE, Model
from .static import (
    _NUMPY_FN,
    FALSE,
    MONOTONE,
    TRUE,
    Array,
    Ground,
    Layout,
    NotStatic,
    Scope,
    _Static,
)

_INF = math.inf


@dataclass(frozen=True)
class Element:
    """One ground formula that must hold: from constraint `index` of the
    domain's preconditions and state-action constraints (in that order), at
    the binding `env` of the variables of its outer `forall`s."""

    formula: Ground
    index: int
    env: tuple[tuple[str, str], ...]  # (variable, object name)


# ------------------------------------------------------------- grounding


def node_reads(model: Model, expr: A.Expr) -> tuple[bool, bool]:
    """(reads an action or a fluent unknown before the step, reads a state
    fluent)."""
    dyn = False
    state = False
    for node in A.walk(expr):
        if isinstance(node, A.PVar) and not node.default:
            p = model.pvariables.get(node.name)
            if p is None:
                continue
            if p.kind == STATE and not node.primed:
                state = True
            elif p.kind != NON_FLUENT:
                dyn = True
    return dyn, state


class Grounder:
    """Ground formulas of the constraints in one state (see the module
    docstring). `dyn` caches which AST nodes read actions."""

    def __init__(self, layout: Layout, values: Mapping[str, Array], dyn: dict[int, bool]):
        self.layout = layout
        self.model = layout.model
        self.static = _Static(layout, values)
        self._dyn = dyn
        self._cache: dict[tuple[int, Scope], tuple[Array, str | None] | None] = {}

    def is_dyn(self, e: A.Expr) -> bool:
        got = self._dyn.get(id(e))
        if got is None:
            got = self._dyn[id(e)] = node_reads(self.model, e)[0]
        return got

    def elements(self, exprs: list[A.Expr]) -> Iterator[Element]:
        """Every element of every constraint (constant true ones left out;
        a constant false one is yielded as FALSE)."""
        for k, expr in enumerate(exprs):
            for formula, env in self._split(expr, ()):
                if formula != TRUE:
                    yield Element(formula, k, tuple((v, self._object(t, i)) for v, t, i in env))

    def _object(self, t: str, i: int) -> str:
        return self.model.types[t].members[i]

    def _split(
        self, e: A.Expr, env: tuple[tuple[str, str, int], ...]
    ) -> Iterator[tuple[Ground, tuple[tuple[str, str, int], ...]]]:
        if isinstance(e, A.Aggregation) and e.op == "forall" and self.is_dyn(e.body):
            for binding in self._bindings(e.params):
                yield from self._split(e.body, env + binding)
            return
        if isinstance(e, A.Binary) and e.op == "^":
            yield from self._split(e.left, env)
            yield from self._split(e.right, env)
            return
        g = self.truth(e, env)
        if g[0] == "and":
            for child in g[1:]:
                yield child, env
        else:
            yield g, env

    def _bindings(
        self, params: tuple[A.TypedVar, ...]
    ) -> Iterator[tuple[tuple[str, str, int], ...]]:
        sizes = [len(self.model.types[v.type].members) for v in params]
        for idx in itertools.product(*(range(n) for n in sizes)):
            yield tuple((v.name, v.type, i) for v, i in zip(params, idx, strict=True))

    # -- static parts ------------------------------------------------

    def _value(
        self, e: A.Expr, env: tuple[tuple[str, str, int], ...], hint: str | None
    ) -> tuple[Any, str | None] | None:
        """The known value of an action-free expression at this binding, or
        None where it cannot be computed statically."""
        scope: Scope = tuple((v, t) for v, t, _ in env)
        key = (id(e), scope)
        if key in self._cache:
            got = self._cache[key]
        else:
            try:
                got = self.static.eval(e, scope, hint)
            except (NotStatic, IndexError, ValueError, KeyError, TypeError):
                got = None
            self._cache[key] = got
        if got is None:
            return None
        arr, t = got
        idx = tuple(i if arr.shape[k] > 1 else 0 for k, (_, _, i) in enumerate(env))
        return arr[idx].item() if arr.ndim else arr.item(), t

    # -- dynamic parts -----------------------------------------------

    def truth(self, e: A.Expr, env: tuple[tuple[str, str, int], ...]) -> Ground:
        g, _ = self.ground(e, env)
        if g[0] == "x" and self.layout.fluent_of[g[1]].range != "bool":
            return compare("ne", g, ("c", 0))  # a number read as a truth value
        return to_truth(g)

    def ground(
        self, e: A.Expr, env: tuple[tuple[str, str, int], ...], hint: str | None = None
    ) -> tuple[Ground, str | None]:
        """(formula, enum or object type of its value or None)."""
        if not self.is_dyn(e):
            got = self._value(e, env, hint)
            if got is None:
                return opaque_like(e, self.model), None
            value, t = got
            return ("c", _num(value)), t
        if isinstance(e, A.PVar):
            return self._action(e, env)
        if isinstance(e, A.Unary):
            if e.op == "~":
                return neg_truth(self.truth(e.operand, env)), None
            x = self.numeric(e.operand, env)
            return (negate(x) if e.op == "-" else x), None
        if isinstance(e, A.Binary):
            return self._binary(e, env), None
        if isinstance(e, A.Aggregation):
            return self._aggregation(e, env), None
        if isinstance(e, A.If):
            c = self.truth(e.cond, env)
            a, ta = self.ground(e.then, env, hint)
            b, tb = self.ground(e.else_, env, hint or ta)
            return ite(c, a, b), ta or tb
        if isinstance(e, A.Switch):
            subject, st = self.ground(e.subject, env)
            out: Ground | None = None
            otype: str | None = None
            arms: list[tuple[Ground, Ground]] = []
            for case in e.cases:
                val, vt = self.ground(case.value, env, hint)
                otype = otype or vt
                if case.label is None:
                    out = val
                else:
                    lab, _ = self.ground(case.label, env, st)
                    arms.append((compare("eq", subject, lab), val))
            if out is None:
                out = arms[-1][1]
            for cond, val in reversed(arms):
                out = ite(cond, val, out)
            return out, otype
        if isinstance(e, A.Function):
            args = [self.numeric(a, env) for a in e.args]
            return function(e.name, args), None
        return opaque_like(e, self.model), None

    def numeric(self, e: A.Expr, env: tuple[tuple[str, str, int], ...]) -> Ground:
        g, t = self.ground(e, env)
        if t is not None and t in self.layout.numeric_of_code:
            table = self.layout.numeric_of_code[t]
            if g[0] == "c":
                return ("c", int(table[int(g[1])]))
            return ("u", float(table.min()), float(table.max())) if len(table) else g
        return g

    def _action(
        self, e: A.PVar, env: tuple[tuple[str, str, int], ...]
    ) -> tuple[Ground, str | None]:
        p = self.model.pvariables.get(e.name)
        if p is None or p.kind != ACTION or e.primed:
            return opaque_like(e, self.model), None
        etype = p.range if p.range in self.layout.codes else None
        idx: list[int] = []
        for a, t in zip(e.args, p.params, strict=True):
            if isinstance(a, A.Var):
                found = [i for v, _, i in env if v == a.name]
                if not found:
                    return opaque_like(e, self.model), etype
                idx.append(found[-1])
                continue
            if self.is_dyn(a):
                return opaque_like(e, self.model), etype
            try:
                if isinstance(a, (A.EnumLit, A.ObjectLit)) or (
                    isinstance(a, A.PVar) and a.name not in self.model.pvariables
                ):
                    idx.append(self.layout.code_of(a.name, t)[0])
                    continue
            except NotStatic:
                return opaque_like(e, self.model), etype
            got = self._value(a, env, t)
            if got is None:
                return opaque_like(e, self.model), etype
            idx.append(int(got[0]))
        shape = self.layout.shape[p.name]
        flat = int(np.ravel_multi_index(idx, shape)) if shape else 0
        return ("x", self.layout.offset[p.name] + flat), etype

    def _binary(self, e: A.Binary, env: tuple[tuple[str, str, int], ...]) -> Ground:
        op = e.op
        if op in ("^", "|", "=>", "<=>"):
            a = self.truth(e.left, env)
            b = self.truth(e.right, env)
            if op == "^":
                return conj([a, b])
            if op == "|":
                return disj([a, b])
            if op == "=>":
                return disj([neg_truth(a), b])
            return compare("eq", a, b)
        if op in ("==", "~="):
            left, lt = self.ground(e.left, env)
            right, rt = self.ground(e.right, env, lt)
            if lt != rt:
                left = self.numeric(e.left, env)
                right = self.numeric(e.right, env)
            return compare("eq" if op == "==" else "ne", left, right)
        a = self.numeric(e.left, env)
        b = self.numeric(e.right, env)
        if op == "+":
            return add([a, b])
        if op == "-":
            return add([a, negate(b)])
        if op == "*":
            return mul(a, b)
        if op == "/":
            return divide(a, b)
        cmp = {"<": "lt", "<=": "le", ">": "gt", ">=": "ge"}.get(op)
        if cmp is None:
            return ("u", -_INF, _INF)
        return compare(cmp, a, b)

    def _aggregation(self, e: A.Aggregation, env: tuple[tuple[str, str, int], ...]) -> Ground:
        op = e.op
        parts: list[Ground] = []
        for binding in self._bindings(e.params):
            inner = env + binding
            parts.append(
                self.truth(e.body, inner)
                if op in ("forall", "exists")
                else self.numeric(e.body, inner)
            )
        if op == "forall":
            return conj(parts)
        if op == "exists":
            return disj(parts)
        if op == "sum":
            return add(parts)
        if op == "avg":
            return mul(("c", 1.0 / max(1, len(parts))), add(parts))
        if op == "prod":
            out: Ground = ("c", 1)
            for part in parts:
                out = mul(out, part)
            return out
        if op in ("min", "max"):
            return extreme(op, parts)
        return ("u", -_INF, _INF)


# ------------------------------------------------- formula constructors


def _num(value: Any) -> int | float:
    if isinstance(value, (bool, np.bool_)):
        return int(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    return float(value)


def opaque_like(e: A.Expr, model: Model) -> Ground:
    """A value only known to lie in its type's range."""
    if isinstance(e, A.PVar):
        p = model.pvariables.get(e.name)
        if p is not None and p.range == "bool":
            return ("u", 0, 1)
    return ("u", -_INF, _INF)


def is_bool(g: Ground) -> bool:
    """Whether a formula's value is 0/1 by construction."""
    return (
        g[0] in ("and", "or", "not", "eq", "ne", "lt", "le", "gt", "ge")
        or (g[0] == "c" and g[1] in (0, 1))
        or (g[0] == "u" and g[1] >= 0 and g[2] <= 1)
    )


def to_truth(g: Ground) -> Ground:
    """A formula read as a truth value (non-zero is true)."""
    if g[0] == "c":
        return TRUE if g[1] != 0 else FALSE
    if g[0] == "x" or is_bool(g):
        return g  # bool action variables are 0/1 already; others: see `ne`
    return compare("ne", g, ("c", 0))


def neg_truth(g: Ground) -> Ground:
    if g[0] == "c":
        return FALSE if g[1] else TRUE
    if g[0] == "not":
        return g[1]  # type: ignore[no-any-return]
    flip = {"eq": "ne", "ne": "eq", "lt": "ge", "ge": "lt", "gt": "le", "le": "gt"}
    if g[0] in flip:
        return (flip[g[0]], g[1], g[2])
    return ("not", g)


def conj(parts: list[Ground]) -> Ground:
    out: list[Ground] = []
    for p in parts:
        if p == FALSE or (p[0] == "c" and not p[1]):
            return FALSE
        if p[0] == "c":
            continue
        if p[0] == "and":
            out.extend(p[1:])
        else:
            out.append(p)
    if not out:
        return TRUE
    return out[0] if len(out) == 1 else ("and", *out)


def disj(parts: list[Ground]) -> Ground:
    out: list[Ground] = []
    for p in parts:
        if p[0] == "c" and p[1]:
            return TRUE
        if p[0] == "c":
            continue
        if p[0] == "or":
            out.extend(p[1:])
        else:
            out.append(p)
    if not out:
        return FALSE
    return out[0] if len(out) == 1 else ("or", *out)


def add(parts: list[Ground]) -> Ground:
    const: int | float = 0
    out: list[Ground] = []
    for p in parts:
        if p[0] == "c":
            const += p[1]
        elif p[0] == "add":
            for q in p[1:]:
                if q[0] == "c":
                    const += q[1]
                else:
                    out.append(q)
        else:
            out.append(p)
    if not out:
        return ("c", const)
    if const != 0:
        out.append(("c", const))
    return out[0] if len(out) == 1 else ("add", *out)


def negate(g: Ground) -> Ground:
    if g[0] == "c":
        return ("c", -g[1])
    if g[0] == "neg":
        return g[1]  # type: ignore[no-any-return]
    return ("neg", g)


def mul(a: Ground, b: Ground) -> Ground:
    if a[0] == "c" and b[0] == "c":
        return ("c", a[1] * b[1])
    for x, y in ((a, b), (b, a)):
        if x[0] == "c":
            if x[1] == 0 and y[0] != "u":
                return ("c", 0)
            if x[1] == 1:
                return y
    return ("mul", a, b)


def divide(a: Ground, b: Ground) -> Ground:
    if a[0] == "c" and b[0] == "c":
        with np.errstate(all="ignore"):
            return ("c", float(np.true_divide(a[1], b[1])))
    if b[0] == "c" and b[1] != 0:
        return mul(("c", 1.0 / b[1]), a) if b[1] not in (1, -1) else (a if b[1] == 1 else negate(a))
    return ("div", a, b)


def compare(op: str, a: Ground, b: Ground) -> Ground:
    if a[0] == "c" and b[0] == "c":
        x, y = a[1], b[1]
        result = {
            "eq": x == y,
            "ne": x != y,
            "lt": x < y,
            "le": x <= y,
            "gt": x > y,
            "ge": x >= y,
        }[op]
        return TRUE if result else FALSE
    return (op, a, b)


def ite(c: Ground, a: Ground, b: Ground) -> Ground:
    if c[0] == "c":
        return a if c[1] else b
    if a == b:
        return a
    return ("ite", c, a, b)


def extreme(op: str, parts: list[Ground]) -> Ground:
    if not parts:
        return ("c", _INF if op == "min" else -_INF)
    consts = [p[1] for p in parts if p[0] == "c"]
    rest = [p for p in parts if p[0] != "c"]
    if consts:
        rest.append(("c", min(consts) if op == "min" else max(consts)))
    return rest[0] if len(rest) == 1 else (op, *rest)


def function(name: str, args: list[Ground]) -> Ground:
    if all(a[0] == "c" for a in args):
        try:
            with np.errstate(all="ignore"):
                if name in _NUMPY_FN and len(args) == 1:
                    return ("c", _num(_NUMPY_FN[name](float(args[0][1]))))
                if name in ("min", "max") and len(args) == 2:
                    return ("c", (min if name == "min" else max)(args[0][1], args[1][1]))
        except (ValueError, OverflowError):
            pass
        return ("u", -_INF, _INF)
    if name in ("min", "max") and len(args) == 2:
        return extreme(name, args)
    if name == "abs" and len(args) == 1:
        return ("abs", args[0])
    if name in MONOTONE and len(args) == 1:
        return ("fn", name, args[0])
    return ("u", -_INF, _INF)


def variables(g: Ground) -> set[int]:
    """The action variables a formula reads."""
    out: set[int] = set()
    todo = [g]
    while todo:
        n = todo.pop()
        tag = n[0]
        if tag == "x":
            out.add(n[1])
        elif tag in ("c", "u"):
            continue
        elif tag == "fn":
            todo.append(n[2])
        else:
            todo.extend(n[1:])
    return out


def linear(g: Ground) -> tuple[dict[int, float], float] | None:
    """`g` as coefficients and a constant (sum of c_i x_i + k), or None.
    Only numeric action variables may appear (the caller checks that)."""
    tag = g[0]
    if tag == "c":
        return {}, g[1]
    if tag == "x":
        return {g[1]: 1}, 0
    if tag == "not" and g[1][0] == "x":
        return {g[1][1]: -1}, 1
    if tag == "neg":
        inner = linear(g[1])
        if inner is None:
            return None
        return {k: -v for k, v in inner[0].items()}, -inner[1]
    if tag == "add":
        coefs: dict[int, float] = {}
        const: float = 0
        for part in g[1:]:
            got = linear(part)
            if got is None:
                return None
            for k, v in got[0].items():
                coefs[k] = coefs.get(k, 0) + v
            const += got[1]
        return {k: v for k, v in coefs.items() if v != 0}, const
    if tag == "mul":
        a, b = g[1], g[2]
        if b[0] == "c":
            a, b = b, a
        if a[0] != "c":
            return None
        inner = linear(b)
        if inner is None:
            return None
        return {k: a[1] * v for k, v in inner[0].items() if a[1] * v != 0}, a[1] * inner[1]
    return None
