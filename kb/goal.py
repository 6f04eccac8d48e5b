"""The goal of a domain, as ROSPlan extracts it, without its defects.

ROSPlan looks for a state fluent literally named `goal`: first for a cpf
`goal' = formula | goal`, then for a constraint `goal => formula`, and
turns the formula into ground goal facts. It splits conjunctions, grounds
`forall`, flips negations, and for a disjunction keeps the first disjunct
that is not `goal`. On its own print-fetching domain that last rule is
wrong: the goal `forall_{?w} [~DELIVERY_DESTINATION(?w) | exists_{?r}
papers_delivered(?r, ?w)]` becomes "not DELIVERY_DESTINATION(w)" for every
w.

Here a disjunction is read as what it means. It is grounded over the
instance, and each disjunct that reads only non-fluents is decided there and
then: a true one makes the whole disjunction hold (nothing to achieve), a
false one is dropped. `~P(?w) | Q(?w)` therefore gives Q(w) exactly where
P(w) holds, which on the print domain is papers_delivered(kenny, phdarea).
What stays a real choice between several state conditions cannot be a
conjunction of facts; it is reported, and `goal_holds` still decides the
whole formula exactly.

Besides the `goal` fluent, an rddlsim `terminate-when` horizon is the goal
of its instance.

At run time a controller may replace the domain's goal by a conjunction of
ground facts (ROSPlan's ADD_GOAL and REMOVE_GOAL updates): such a goal has
source "runtime" and no lifted formula; `parse_goal_fact` reads the facts
(`GoalFact`s, "holding(r1)", "~present(office)", "status == @busy", or
`{"fluent", "args", "value"}`).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from ..rddl import ast as A
from ..rddl.model import NON_FLUENT, STATE, Model, Value
from ..rddl.writer import write_expr
from .evaluate import Env, Evaluator, NotEvaluable
from .report import Unsupported

GOAL_FLUENT = "goal"
RUNTIME = "runtime"  # the source of a goal set at run time


@dataclass(frozen=True)
class GoalFact:
    """One ground goal: `fluent(args)` must have `value` (False for a
    negated goal)."""

    fluent: str
    args: tuple[str, ...]
    value: Value = True

    def to_json(self) -> dict[str, Any]:
        return {"fluent": self.fluent, "args": list(self.args), "value": self.value}

    def __str__(self) -> str:
        ground = f"{self.fluent}({', '.join(self.args)})" if self.args else self.fluent
        if self.value is True:
            return ground
        if self.value is False:
            return f"~{ground}"
        return f"{ground} == {self.value}"


@dataclass(frozen=True)
class GoalSource:
    """Where a domain's goal is: the `goal` fluent (or None) and the lifted
    condition that makes it true (None when there is none to read)."""

    fluent: str | None
    formula: A.Expr | None
    source: str  # "cpf", "constraint", "terminate-when" or "fluent"
    loc: A.Loc


@dataclass(frozen=True)
class Goal:
    """The goal of the current state of a knowledge base."""

    fluent: str | None
    formula: A.Expr | None
    source: str
    facts: tuple[GoalFact, ...]
    unsupported: tuple[Unsupported, ...]
    version: int = 0  # 0 at load, one more at every goal change

    @property
    def text(self) -> str | None:
        """The lifted condition in RDDL syntax (a run-time goal's: the
        conjunction of its facts)."""
        if self.formula is None:
            if self.source == RUNTIME and self.facts:
                return " ^ ".join(str(f) for f in self.facts)
            return None
        return write_expr(self.formula)

    def to_json(self) -> dict[str, Any]:
        return {
            "fluent": self.fluent,
            "source": self.source,
            "formula": self.text,
            "facts": [f.to_json() for f in self.facts],
            "unsupported": [u.to_json() for u in self.unsupported],
            "version": self.version,
        }


def _is_goal(e: A.Expr) -> bool:
    return isinstance(e, A.PVar) and e.name == GOAL_FLUENT and not e.args


def _disjuncts(e: A.Expr) -> Iterator[A.Expr]:
    if isinstance(e, A.Binary) and e.op == "|":
        yield from _disjuncts(e.left)
        yield from _disjuncts(e.right)
    else:
        yield e


def _conjuncts(e: A.Expr) -> Iterator[A.Expr]:
    if isinstance(e, A.Binary) and e.op in ("^", "&"):
        yield from _conjuncts(e.left)
        yield from _conjuncts(e.right)
    else:
        yield e


def _or(parts: list[A.Expr]) -> A.Expr:
    out = parts[0]
    for p in parts[1:]:
        out = A.Binary("|", out, p, p.loc)
    return out


def find_goal(model: Model) -> GoalSource | None:
    """Where the goal of `model` is, or None when it has none."""
    p = model.pvariables.get(GOAL_FLUENT)
    if p is not None and p.kind == STATE and p.range == "bool" and not p.params:
        cpf = model.cpfs.get(GOAL_FLUENT)
        if cpf is not None:
            expr = cpf.expr
            if isinstance(expr, A.Distribution) and expr.name == "KronDelta":
                expr = expr.args[0]
            if isinstance(expr, A.If) and _is_goal(expr.else_) and expr.then == A.Const(True):
                expr = expr.cond  # if (formula) then true else goal
            rest = [d for d in _disjuncts(expr) if not _is_goal(d)]
            if rest and not any(
                isinstance(n, (A.Distribution, A.Discrete, A.DiscreteOver)) for n in A.walk(expr)
            ):
                return GoalSource(GOAL_FLUENT, _or(rest), "cpf", cpf.loc)
        dom = model.domain
        for c in (*dom.state_action_constraints, *dom.action_preconditions, *dom.state_invariants):
            for part in _conjuncts(c):
                if isinstance(part, A.Binary) and part.op == "=>" and _is_goal(part.left):
                    return GoalSource(GOAL_FLUENT, part.right, "constraint", part.loc)
        return GoalSource(GOAL_FLUENT, None, "fluent", p.loc)
    h = model.instance.horizon
    if h is not None and not isinstance(h, (int, str)):
        return GoalSource(None, h, "terminate-when", model.instance.loc)
    return None


class _Grounder:
    """Turns a goal formula into ground facts (see the module's docstring)."""

    def __init__(self, model: Model, evaluator: Evaluator, is_state: Callable[[str], bool]):
        self.model = model
        self.ev = evaluator
        self.is_state = is_state
        self.facts: list[GoalFact] = []
        self.unsupported: list[Unsupported] = []

    def static(self, e: A.Expr) -> bool:
        """Whether `e` reads no state fluent (only non-fluents, constants)."""
        for n in A.walk(e):
            if isinstance(n, A.PVar) and n.name in self.model.pvariables:
                if self.model.pvariables[n.name].kind != NON_FLUENT:
                    return False
        return True

    def skip(self, e: A.Expr, env: Env, reason: str) -> None:
        bound = ", ".join(f"{k}={v}" for k, v in env.items())
        text = write_expr(e) + (f" with {bound}" if bound else "")
        self.unsupported.append(Unsupported("goal", f"{reason}: {text}", e.loc))

    def ground(self, e: A.Expr, env: Env, positive: bool = True) -> None:
        """Add the facts that make `e` (or its negation) true under `env`."""
        if self.static(e):
            try:
                holds = bool(self.ev(e, env)) == positive
            except NotEvaluable as err:
                self.skip(e, env, f"cannot be decided ({err})")
                return
            if not holds:
                self.skip(e, env, "can never hold in this instance")
            return
        if isinstance(e, A.Unary) and e.op == "~":
            self.ground(e.operand, env, not positive)
            return
        if isinstance(e, A.PVar) and self.is_state(e.name):
            p = self.model.pvariables[e.name]
            if p.range == "bool" and not e.primed:
                try:
                    self.facts.append(GoalFact(e.name, self.ev.args(e, env), positive))
                except NotEvaluable as err:
                    self.skip(e, env, str(err))
                return
        if isinstance(e, A.Binary):
            if e.op in ("^", "&") and positive or e.op == "|" and not positive:
                self.ground(e.left, env, positive)
                self.ground(e.right, env, positive)
                return
            if e.op == "=>" and not positive:  # ~(a => b) = a ^ ~b
                self.ground(e.left, env, True)
                self.ground(e.right, env, False)
                return
            if e.op in ("^", "&", "|", "=>"):
                self.choose(list(self.alternatives(e, env, positive)), e, env)
                return
            if e.op == "==" and positive:
                fact = self.equality(e, env)
                if fact is not None:
                    self.facts.append(fact)
                    return
        if isinstance(e, A.Aggregation) and e.op in ("forall", "exists"):
            every = (e.op == "forall") == positive
            envs = self.ev.bindings(e.params, env)
            if every:
                for b in envs:
                    self.ground(e.body, b, positive)
            else:
                self.choose([(e.body, b, positive) for b in envs], e, env)
            return
        self.skip(e, env, "not a conjunction of facts")

    def alternatives(
        self, e: A.Expr, env: Env, positive: bool
    ) -> Iterator[tuple[A.Expr, Env, bool]]:
        """The disjuncts of `e` (or of its negation), with their polarity."""
        if isinstance(e, A.Binary):
            if e.op == "|" and positive or e.op in ("^", "&") and not positive:
                yield from self.alternatives(e.left, env, positive)
                yield from self.alternatives(e.right, env, positive)
                return
            if e.op == "=>" and positive:  # a => b = ~a | b
                yield from self.alternatives(e.left, env, False)
                yield from self.alternatives(e.right, env, True)
                return
        if isinstance(e, A.Unary) and e.op == "~":
            yield from self.alternatives(e.operand, env, not positive)
            return
        if (
            isinstance(e, A.Aggregation)
            and (e.op == "exists") == positive
            and e.op
            in (
                "exists",
                "forall",
            )
        ):
            for b in self.ev.bindings(e.params, env):
                yield from self.alternatives(e.body, b, positive)
            return
        yield e, env, positive

    def choose(self, alts: list[tuple[A.Expr, Env, bool]], e: A.Expr, env: Env) -> None:
        """A disjunction: decide the static disjuncts, ground what is left."""
        left = []
        for sub, b, pos in alts:
            if _is_goal(sub):
                continue
            if self.static(sub):
                try:
                    if bool(self.ev(sub, b)) == pos:
                        return  # the disjunction holds whatever the state
                except NotEvaluable as err:
                    self.skip(sub, b, f"cannot be decided ({err})")
                    return
                continue
            left.append((sub, b, pos))
        if not left:
            self.skip(e, env, "can never hold in this instance")
        elif len(left) == 1:
            self.ground(*left[0])
        else:
            self.skip(e, env, f"a choice between {len(left)} alternatives")

    def equality(self, e: A.Binary, env: Env) -> GoalFact | None:
        for f, v in ((e.left, e.right), (e.right, e.left)):
            if isinstance(f, A.PVar) and self.is_state(f.name) and not f.primed and self.static(v):
                try:
                    return GoalFact(f.name, self.ev.args(f, env), self.ev(v, env))
                except NotEvaluable:
                    return None
        return None


def ground_goal(
    model: Model, where: GoalSource, evaluator: Evaluator, is_state: Callable[[str], bool]
) -> Goal:
    """The goal facts of `where` on the evaluator's current non-fluents."""
    if where.formula is None:
        return Goal(where.fluent, None, where.source, (GoalFact(GOAL_FLUENT, (), True),), ())
    g = _Grounder(model, evaluator, is_state)
    g.ground(where.formula, {})
    # a fact named twice (two destinations sharing one condition) once
    facts = tuple(dict.fromkeys(g.facts))
    return Goal(where.fluent, where.formula, where.source, facts, tuple(g.unsupported))


_FACT_TEXT = re.compile(
    r"^\s*(?P<neg>~)?\s*(?P<name>[A-Za-z_][\w\-]*)\s*"
    r"(?:\((?P<args>[^()]*)\))?\s*(?:==\s*(?P<value>\S+))?\s*$"
)


def _literal(text: str) -> Value:
    if text in ("true", "false"):
        return text == "true"
    for kind in (int, float):
        try:
            return kind(text)  # type: ignore[no-any-return]
        except ValueError:
            pass
    return text


def parse_goal_fact(item: Any) -> GoalFact:
    """One goal fact from a `GoalFact`, a text ("holding(r1)",
    "~present(office)", "delivered", "status == @busy") or a dict
    `{"fluent", "args"?, "value"?}` (value true by default). Checks the
    shape only; the knowledge base checks names and values. `ValueError`
    says what is wrong."""
    if isinstance(item, GoalFact):
        return item
    if isinstance(item, str):
        m = _FACT_TEXT.match(item)
        if m is None or (m["neg"] and m["value"]):
            raise ValueError(
                f"{item!r} is not a goal fact: write name(args), ~name(args) or name(args) == value"
            )
        args = tuple(a.strip() for a in (m["args"] or "").split(",") if a.strip())
        value: Value = False if m["neg"] else True
        if m["value"] is not None:
            value = _literal(m["value"])
        return GoalFact(m["name"], args, value)
    if isinstance(item, dict):
        unknown = sorted(set(item) - {"fluent", "args", "value"})
        fluent, args, value = item.get("fluent"), item.get("args", []), item.get("value", True)
        if unknown:
            raise ValueError(f"unknown key(s) {', '.join(unknown)} (known: fluent, args, value)")
        if not isinstance(fluent, str):
            raise ValueError(f"'fluent' must be a name, not {fluent!r}")
        if not isinstance(args, (list, tuple)) or not all(isinstance(a, str) for a in args):
            raise ValueError(f"'args' must be a list of names, not {args!r}")
        if value is None or isinstance(value, (dict, list)):
            raise ValueError(f"'value' must be a bool, a number or a name, not {value!r}")
        return GoalFact(fluent, tuple(args), value)
    raise ValueError(f"a goal fact is a text or {{fluent, args, value}}, not {item!r}")
