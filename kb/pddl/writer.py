"""The PDDL domain and problem texts (`to_pddl`): the actions of the
operators (with their determinised variants and cost classes), the goal,
the initial state, and the domain's types, constants and predicates; it
puts together what `translate.py`, `determinisation.py` and `costs.py`
compute.
"""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING, Any

from ...rddl.writer import write_expr
from ..exprs import conjuncts
from ..goal import Goal
from ..operators import EXOGENOUS, Operator, ProbabilisticEffect
from ..store import KBError

if TYPE_CHECKING:
    from ..view import KnowledgeView
from .costs import _Costs
from .determinisation import _Determiniser
from .normal_form import normal_effect

MAX_VARIANTS = 64

REQUIREMENTS = (
    ":strips",
    ":typing",
    ":negative-preconditions",
    ":disjunctive-preconditions",
    ":equality",
    ":existential-preconditions",
    ":universal-preconditions",
    ":conditional-effects",
    ":action-costs",
)


class _Writer(_Determiniser, _Costs):
    """One writing of a knowledge base's domain and problem."""

    # -- actions

    def action(self, op: Operator, costs: dict[str, str]) -> list[str]:
        types = {"?" + p.name: p.type for p in op.parameters}
        pre = [self.atom(a) for a in op.positive]
        pre += [f"(not {self.atom(a)})" for a in op.negative]
        for cond in op.other_exprs:
            parts = list(conjuncts(cond))
            for part in parts:
                text = self.formula(part, types)
                if text is None:
                    self.note(
                        op.name, f"the condition {write_expr(part)} cannot be written: dropped"
                    )
                else:
                    pre.append(text)
        det = [x for x in (self.effect(op.name, e, types) for e in op.effects) if x is not None]
        cost = costs.get(op.name)
        if cost:
            det.append(cost)
        draws = list(op.probabilistic)
        variants: list[tuple[str, list[str]]] = []
        if self.mode == "most-likely" or not draws:
            eff = list(det)
            for d in draws:
                eff += self.most_likely(op, d, types)
            variants.append((self.names("action", op.name), eff))
        else:
            split: list[ProbabilisticEffect] = []
            n = 1
            for d in draws:
                if n * len(d.outcomes) > MAX_VARIANTS:
                    break
                split.append(d)
                n *= len(d.outcomes)
            rest = draws[len(split) :]
            if rest:
                self.note(
                    op.name,
                    f"{len(rest)} draw(s) beyond {MAX_VARIANTS} combinations take their most likely outcome",
                )
            common = list(det)
            for d in rest:
                common += self.most_likely(op, d, types)
            options = []
            for d in split:
                _, _, never = self.choices(op, d, types)
                options.append([i for i in range(len(d.outcomes)) if str(i) not in never])
            for combo in itertools.product(*options):
                eff = list(common)
                for d, i in zip(split, combo, strict=True):
                    inner = {**types, **{"?" + q.name: q.type for q in d.forall}}
                    effects = self.outcome_effects(op.name, d.outcomes[i], inner)
                    if effects:
                        eff.append(
                            self.wrap(
                                op.name,
                                f"(and {' '.join(effects)})",
                                d.condition_expr,
                                d.forall,
                                inner,
                            )
                        )
                suffix = "_".join(str(i + 1) for i in combo)
                variants.append((self.names("action", f"{op.name}__o{suffix}"), eff))
        params = " ".join(f"{self.var(p.name)} - {self.typ(p.type)}" for p in op.parameters)
        keys = " ".join(self.var(p.name) for p in op.parameters)
        classes: list[tuple[str, str | None, str | None]] = [("", None, None)]
        if op.name in self.cost_classes:
            classes = [
                (f"__c{c}", f"({pred} {keys})", f"(increase (total-cost) {c})")
                for c, pred in self.cost_classes[op.name]
            ]
        out = []
        for name, eff in variants:
            for suffix, guard, cost_effect in classes:
                action = self.names("action", name + suffix) if suffix else name
                lines = [f"  (:action {action}", f"   :parameters ({params})"]
                conds = [*pre, *([guard] if guard else [])]
                lines.append(f"   :precondition (and {' '.join(conds)})")
                effects = [*eff, *([cost_effect] if cost_effect else [])]
                lines.append(f"   :effect {normal_effect('(and ' + ' '.join(effects) + ')')})")
                out.append("\n".join(lines))
        return out

    # -- the two texts

    def goal(self, goal: Goal) -> str:
        if goal.unsupported and goal.formula is not None:
            text = self.formula(goal.formula, {})
            if text is None:
                raise KBError(f"the goal {goal.text} cannot be written in PDDL", "not-expressible")
            return text
        parts = []
        for f in goal.facts:
            p = self.stored[f.fluent]
            args = [self.obj(a) for a in f.args]
            if p.range == "bool":
                atom = f"({' '.join([self.pred(f.fluent), *args])})"
                parts.append(atom if f.value else f"(not {atom})")
            elif p.range in ("int", "real"):
                raise KBError(
                    f"the goal {f} is on a number: not in classical PDDL", "not-expressible"
                )
            else:
                parts.append(f"({' '.join([self.pred(f.fluent), *args, self.obj(str(f.value))])})")
        return f"(and {' '.join(parts)})"

    def write(self) -> tuple[str, str]:
        kb, model = self.kb, self.model
        goal = kb.goal()
        if goal is None:
            raise KBError(
                f"domain '{model.domain_name}' has no goal (a 'goal' state fluent or a "
                "terminate-when horizon): a classical planner needs one",
                "no-goal",
            )
        ops = [o for o in kb.operators() if o.name != EXOGENOUS]
        kept = []
        for o in ops:
            p = model.pvariables[o.name]
            if p.range != "bool":
                self.note(o.name, f"a {p.range}-valued action: left out")
            else:
                kept.append(o)
        with kb._lock:
            costs = self.costs(kept)
            actions = [text for o in kept for text in self.action(o, costs)]
            if self.exogenous == "outcomes":
                actions += self.exogenous_actions()
            goal_text = self.goal(goal)
            init = self.init()
        dname = self.names("domain", model.domain_name)
        types = []
        for t in model.types.values():
            parent = self.typ(t.parent) if t.parent else "object"
            types.append(f"{self.typ(t.name)} - {parent}")
        preds = []
        for p in self.stored.values():
            params = [f"?x{i} - {self.typ(t)}" for i, t in enumerate(p.params)]
            if p.range == "bool":
                preds.append(f"({' '.join([self.pred(p.name), *params])})")
            elif p.range not in ("int", "real"):
                preds.append(
                    f"({' '.join([self.pred(p.name), *params, f'?v - {self.typ(p.range)}'])})"
                )
        if self.uses_never:
            preds.append("(ippc-never)")
        preds += self.static_preds
        enum_values = {m for t in model.types.values() if t.kind == "enum" for m in t.members}
        consts: dict[str, list[str]] = {}
        for t in model.types.values():
            for m in t.members:
                if (m in self.constants or m in enum_values) and _own_type(model, m) == t.name:
                    consts.setdefault(t.name, []).append(self.obj(m))
        header = [
            f"; PDDL of RDDL domain '{model.domain_name}' by ippc.kb ({self.mode} determinisation)",
            "; numeric fluents are left out; costs in hundredths of reward",
            *(f"; not written: {n}" for n in self.notes),
        ]
        domain = "\n".join(
            [
                *header,
                f"(define (domain {dname})",
                "  (:requirements " + " ".join(REQUIREMENTS) + ")",
                f"  (:types {' '.join(types)})" if types else "",
                (
                    "  (:constants "
                    + " ".join(f"{' '.join(ms)} - {self.typ(t)}" for t, ms in consts.items())
                    + ")"
                )
                if consts
                else "",
                f"  (:predicates {' '.join(preds)})",
                "  (:functions (total-cost) - number)",
                *actions,
                ")",
                "",
            ]
        )
        domain = "\n".join(line for line in domain.split("\n") if line != "")
        objects: dict[str, list[str]] = {}
        for t in model.types.values():
            if t.kind != "object":
                continue
            for m in t.members:
                if m not in self.constants and _own_type(model, m) == t.name:
                    objects.setdefault(t.name, []).append(self.obj(m))
        problem = "\n".join(
            [
                f"(define (problem {self.names('problem', model.name)})",
                f"  (:domain {dname})",
                "  (:objects "
                + " ".join(f"{' '.join(ms)} - {self.typ(t)}" for t, ms in objects.items())
                + ")",
                f"  (:init {' '.join(init)} (= (total-cost) 0))",
                f"  (:goal {goal_text})",
                "  (:metric minimize (total-cost)))",
                "",
            ]
        )
        return domain + "\n", problem

    def init(self) -> list[str]:
        out = []
        world = self.world_step() if self.exogenous == "most-likely" else {}
        for p in self.stored.values():
            if p.range in ("int", "real"):
                continue
            for args, v in self.kb._store.items(p):
                if p.range == "bool":
                    v = world.get((p.name, args), v)
                names = [self.obj(a) for a in args]
                if p.range == "bool":
                    if v:
                        out.append(f"({' '.join([self.pred(p.name), *names])})")
                else:
                    out.append(f"({' '.join([self.pred(p.name), *names, self.obj(str(v))])})")
        return out + self.static_facts


def _own_type(model: Any, member: str) -> str:
    """The most specific type of an object or enum value."""
    best = None
    for t in model.types.values():
        if member in t.members and (
            best is None or len(t.members) < len(model.types[best].members)
        ):
            best = t.name
    assert best is not None
    return best


def to_pddl(
    kb: KnowledgeView, mode: str = "most-likely", exogenous: str = "current"
) -> tuple[str, str]:
    """(domain, problem) PDDL texts of `kb` (see the package's docstring)."""
    return _Writer(kb, mode, exogenous).write()
