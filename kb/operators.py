"""RDDL's action fluents as PDDL-like operators, as ROSPlan's RDDL knowledge
base presents them, with its defects fixed.

Theory of operation. One operator per action fluent, plus the virtual
`exogenous` operator for the dynamics no action causes.

Parameters are named as ROSPlan names them (action interfaces key on these
names): a parameter is named by the first letter of its type, with a
counter from 1 for the repeats of a letter: goto_waypoint(robot, waypoint,
waypoint) has r, w and w1. In conditions and effects a parameter is written
`?w1`; an object is written by its name.

Preconditions come from every action-precondition and state-action
constraint of the shape `forall_{...} [a(?x, ...) => formula]` (or
`~a(...) | formula`): the formula's conjuncts that are a fluent or a negated
fluent become positive and negative conditions, as in ROSPlan; the other
conjuncts (quantifiers, comparisons, equalities, disjunctions), which ROSPlan
dropped, are kept as RDDL formulas over the parameters (`other`).

Effects come from the cpfs, with intermediate fluents inlined. A cpf is read
as a decision list (`if c1 then v1 else if c2 then v2 ... else frame`); a
case whose condition holds the action as a conjunct (possibly under an
`exists`) is an effect of that action on the cpf's fluent, the action's
arguments matched to the cpf's parameters by variable (goto_waypoint(?r,
?from, ?w) in robot_at'(?r, ?w) makes the effect robot_at(?r, ?w1)). What
else the condition asks, and the negation of the earlier cases that involve
no action, becomes the effect's condition (a conditional effect); a cpf
parameter the action does not fix becomes a `forall` of the effect. A value
`true` is an add effect, `false` a delete (a constant `true` is only an add:
ROSPlan made it both), negation swaps them; `Bernoulli(p)` is a probabilistic
effect with two outcomes, add with p and delete with 1 - p; `Discrete(...)`
one outcome per value, an assignment each; a number is an assignment, `f +
e` an increase and `f - e` a decrease. `X | f` and `f ^ X` (f the cpf's own
fluent) read as "if X then true else f" and "if ~X then false else f".

Whatever has another shape is reported (`Unsupported`, with the cpf or
constraint and its line) instead of dropped: a cpf value that copies another
fluent, a continuous draw, an action under a negation, a constraint about
several actions or none. The planner always receives the complete RDDL, so
this only limits what operator-level clients (and the PDDL export) see.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from ..rddl import ast as A
from ..rddl.model import ACTION, NON_FLUENT, STATE, Model, PVariable
from ..rddl.writer import write_expr
from .exprs import (
    FALSE,
    TRUE,
    conjoin,
    conjuncts,
    free_vars,
    inline_interm,
    mentions,
    negate,
    strip_delta,
    substitute,
)
from .report import Unsupported

EXOGENOUS = "exogenous"


# ------------------------------------------------------------------ data


@dataclass(frozen=True)
class Parameter:
    """A typed parameter, `name` without its `?` (ROSPlan's key)."""

    name: str
    type: str

    def to_json(self) -> dict[str, str]:
        return {"name": self.name, "type": self.type}


@dataclass(frozen=True)
class Atom:
    """`fluent(args)`: an arg is a parameter (`?w1`) or an object name."""

    fluent: str
    args: tuple[str, ...] = ()

    def __str__(self) -> str:
        return f"{self.fluent}({', '.join(self.args)})" if self.args else self.fluent

    def to_json(self) -> dict[str, Any]:
        return {"fluent": self.fluent, "args": list(self.args)}


def _text(e: A.Expr | None) -> str | None:
    return None if e is None or e == TRUE else write_expr(e)


def _guarded(
    out: dict[str, Any], condition: str | None, forall: tuple[Parameter, ...]
) -> dict[str, Any]:
    """`out` with the condition and forall parameters of an effect, if any."""
    if condition:
        out["condition"] = condition
    if forall:
        out["forall"] = [p.to_json() for p in forall]
    return out


@dataclass(frozen=True)
class Effect:
    """One effect: `kind` is add, delete, assign, increase or decrease;
    `value` (RDDL text) for the last three; it happens only where
    `condition` holds, for every value of the `forall` parameters."""

    kind: str
    atom: Atom
    value_expr: A.Expr | None = field(default=None, compare=False, repr=False)
    condition_expr: A.Expr = field(default=TRUE, compare=False, repr=False)
    forall: tuple[Parameter, ...] = ()
    loc: A.Loc = field(default=A.NOWHERE, compare=False, repr=False)

    @property
    def value(self) -> str | None:
        return _text(self.value_expr) if self.value_expr is not None else None

    @property
    def condition(self) -> str | None:
        return _text(self.condition_expr)

    def __str__(self) -> str:
        out = f"{self.kind} {self.atom}"
        if self.value_expr is not None:
            out += f" {self.value}"
        if self.condition:
            out += f" when {self.condition}"
        if self.forall:
            out = f"forall {', '.join('?' + p.name for p in self.forall)}: {out}"
        return out

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind, **self.atom.to_json()}
        if self.value_expr is not None:
            out["value"] = self.value
        return _guarded(out, self.condition, self.forall)


