"""Rewriting RDDL expressions for the operator translation.

Small tools over `ippc.rddl.ast`: rebuild a node from rewritten children,
substitute variables without capturing bound ones, inline intermediate
fluents (so that an action that acts through `picked-up(?d)` is seen in the
cpf that reads it), and the shapes the translation asks about (conjuncts,
does a fluent occur here).
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable, Iterator

from ..rddl import ast as A
from ..rddl.model import DERIVED, INTERM, Model

TRUE = A.Const(True)
FALSE = A.Const(False)

_fresh = itertools.count(1)


def rebuild(e: A.Expr, f: Callable[[A.Expr], A.Expr]) -> A.Expr:
    """`e` with `f` applied to each direct sub-expression."""
    if isinstance(e, A.PVar):
        return dataclasses.replace(e, args=tuple(f(a) for a in e.args)) if e.args else e
    if isinstance(e, A.Unary):
        return dataclasses.replace(e, operand=f(e.operand))
    if isinstance(e, A.Binary):
        return dataclasses.replace(e, left=f(e.left), right=f(e.right))
    if isinstance(e, (A.Aggregation, A.MatrixOp, A.DiscreteOver)):
        return dataclasses.replace(e, body=f(e.body))
    if isinstance(e, (A.Function, A.Distribution, A.VectorDistribution)):
        return dataclasses.replace(e, args=tuple(f(a) for a in e.args))
    if isinstance(e, A.If):
        return dataclasses.replace(e, cond=f(e.cond), then=f(e.then), else_=f(e.else_))
    if isinstance(e, A.Switch):
        cases = tuple(
            dataclasses.replace(c, label=None if c.label is None else f(c.label), value=f(c.value))
            for c in e.cases
        )
        return dataclasses.replace(e, subject=f(e.subject), cases=cases)
    if isinstance(e, A.Discrete):
        dcs = tuple(
            dataclasses.replace(dc, label=f(dc.label), prob=None if dc.prob is None else f(dc.prob))
            for dc in e.cases
        )
        return dataclasses.replace(e, cases=dcs, count=None if e.count is None else f(e.count))
    return e


def free_vars(e: A.Expr) -> set[str]:
    """The variables of `e` that no quantifier in it binds."""
    if isinstance(e, A.Var):
        return {e.name}
    if isinstance(e, (A.Aggregation, A.DiscreteOver)):
        return free_vars(e.body) - {p.name for p in e.params}
    out: set[str] = set()
    for c in A.children(e):
        out |= free_vars(c)
    return out


def substitute(e: A.Expr, mapping: dict[str, A.Expr]) -> A.Expr:
    """`e` with each free variable of `mapping` replaced; a quantifier whose
    variable would capture a substituted one is renamed first."""
    if not mapping:
        return e
    if isinstance(e, A.Var):
        return mapping.get(e.name, e)
    if isinstance(e, (A.Aggregation, A.DiscreteOver)):
        inner = {k: v for k, v in mapping.items() if k not in {p.name for p in e.params}}
        incoming: set[str] = set()
        for v in inner.values():
            incoming |= free_vars(v)
        params = []
        renames: dict[str, A.Expr] = {}
        for p in e.params:
            if p.name in incoming:
                new = f"{p.name}_{next(_fresh)}"
                renames[p.name] = A.Var(new, p.loc)
                params.append(dataclasses.replace(p, name=new))
            else:
                params.append(p)
        body = substitute(e.body, renames) if renames else e.body
        return dataclasses.replace(e, params=tuple(params), body=substitute(body, inner))
    return rebuild(e, lambda c: substitute(c, mapping))


def inline_interm(e: A.Expr, model: Model, depth: int = 0) -> A.Expr:
    """`e` with every intermediate and derived fluent replaced by its
    definition (levels are acyclic, so this ends)."""
    if depth > 50:  # a cycle the checker let through: leave it
        return e
    if isinstance(e, A.PVar) and not e.primed:
        p = model.pvariables.get(e.name)
        cpf = model.cpfs.get(e.name)
        if p is not None and p.kind in (INTERM, DERIVED) and cpf is not None:
            args = [inline_interm(a, model, depth) for a in e.args]
            body = substitute(cpf.expr, dict(zip(cpf.params, args, strict=False)))
            return inline_interm(body, model, depth + 1)
    return rebuild(e, lambda c: inline_interm(c, model, depth))


def conjuncts(e: A.Expr) -> Iterator[A.Expr]:
    if isinstance(e, A.Binary) and e.op in ("^", "&"):
        yield from conjuncts(e.left)
        yield from conjuncts(e.right)
    elif not e == TRUE:
        yield e


def conjoin(parts: list[A.Expr]) -> A.Expr:
    """The conjunction of `parts` (true for none), without `true`s."""
    parts = [p for p in parts if p != TRUE]
    if not parts:
        return TRUE
    if any(p == FALSE for p in parts):
        return FALSE
    out = parts[0]
    for p in parts[1:]:
        out = A.Binary("^", out, p, p.loc)
    return out


def negate(e: A.Expr) -> A.Expr:
    if e == TRUE:
        return FALSE
    if e == FALSE:
        return TRUE
    if isinstance(e, A.Unary) and e.op == "~":
        return e.operand
    return A.Unary("~", e, e.loc)


def strip_delta(e: A.Expr) -> A.Expr:
    """`KronDelta(x)` and `DiracDelta(x)` are x."""
    while isinstance(e, A.Distribution) and e.name in ("KronDelta", "DiracDelta") and e.args:
        e = e.args[0]
    return e


def mentions(e: A.Expr, names: frozenset[str] | set[str]) -> bool:
    """Whether a pvariable of `names` occurs in `e`."""
    return any(isinstance(n, A.PVar) and n.name in names for n in A.walk(e))
