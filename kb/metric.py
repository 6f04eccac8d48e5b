"""The reward as an expression tree (the metric), with RDDL's meaning.

ROSPlan's tree for the metric knew only ADD, SUB, MUL and DIV: it wrote a
conjunction as a product, a disjunction as a sum, a negation as a unary
minus and an if-then-else as cond·then + (−cond)·else, and gave up on
comparisons; so it could only be read, not evaluated. This tree keeps each
RDDL operator as it is, so a client can evaluate it exactly (the knowledge
base evaluates R(s, a) itself: `immediate_reward`).

A node is a JSON object: ``{"op": "+", "args": [...]}`` for operators and
functions (`op` the RDDL operator: + - * / ^ | ~ => <=> == ~= < <= > >=,
"neg" for unary minus, "if", "switch", a function or distribution name),
``{"op": "sum", "vars": [["?r", "robot"]], "args": [body]}`` for
aggregations, ``{"fluent": name, "args": [...], "primed": bool}``,
``{"var": "?x"}``, ``{"const": value}``, ``{"enum": "@a"}`` and
``{"object": name}``.
"""

from __future__ import annotations

from typing import Any

from ..rddl import ast as A


def expression_tree(e: A.Expr) -> dict[str, Any]:
    """The JSON tree of an expression (see the module's docstring)."""
    t = expression_tree
    if isinstance(e, A.Const):
        return {"const": e.value}
    if isinstance(e, A.Var):
        return {"var": e.name}
    if isinstance(e, A.EnumLit):
        return {"enum": e.name}
    if isinstance(e, A.ObjectLit):
        return {"object": e.name}
    if isinstance(e, A.PVar):
        return {"fluent": e.name, "args": [t(a) for a in e.args], "primed": e.primed}
    if isinstance(e, A.Unary):
        op = {"-": "neg", "+": "pos"}.get(e.op, e.op)
        return {"op": op, "args": [t(e.operand)]}
    if isinstance(e, A.Binary):
        return {"op": e.op, "args": [t(e.left), t(e.right)]}
    if isinstance(e, (A.Aggregation, A.DiscreteOver)):
        op = e.op if isinstance(e, A.Aggregation) else e.name
        return {"op": op, "vars": [[p.name, p.type] for p in e.params], "args": [t(e.body)]}
    if isinstance(e, A.If):
        return {"op": "if", "args": [t(e.cond), t(e.then), t(e.else_)]}
    if isinstance(e, A.Switch):
        cases = [
            {"label": None if c.label is None else t(c.label), "value": t(c.value)} for c in e.cases
        ]
        return {"op": "switch", "args": [t(e.subject)], "cases": cases}
    if isinstance(e, A.Discrete):
        cases = [
            {"label": t(c.label), "probability": None if c.prob is None else t(c.prob)}
            for c in e.cases
        ]
        return {"op": e.name, "type": e.type, "cases": cases}
    if isinstance(e, (A.Function, A.Distribution, A.VectorDistribution)):
        return {"op": e.name, "args": [t(a) for a in e.args]}
    if isinstance(e, A.MatrixOp):
        return {"op": e.name, "args": [t(e.body)]}
    raise TypeError(f"no tree for {type(e).__name__}")  # pragma: no cover