@dataclass(frozen=True)
class Outcome:
    """One outcome of a draw: its probability (RDDL text) and effects."""

    probability_expr: A.Expr = field(compare=False, repr=False)
    effects: tuple[Effect, ...]
    probability: str = ""

    def to_json(self) -> dict[str, Any]:
        return {"probability": self.probability, "effects": [e.to_json() for e in self.effects]}


@dataclass(frozen=True)
class ProbabilisticEffect:
    """A draw (a Bernoulli or a Discrete) and its exclusive outcomes, where
    `condition` holds, for every value of the `forall` parameters."""

    outcomes: tuple[Outcome, ...]
    draw: str  # "Bernoulli" or "Discrete"
    condition_expr: A.Expr = field(default=TRUE, compare=False, repr=False)
    forall: tuple[Parameter, ...] = ()
    loc: A.Loc = field(default=A.NOWHERE, compare=False, repr=False)

    @property
    def condition(self) -> str | None:
        return _text(self.condition_expr)

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"draw": self.draw, "outcomes": [o.to_json() for o in self.outcomes]}
        return _guarded(out, self.condition, self.forall)


@dataclass(frozen=True)
class Operator:
    """An action fluent as a PDDL-like operator (ROSPlan's operator details)."""

    name: str
    parameters: tuple[Parameter, ...]
    positive: tuple[Atom, ...] = ()
    negative: tuple[Atom, ...] = ()
    other_exprs: tuple[A.Expr, ...] = field(default=(), compare=False, repr=False)
    effects: tuple[Effect, ...] = ()
    probabilistic: tuple[ProbabilisticEffect, ...] = ()

    @property
    def other(self) -> tuple[str, ...]:
        """The conditions that are no (negated) fluent, in RDDL syntax."""
        return tuple(write_expr(e) for e in self.other_exprs)

    def of_kind(self, kind: str) -> tuple[Effect, ...]:
        return tuple(e for e in self.effects if e.kind == kind)

    @property
    def add_effects(self) -> tuple[Effect, ...]:
        return self.of_kind("add")

    @property
    def delete_effects(self) -> tuple[Effect, ...]:
        return self.of_kind("delete")

    @property
    def numeric_effects(self) -> tuple[Effect, ...]:
        return tuple(e for e in self.effects if e.kind in ("assign", "increase", "decrease"))

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "parameters": [p.to_json() for p in self.parameters],
            "preconditions": {
                "positive": [a.to_json() for a in self.positive],
                "negative": [a.to_json() for a in self.negative],
                "other": list(self.other),
            },
            "effects": [e.to_json() for e in self.effects],
            "probabilistic_effects": [p.to_json() for p in self.probabilistic],
        }


def parameter_names(types: tuple[str, ...]) -> tuple[str, ...]:
    """ROSPlan's keys for parameters of these types: first letter, then a
    counter per letter (robot, waypoint, waypoint -> r, w, w1)."""
    seen: dict[str, int] = {}
    out = []
    for t in types:
        letter = (t[:1] or "x").lower()
        n = seen.get(letter, 0)
        seen[letter] = n + 1
        out.append(letter if n == 0 else f"{letter}{n}")
    return tuple(out)


# ---------------------------------------------------------- translation


class _Context:
    """What an effect is expressed in: the operator's parameters (variable
    of the cpf or constraint -> key) and the variables left to `forall`."""

    def __init__(self, binding: dict[str, str], forall: tuple[Parameter, ...], condition: A.Expr):
        self.binding = binding  # cpf variable ("?w") -> operator parameter ("?w1") or object
        self.forall = forall
        self.condition = condition


class Translator:
    """Builds the operators of a model and records what it cannot read."""

    def __init__(self, model: Model):
        self.model = model
        self.unsupported: list[Unsupported] = []
        self.actions = [p for p in model.pvariables.values() if p.kind == ACTION]
        self.action_names = frozenset(p.name for p in self.actions)
        self.keys = {p.name: parameter_names(p.params) for p in self.actions}
        self._reported: set[tuple[str, str]] = set()
        # cpfs of the state fluents, intermediate fluents inlined
        self.cpfs: list[tuple[A.Cpf, PVariable, A.Expr]] = []
        for name, cpf in model.cpfs.items():
            p = model.pvariables.get(name)
            if p is not None and p.kind == STATE:
                self.cpfs.append((cpf, p, inline_interm(cpf.expr, model)))

    def report(self, where: str, reason: str, loc: A.Loc) -> None:
        if (where, reason) not in self._reported:
            self._reported.add((where, reason))
            self.unsupported.append(Unsupported(where, reason, loc))

    # -- operators

    def operators(self) -> list[Operator]:
        pre = self._preconditions()
        effects: dict[str, tuple[list[Effect], list[ProbabilisticEffect]]] = {
            a.name: ([], []) for a in self.actions
        }
        exo: tuple[list[Effect], list[ProbabilisticEffect]] = ([], [])
        for cpf, p, expr in self.cpfs:
            self._cpf_effects(cpf, p, expr, effects, exo)
        out = []
        for a in self.actions:
            params = tuple(
                Parameter(k, t) for k, t in zip(self.keys[a.name], a.params, strict=True)
            )
            pos, neg, other = pre.get(a.name, ([], [], []))
            eff, prob = effects[a.name]
            out.append(
                Operator(
                    a.name, params, tuple(pos), tuple(neg), tuple(other), tuple(eff), tuple(prob)
                )
            )
        out.append(Operator(EXOGENOUS, (), effects=tuple(exo[0]), probabilistic=tuple(exo[1])))
        return out

    # -- preconditions

    def _preconditions(self) -> dict[str, tuple[list[Atom], list[Atom], list[A.Expr]]]:
        out: dict[str, tuple[list[Atom], list[Atom], list[A.Expr]]] = {}
        dom = self.model.domain
        for kind, constraints in (
            ("action-precondition", dom.action_preconditions),
            ("state-action constraint", dom.state_action_constraints),
        ):
            for c in constraints:
                self._constraint(kind, c, out)
        return out

    def _constraint(
        self,
        kind: str,
        c: A.Expr,
        out: dict[str, tuple[list[Atom], list[Atom], list[A.Expr]]],
    ) -> None:
        body = c
        bound: dict[str, str] = {}  # forall variable -> type
        while isinstance(body, A.Aggregation) and body.op == "forall":
            bound.update({p.name: p.type for p in body.params})
            body = body.body
        head: A.Expr | None = None
        formula: A.Expr | None = None
        if isinstance(body, A.Binary) and body.op == "=>":
            head, formula = body.left, body.right
        elif isinstance(body, A.Binary) and body.op == "|":
            if isinstance(body.left, A.Unary) and body.left.op == "~":
                head, formula = body.left.operand, body.right
        acts = {n.name for n in A.walk(c) if isinstance(n, A.PVar) and n.name in self.action_names}
        where = f"{kind} at line {c.loc.line}"
        if (
            head is None
            or formula is None
            or not isinstance(head, A.PVar)
            or head.name not in self.action_names
        ):
            if not acts:
                reason = "constrains states, not an action (checked by the simulator)"
            elif len(acts) > 1:
                reason = f"about several actions ({', '.join(sorted(acts))}), not one"
            else:
                reason = "not of the form forall_{...} [action(...) => formula]"
            self.report(where, reason, c.loc)
            return
        keys = self.keys[head.name]
        binding: dict[str, A.Expr] = {}
        for i, arg in enumerate(head.args):
            if not (isinstance(arg, A.Var) and arg.name in bound and arg.name not in binding):
                self.report(
                    where, f"the arguments of {head.name} are not distinct variables", c.loc
                )
                return
            binding[arg.name] = A.Var("?" + keys[i], arg.loc)
        if mentions(formula, self.action_names):
            self.report(where, "the condition reads action fluents", c.loc)
            return
        pos, neg, other = out.setdefault(head.name, ([], [], []))
        for part in conjuncts(substitute(formula, binding)):
            atom = self._atom(part)
            if atom is not None:
                pos.append(atom)
                continue
            if isinstance(part, A.Unary) and part.op == "~":
                atom = self._atom(part.operand)
                if atom is not None:
                    neg.append(atom)
                    continue
            other.append(part)

    def _atom(self, e: A.Expr) -> Atom | None:
        """`e` as a ground-or-parameter atom of a bool fluent, or None."""
        if not isinstance(e, A.PVar) or e.primed:
            return None
        p = self.model.pvariables.get(e.name)
        if p is None or p.kind not in (STATE, NON_FLUENT) or p.range != "bool":
            return None
        args = []
        for a in e.args:
            if isinstance(a, A.Var):
                args.append(a.name)
            elif isinstance(a, (A.ObjectLit, A.EnumLit)):
                args.append(a.name)
            elif isinstance(a, A.PVar) and not a.args and a.name not in self.model.pvariables:
                args.append(a.name)  # a bare object name
            else:
                return None
        return Atom(e.name, tuple(args))

    # -- effects

    def _cases(self, cpf: A.Cpf, expr: A.Expr) -> list[tuple[A.Expr | None, A.Expr]]:
        """The cpf as a decision list [(condition, value)]; None: otherwise."""
        frame = A.PVar(cpf.name, tuple(A.Var(v) for v in cpf.params))
        e = strip_delta(expr)
        cases: list[tuple[A.Expr | None, A.Expr]] = []
        while isinstance(e, A.If):
            cases.append((e.cond, e.then))
            e = strip_delta(e.else_)
        if not cases and isinstance(e, A.Binary) and e.op in ("|", "^"):
            parts = list(_flatten(e, e.op))
            rest = [x for x in parts if x != frame]
            if len(rest) < len(parts) and rest and not any(A.has_draws(x) for x in rest):
                other = rest[0] if len(rest) == 1 else _join(rest, e.op)
                if e.op == "|":  # f | X: true where X, else unchanged
                    return [(other, TRUE), (None, frame)]
                return [(negate(other), FALSE), (None, frame)]  # f ^ X
        cases.append((None, e))
        return cases

    def _cpf_effects(
        self,
        cpf: A.Cpf,
        p: PVariable,
        expr: A.Expr,
        effects: dict[str, tuple[list[Effect], list[ProbabilisticEffect]]],
        exo: tuple[list[Effect], list[ProbabilisticEffect]],
    ) -> None:
        frame = A.PVar(cpf.name, tuple(A.Var(v) for v in cpf.params))
        types = dict(zip(cpf.params, p.params, strict=False))
        where = f"cpf {cpf.name}"
        if not mentions(expr, self.action_names):
            # the virtual operator: the cpf's parameters are its foralls
            ctx_forall = tuple(Parameter(v.lstrip("?"), types[v]) for v in cpf.params)
            earlier: list[A.Expr] = []
            for cond, value in self._cases(cpf, expr):
                guard = conjoin([*(negate(x) for x in earlier), cond if cond is not None else TRUE])
                if strip_delta(value) != frame:
                    ctx = _Context({v: v for v in cpf.params}, ctx_forall, guard)
                    self._value(where, cpf, p, value, ctx, exo, frame)
                if cond is not None:
                    earlier.append(cond)
            return
        earlier_free: list[A.Expr] = []  # earlier conditions that involve no action
        for cond, value in self._cases(cpf, expr):
            if cond is None or not mentions(cond, self.action_names):
                if mentions(value, self.action_names):
                    self.report(where, "an action fluent in a value (not in a condition)", cpf.loc)
                elif cond is None and strip_delta(value) != frame:
                    self.report(
                        where,
                        f"the value {write_expr(value)} when no action case applies is no effect "
                        "of an operator",
                        cpf.loc,
                    )
                if cond is not None:
                    earlier_free.append(cond)
                continue
            found = self._action_in(cond)
            if found is None:
                acts = sorted(
                    {
                        n.name
                        for n in A.walk(cond)
                        if isinstance(n, A.PVar) and n.name in self.action_names
                    }
                )
                self.report(
                    where,
                    f"the action{'s' if len(acts) > 1 else ''} {', '.join(acts)} "
                    "not a plain conjunct of the condition",
                    cpf.loc,
                )
                continue
            atom, rest, qvars = found
            keys = self.keys[atom.name]
            binding: dict[str, str] = {}  # cpf parameter -> "?key"
            subst: dict[str, str] = {}  # variable bound by the exists -> "?key"
            fixed: list[tuple[str, A.Expr]] = []  # "?key" must equal this (cpf space)
            for i, arg in enumerate(atom.args):
                key = "?" + keys[i]
                if isinstance(arg, A.Var) and arg.name in cpf.params and arg.name not in binding:
                    binding[arg.name] = key
                elif isinstance(arg, A.Var) and arg.name in qvars and arg.name not in subst:
                    subst[arg.name] = key
                else:  # an object, or a variable used twice: a condition on the parameter
                    fixed.append((key, arg))
            forall = tuple(
                Parameter(_free_name(v, keys), types[v]) for v in cpf.params if v not in binding
            )
            renamed = {v: "?" + _free_name(v, keys) for v in cpf.params if v not in binding}
            # one simultaneous substitution from the cpf's variables to the operator's
            mapping: dict[str, A.Expr] = {
                v: A.Var(k) for v, k in {**binding, **renamed, **subst}.items()
            }
            left = [v for v in qvars if v not in subst]
            raw = conjoin([*(negate(x) for x in earlier_free), rest])
            if left and raw != TRUE:
                raw = A.Aggregation(
                    "exists", tuple(A.TypedVar(v, qvars[v]) for v in left), raw, cond.loc
                )
            guard = conjoin(
                [
                    *(
                        A.Binary("==", A.Var(k), substitute(arg, mapping), arg.loc)
                        for k, arg in fixed
                    ),
                    substitute(raw, mapping),
                ]
            )
            if mentions(guard, self.action_names):
                self.report(
                    where, f"the effect of {atom.name} also depends on other actions", cpf.loc
                )
            ctx = _Context({**binding, **renamed}, forall, guard)
            self._value(where, cpf, p, value, ctx, effects[atom.name], frame)

    def _action_in(self, cond: A.Expr) -> tuple[A.PVar, A.Expr, dict[str, str]] | None:
        """The action atom that is a conjunct of `cond` (under `exists` at
        most), the rest of the condition, and the variables `exists` binds."""
        qvars: dict[str, str] = {}
        e = cond
        while isinstance(e, A.Aggregation) and e.op == "exists":
            qvars.update({p.name: p.type for p in e.params})
            e = e.body
        parts = list(conjuncts(e))
        for i, part in enumerate(parts):
            inner = part
            inner_q: dict[str, str] = {}
            while isinstance(inner, A.Aggregation) and inner.op == "exists":
                inner_q.update({p.name: p.type for p in inner.params})
                inner = inner.body
            inner_parts = list(conjuncts(inner))
            for j, x in enumerate(inner_parts):
                if isinstance(x, A.PVar) and x.name in self.action_names:
                    rest_inner = conjoin(inner_parts[:j] + inner_parts[j + 1 :])
                    others = parts[:i] + parts[i + 1 :]
                    if inner_q and mentions(conjoin(others), self.action_names):
                        return None
                    rest = conjoin([*others, rest_inner])
                    if mentions(rest, frozenset({x.name})):
                        return None
                    return x, rest, {**qvars, **inner_q}
        return None

    def _value(
        self,
        where: str,
        cpf: A.Cpf,
        p: PVariable,
        value: A.Expr,
        ctx: _Context,
        into: tuple[list[Effect], list[ProbabilisticEffect]],
        frame: A.PVar,
    ) -> None:
        """Add the effects of `value` becoming the cpf's next value."""
        names: dict[str, A.Expr] = {v: A.Var(k) for v, k in ctx.binding.items()}
        atom = Atom(cpf.name, tuple(ctx.binding[v] for v in cpf.params))
        own = substitute(frame, names)
        v = strip_delta(value)
        eff, prob = into
        # nested decisions: conditional effects
        if isinstance(v, A.If):
            cond = substitute(v.cond, names)
            self._value(where, cpf, p, v.then, _with(ctx, cond), into, frame)
            self._value(where, cpf, p, v.else_, _with(ctx, negate(cond)), into, frame)
            return
        if v == frame:
            return  # unchanged
        if p.range == "bool":
            self._bool_value(where, cpf, p, v, ctx, atom, own, names, into)
            return
        if isinstance(v, A.Discrete):
            self._discrete(where, cpf, v, ctx, atom, names, prob)
            return
        if A.has_draws(v):
            self.report(where, f"a draw of another kind ({write_expr(v)})", cpf.loc)
            return
        e = substitute(v, names)
        kind, amount = "assign", e
        if isinstance(e, A.Binary) and e.op in ("+", "-"):
            if e.left == own and not mentions(e.right, frozenset({cpf.name})):
                kind, amount = ("increase" if e.op == "+" else "decrease"), e.right
            elif e.op == "+" and e.right == own and not mentions(e.left, frozenset({cpf.name})):
                kind, amount = "increase", e.left
        if kind == "assign" and mentions(e, frozenset({cpf.name})):
            self.report(
                where, f"a value computed from the fluent itself ({write_expr(v)})", cpf.loc
            )
            return
        eff.append(Effect(kind, atom, amount, ctx.condition, ctx.forall, cpf.loc))

    def _bool_value(
        self,
        where: str,
        cpf: A.Cpf,
        p: PVariable,
        v: A.Expr,
        ctx: _Context,
        atom: Atom,
        own: A.Expr,
        names: dict[str, A.Expr],
        into: tuple[list[Effect], list[ProbabilisticEffect]],
        negated: bool = False,
    ) -> None:
        eff, prob = into
        add, delete = ("delete", "add") if negated else ("add", "delete")
        if v == TRUE or v == FALSE:
            # "true where the fluent is true already" changes nothing
            kept = own if (v == TRUE) != negated else negate(own)
            if kept in list(conjuncts(ctx.condition)):
                return
            # (a constant true is an add effect only: ROSPlan filled the delete list too)
            eff.append(
                Effect(add if v == TRUE else delete, atom, None, ctx.condition, ctx.forall, cpf.loc)
            )
            return
        if isinstance(v, A.Unary) and v.op == "~":
            self._bool_value(
                where, cpf, p, strip_delta(v.operand), ctx, atom, own, names, into, not negated
            )
            return
        if isinstance(v, A.Distribution) and v.name == "Bernoulli":
            pr = substitute(v.args[0], names)
            outcomes = (
                Outcome(pr, (Effect(add, atom, loc=cpf.loc),), write_expr(pr)),
                Outcome(
                    _one_minus(pr), (Effect(delete, atom, loc=cpf.loc),), write_expr(_one_minus(pr))
                ),
            )
            prob.append(
                ProbabilisticEffect(outcomes, "Bernoulli", ctx.condition, ctx.forall, cpf.loc)
            )
            return
        if isinstance(v, A.Binary) and v.op in ("^", "&", "|"):
            parts = list(_flatten(v, "^" if v.op == "&" else v.op))
            draws = [x for x in parts if A.has_draws(x)]
            if len(draws) == 1:
                rest = [x for x in parts if x is not draws[0]]
                cond = substitute(_join(rest, v.op if v.op != "&" else "^"), names)
                if v.op == "|":  # X | D: true where X, else the draw
                    self._bool_value(
                        where, cpf, p, TRUE, _with(ctx, cond), atom, own, names, into, negated
                    )
                    self._bool_value(
                        where,
                        cpf,
                        p,
                        draws[0],
                        _with(ctx, negate(cond)),
                        atom,
                        own,
                        names,
                        into,
                        negated,
                    )
                else:  # X ^ D: the draw where X, else false
                    self._bool_value(
                        where, cpf, p, draws[0], _with(ctx, cond), atom, own, names, into, negated
                    )
                    self._bool_value(
                        where,
                        cpf,
                        p,
                        FALSE,
                        _with(ctx, negate(cond)),
                        atom,
                        own,
                        names,
                        into,
                        negated,
                    )
                return
        if not A.has_draws(v):
            self.report(
                where,
                f"a value that is a formula, not a constant or a draw ({write_expr(v)}); "
                "write if (formula) then true else ... to make it an effect",
                cpf.loc,
            )
            return
        self.report(where, f"a draw of another kind ({write_expr(v)})", cpf.loc)

    def _discrete(
        self,
        where: str,
        cpf: A.Cpf,
        v: A.Discrete,
        ctx: _Context,
        atom: Atom,
        names: dict[str, A.Expr],
        prob: list[ProbabilisticEffect],
    ) -> None:
        if v.count is not None:
            self.report(where, f"{v.name} is no single draw", cpf.loc)
            return
        given = [None if dc.prob is None else substitute(dc.prob, names) for dc in v.cases]
        outcomes = []
        for dc, pr in zip(v.cases, given, strict=True):
            if pr is None:  # otherwise: what the others leave
                pr = _one_minus(_join([q for q in given if q is not None], "+"))
            label = dc.label
            if isinstance(label, A.PVar) and not label.args:
                label = A.ObjectLit(label.name, False, label.loc)
            outcomes.append(
                Outcome(pr, (Effect("assign", atom, label, loc=cpf.loc),), write_expr(pr))
            )
        prob.append(
            ProbabilisticEffect(tuple(outcomes), "Discrete", ctx.condition, ctx.forall, cpf.loc)
        )


def _with(ctx: _Context, cond: A.Expr) -> _Context:
    return _Context(ctx.binding, ctx.forall, conjoin([ctx.condition, cond]))


def _flatten(e: A.Expr, op: str) -> Iterator[A.Expr]:
    ops = ("^", "&") if op in ("^", "&") else (op,)
    if isinstance(e, A.Binary) and e.op in ops:
        yield from _flatten(e.left, op)
        yield from _flatten(e.right, op)
    else:
        yield e


def _join(parts: list[A.Expr], op: str) -> A.Expr:
    if not parts:
        return TRUE if op in ("^", "&") else (FALSE if op == "|" else A.Const(0.0))
    out = parts[0]
    for x in parts[1:]:
        out = A.Binary(op, out, x, x.loc)
    return out


def _one_minus(p: A.Expr) -> A.Expr:
    if isinstance(p, A.Const) and not isinstance(p.value, bool):
        return A.Const(round(1.0 - float(p.value), 12))
    if isinstance(p, A.Binary) and p.op == "-" and p.left == A.Const(1.0):
        return p.right
    return A.Binary("-", A.Const(1.0), p, p.loc)


def _free_name(var: str, keys: tuple[str, ...]) -> str:
    """A cpf variable as a forall parameter, clear of the operator's keys."""
    base = var.lstrip("?")
    name = base
    for n in itertools.count(1):
        if name not in keys:
            return name
        name = f"{base}_{n}"
    raise AssertionError  # pragma: no cover


def translate(model: Model) -> tuple[list[Operator], list[Unsupported]]:
    """The operators of `model` (the action fluents, then `exogenous`) and
    what could not be put into their form."""
    t = Translator(model)
    ops = t.operators()
    return ops, t.unsupported


__all__ = [
    "EXOGENOUS",
    "Atom",
    "Effect",
    "Operator",
    "Outcome",
    "Parameter",
    "ProbabilisticEffect",
    "free_vars",
    "parameter_names",
    "translate",
]
