"""A classical PDDL domain and problem from the knowledge base, by
determinisation, so that a classical planner (Fast Downward, Metric-FF's
kin) can plan for an RDDL domain that has a goal.

Theory of operation. The domain is written from the operators
(`ippc.kb.operators`), the problem from the current state, both in one pass:

* types: the object types with their super-types, and each enum type, whose
  values become constants ("@low" -> `low`);
* predicates: every boolean state fluent and non-fluent; an enum- or
  object-valued fluent `f(args)` becomes `(f args ?value)`, true for its one
  current value; numeric fluents are left out (classical PDDL has none), and
  so are conditions and effects on them (reported in the domain's header);
* an action per operator: its
  positive and negative conditions, its other conditions translated
  (quantifiers, connectives, equality of objects); a condition that reads
  only non-fluents and constants (a comparison of numbers, `BUSY_RATE(?w) >
  0.5`) is decided now, for every grounding of its variables, and becomes a
  static predicate with those facts in the problem;
* effects: add, delete, conditional (`when`) and universal (`forall`)
  effects; an enum assignment deletes the old value and adds the new one;
* probabilistic effects: in mode "most-likely", each draw's most likely
  outcome (the first of the most likely on a tie, as
  `ippc.planners.determinise` decides, so a Bernoulli of 0.5 happens),
  decided for every grounding of the probability's variables on the current
  knowledge, through static predicates where the choice differs between
  groundings; in mode "all-outcomes", one action per combination of outcomes
  of the operator's draws, named `<op>__o<i>_<j>...` (one outcome number per
  draw, from 1), each with that outcome's effects (at most 64 combinations an
  operator; further draws take their most likely outcome);
* the exogenous operator (what the world does by itself) is no action: with
  `exogenous="current"` (the default, the baseline of ROSPlan's experiments)
  the fluents it changes keep their current values (what the robot last
  sensed); with "most-likely" they start at the world's most likely next
  values (somebody is at the printer whose OCCUPATION_RATE is 0.94); with
  "outcomes" each outcome of each of its draws is an action of cost 0 the
  planner may count on (`exogenous__<fluent>__o<i>`, not to be dispatched);
* action costs from the reward, for every ground action at the current
  state s, in one batched simulator step per additive term of the reward
  (`a - b` has the terms a and -b) that reads action fluents: the term's
  value with noop minus its value with the action alone, at least 0 (a
  reward term is no cost; a term whose noop value is below every legal
  action's, the anti-noop penalty, is taken against the best legal action
  instead); summed over the terms, in hundredths (Fast Downward wants
  integers), as `(increase (total-cost) c)`; where the groundings of an
  operator cost differently, one action per cost, `<action>__c<cost>`, each
  for the groundings a static predicate lists (strict parsers take any cost
  function but total-cost for a numeric fluent, which Fast Downward
  refuses); the problem minimises total-cost. Terms that read the state are
  taken at the current state;
* the goal: the knowledge base's goal facts, or its whole formula where the
  facts cannot say it (a choice between alternatives); a domain without a
  goal raises `KBError`.

What cannot be written (a condition on a number that changes, a numeric
effect, an action fluent that is not boolean) is listed in a comment at the
top of the domain text, by operator, and the condition is dropped (the
planner may then plan an action the knowledge base refuses: the dispatcher
checks every action against the RDDL preconditions).
"""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import numpy as np

from ..rddl import ast as A
from ..rddl.model import ACTION, NON_FLUENT, PVariable
from ..rddl.writer import write_expr
from .evaluate import NotEvaluable
from .exprs import TRUE, conjuncts, free_vars, mentions
from .goal import Goal
from .operators import EXOGENOUS, Atom, Effect, Operator, Outcome, ProbabilisticEffect
from .store import KBError

if TYPE_CHECKING:
    from .knowledge_base import KnowledgeBase

MODES = ("most-likely", "all-outcomes")
EXOGENOUS_MODES = ("current", "most-likely", "outcomes")
MAX_VARIANTS = 64
MAX_GROUND_ACTIONS = 200_000  # beyond this, unit costs
COST_SCALE = 100  # costs in hundredths of the reward
_CHUNK = 4096  # ground actions per simulator batch
_NAME = re.compile(r"[^A-Za-z0-9_-]")

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


class _Names:
    """RDDL names as PDDL names: letters, digits, '-' and '_', a letter
    first, and distinct without regard to case within one kind."""

    def __init__(self) -> None:
        self.map: dict[tuple[str, str], str] = {}
        self.used: dict[str, set[str]] = {}

    def __call__(self, kind: str, name: str) -> str:
        key = (kind, name)
        if key in self.map:
            return self.map[key]
        base = _NAME.sub("_", name.lstrip("@?")) or "x"
        if not base[0].isalpha():
            base = "n" + base
        used = self.used.setdefault(kind, set())
        out = base
        for n in itertools.count(1):
            if out.lower() not in used and out.lower() not in ("object", "either", "number"):
                break
            out = f"{base}_{n}"
        used.add(out.lower())
        self.map[key] = out
        return out


class _Writer:
    def __init__(self, kb: KnowledgeBase, mode: str, exogenous: str = "current"):
        if mode not in MODES:
            raise KBError(
                f"unknown determinisation {mode!r} (one of {', '.join(MODES)})", "bad-params"
            )
        if exogenous not in EXOGENOUS_MODES:
            raise KBError(
                f"unknown exogenous {exogenous!r} (one of {', '.join(EXOGENOUS_MODES)})",
                "bad-params",
            )
        self.exogenous = exogenous
        self.kb = kb
        self.model = kb.model
        self.mode = mode
        self.names = _Names()
        self.notes: list[str] = []
        self.static_preds: list[str] = []  # declarations
        self.static_facts: list[str] = []
        self.cost_classes: dict[str, list[tuple[int, str]]] = {}  # op -> (cost, predicate)
        self.constants: set[str] = set()  # RDDL object names used in the domain
        self.uses_never = False
        self._static_cache: dict[tuple[str, tuple[tuple[str, str], ...]], str] = {}
        self.stored = kb._store.pvars
        self.action_names = frozenset(p.name for p in self.model.fluents(ACTION))
        self.objects_of_type: dict[str, tuple[str, ...]] = {
            t: info.members for t, info in self.model.types.items()
        }
        # every object and enum value gets its PDDL name up front (objects first)
        for info in self.model.types.values():
            for m in info.members:
                self.obj(m)

    # -- names

    def obj(self, name: str) -> str:
        return self.names("object", name)

    def pred(self, name: str) -> str:
        return self.names("predicate", name)

    def typ(self, name: str) -> str:
        return self.names("type", name)

    def var(self, name: str) -> str:
        return "?" + _NAME.sub("_", name.lstrip("?"))

    def note(self, where: str, what: str) -> None:
        line = f"{where}: {what}"
        if line not in self.notes:
            self.notes.append(line)

    # -- formulas

    def term(self, e: A.Expr) -> str | None:
        if isinstance(e, A.Var):
            return self.var(e.name)
        if isinstance(e, (A.ObjectLit, A.EnumLit)):
            self.constants.add(e.name)
            return self.obj(e.name)
        if isinstance(e, A.PVar) and not e.args and e.name not in self.model.pvariables:
            self.constants.add(e.name)
            return self.obj(e.name)
        return None

    def atom(self, a: Atom) -> str:
        args = [self.var(x) if x.startswith("?") else self._const(x) for x in a.args]
        return f"({' '.join([self.pred(a.fluent), *args])})"

    def _const(self, name: str) -> str:
        self.constants.add(name)
        return self.obj(name)

    def is_static(self, e: A.Expr) -> bool:
        for n in A.walk(e):
            if isinstance(n, A.PVar) and n.name in self.model.pvariables:
                if self.model.pvariables[n.name].kind != NON_FLUENT:
                    return False
        return True

    def formula(self, e: A.Expr, types: dict[str, str]) -> str | None:
        """`e` in PDDL, with `types` the types of its free variables; None
        where it cannot be written."""
        if e == TRUE:
            return "(and)"
        if e == A.Const(False):
            self.uses_never = True
            return "(ippc-never)"
        if isinstance(e, A.PVar) and not e.primed:
            p = self.stored.get(e.name)
            if p is not None and p.range == "bool":
                args = [self.term(a) for a in e.args]
                if all(a is not None for a in args):
                    return f"({' '.join([self.pred(e.name), *args])})"  # type: ignore[list-item]
        if isinstance(e, A.Unary) and e.op == "~":
            inner = self.formula(e.operand, types)
            return None if inner is None else f"(not {inner})"
        if isinstance(e, A.Binary) and e.op in ("^", "&", "|", "=>", "<=>"):
            left, right = self.formula(e.left, types), self.formula(e.right, types)
            if left is None or right is None:
                return self.static(e, types)
            if e.op in ("^", "&"):
                return f"(and {left} {right})"
            if e.op == "|":
                return f"(or {left} {right})"
            if e.op == "=>":
                return f"(imply {left} {right})"
            return f"(and (imply {left} {right}) (imply {right} {left}))"
        if isinstance(e, A.Binary) and e.op in ("==", "~="):
            out = self.equality(e.left, e.right) or self.equality(e.right, e.left)
            if out is not None:
                return out if e.op == "==" else f"(not {out})"
        if isinstance(e, A.Aggregation) and e.op in ("exists", "forall"):
            inner_types = {**types, **{p.name: p.type for p in e.params}}
            body = self.formula(e.body, inner_types)
            if body is not None:
                params = " ".join(f"{self.var(p.name)} - {self.typ(p.type)}" for p in e.params)
                return f"({e.op} ({params}) {body})"
        return self.static(e, types)

    def equality(self, a: A.Expr, b: A.Expr) -> str | None:
        ta, tb = self.term(a), self.term(b)
        if ta is not None and tb is not None:
            return f"(= {ta} {tb})"
        if isinstance(a, A.PVar) and not a.primed and tb is not None:
            p = self.stored.get(a.name)
            if p is not None and p.range not in ("bool", "int", "real"):
                args = [self.term(x) for x in a.args]
                if all(x is not None for x in args):
                    return f"({' '.join([self.pred(a.name), *args, tb])})"  # type: ignore[list-item]
        return None

    def static(self, e: A.Expr, types: dict[str, str]) -> str | None:
        """A condition on non-fluents only, decided now as a static predicate."""
        if not self.is_static(e) or any(
            isinstance(n, A.PVar)
            and n.name in self.model.pvariables
            and self.model.pvariables[n.name].kind == ACTION
            for n in A.walk(e)
        ):
            return None
        fv = sorted(free_vars(e))
        if any(v not in types for v in fv):
            return None
        key = (write_expr(e), tuple((v, types[v]) for v in fv))
        if key in self._static_cache:
            name = self._static_cache[key]
        else:
            name = self.names("predicate", f"ippc-static-{len(self._static_cache) + 1}")
            self._static_cache[key] = name
            params = " ".join(f"?x{i} - {self.typ(types[v])}" for i, v in enumerate(fv))
            self.static_preds.append(f"({name}{' ' + params if params else ''})")
            for binding in itertools.product(*(self.objects_of_type[types[v]] for v in fv)):
                try:
                    holds = bool(self.kb._evaluator(e, dict(zip(fv, binding, strict=True))))
                except NotEvaluable:
                    return None
                if holds:
                    self.static_facts.append(f"({' '.join([name, *map(self.obj, binding)])})")
        return f"({' '.join([name, *map(self.var, fv)])})"

    # -- effects

    def effect(self, op: str, e: Effect, types: dict[str, str]) -> str | None:
        body: str | None
        p = self.stored.get(e.atom.fluent)
        if e.kind in ("add", "delete"):
            body = self.atom(e.atom) if e.kind == "add" else f"(not {self.atom(e.atom)})"
        elif p is not None and p.range not in ("bool", "int", "real") and e.kind == "assign":
            value = None if e.value_expr is None else self.term(e.value_expr)
            if value is None:
                self.note(op, f"the value of {e.atom} is computed ({e.value}): left out")
                return None
            atom = self.atom(e.atom)[1:-1]
            old = self.var("ippc-old")
            body = f"(and (forall ({old} - {self.typ(p.range)}) (not ({atom} {old}))) ({atom} {value}))"
        else:
            self.note(op, f"a numeric effect ({e}): left out")
            return None
        inner = {**types, **{"?" + q.name: q.type for q in e.forall}}
        return self.wrap(op, body, e.condition_expr, e.forall, inner)

    def wrap(
        self, op: str, body: str, condition: A.Expr, forall: Iterable[Any], types: dict[str, str]
    ) -> str:
        if condition != TRUE:
            cond = self.formula(condition, types)
            if cond is None:
                self.note(op, f"the condition {write_expr(condition)} cannot be written: dropped")
            else:
                body = f"(when {cond} {body})"
        params = " ".join(f"{self.var(q.name)} - {self.typ(q.type)}" for q in forall)
        return f"(forall ({params}) {body})" if params else body

    def choices(
        self, op: Operator, draw: ProbabilisticEffect, types: dict[str, str]
    ) -> tuple[list[str], dict[tuple[str, ...], int], list[str]]:
        """For every grounding of the variables the draw's probabilities read:
        which outcome is the most likely (the first of them), with the
        variables' names; outcomes that have probability 0 everywhere."""
        inner = {**types, **{"?" + q.name: q.type for q in draw.forall}}
        fv = sorted(set().union(*(free_vars(o.probability_expr) for o in draw.outcomes)))
        fv = [v for v in fv if v in inner]
        out: dict[tuple[str, ...], int] = {}
        possible: set[int] = set()
        for binding in itertools.product(*(self.objects_of_type[inner[v]] for v in fv)):
            env = dict(zip(fv, binding, strict=True))
            probs = []
            for o in draw.outcomes:
                try:
                    probs.append(float(self.kb._evaluator(o.probability_expr, env)))  # type: ignore[arg-type]
                except (NotEvaluable, TypeError, ValueError):
                    probs.append(math.nan)
            best = max(
                range(len(probs)), key=lambda i: (probs[i] if probs[i] == probs[i] else -1, -i)
            )
            out[tuple(binding)] = best
            possible |= {i for i, q in enumerate(probs) if not q == 0}
        never = [str(i) for i in range(len(draw.outcomes)) if i not in possible]
        return fv, out, never

    def outcome_effects(self, op: str, oc: Outcome, types: dict[str, str]) -> list[str]:
        return [x for x in (self.effect(op, e, types) for e in oc.effects) if x is not None]

    def most_likely(
        self, op: Operator, draw: ProbabilisticEffect, types: dict[str, str]
    ) -> list[str]:
        fv, choice, _ = self.choices(op, draw, types)
        inner = {**types, **{"?" + q.name: q.type for q in draw.forall}}
        picked = set(choice.values())
        if len(picked) == 1:
            effects = self.outcome_effects(op.name, draw.outcomes[picked.pop()], inner)
            return (
                [
                    self.wrap(
                        op.name,
                        f"(and {' '.join(effects)})",
                        draw.condition_expr,
                        draw.forall,
                        inner,
                    )
                ]
                if effects
                else []
            )
        out = []
        for i, oc in enumerate(draw.outcomes):
            effects = self.outcome_effects(op.name, oc, inner)
            if not effects or i not in picked:
                continue
            name = self.names("predicate", f"ippc-likely-{op.name}-{len(self.static_preds) + 1}")
            params = " ".join(f"?x{k} - {self.typ(inner[v])}" for k, v in enumerate(fv))
            self.static_preds.append(f"({name} {params})")
            for binding, c in choice.items():
                if c == i:
                    self.static_facts.append(f"({' '.join([name, *map(self.obj, binding)])})")
            cond = f"({' '.join([name, *map(self.var, fv)])})"
            out.append(
                self.wrap(
                    op.name,
                    f"(when {cond} (and {' '.join(effects)}))",
                    draw.condition_expr,
                    draw.forall,
                    inner,
                )
            )
        return out

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

    # -- costs

    def costs(self, ops: list[Operator]) -> dict[str, str]:
        """`(increase (total-cost) ...)` per operator: for every ground action,
        what each additive term of the reward that reads actions costs it at
        the current state against noop (see the module's docstring), in one
        batched pass per term."""
        kb = self.kb
        sim = kb.simulator()
        acts = [
            p
            for p in self.model.fluents(ACTION)
            if p.range == "bool" and any(o.name == p.name for o in ops)
        ]
        ground: list[tuple[PVariable, tuple[int, ...]]] = []
        for p in acts:
            shape = tuple(len(self.model.objects(t)) for t in p.params)
            ground.extend((p, idx) for idx in np.ndindex(*shape))
        if not ground:
            return {}
        if len(ground) > MAX_GROUND_ACTIONS:
            self.note("costs", f"{len(ground)} ground actions: every action costs 1")
            return {p.name: "(increase (total-cost) 1)" for p in acts}
        state = kb.to_state()
        legal = np.empty(len(ground), dtype=bool)
        terms = reward_terms(self.model.reward) if self.model.reward is not None else []
        terms = [t for t in terms if mentions(t, self.action_names)]
        # the value of each term for every ground action, and for noop (last row)
        values = np.zeros((len(terms), len(ground) + 1))
        rng = np.random.default_rng(0)
        for start in range(0, len(ground) + 1, _CHUNK):
            part = ground[start : start + _CHUNK]
            b = len(part) + (1 if start + _CHUNK > len(ground) else 0)
            batch = state[np.zeros(b, dtype=np.int64)]
            actions = sim.noop(b)
            for row, (p, idx) in enumerate(part):
                actions[p.name][(row, *idx)] = True
            for k, term in enumerate(terms):
                step = kb.term_simulator(term).step(batch, actions, rng, check=False)
                values[k, start : start + b] = step.reward
            try:
                ok = sim.check_actions(batch, actions)
            except Exception:  # a constraint that cannot even be evaluated here
                ok = np.zeros(b, dtype=bool)
            legal[start : start + len(part)] = ok[: len(part)]
        total = np.zeros(len(ground))
        for k in range(len(terms)):
            acts_k, noop_k = values[k, :-1], values[k, -1]
            mine_k = acts_k[legal] if legal.any() else acts_k
            if noop_k < mine_k.min():
                ref = mine_k.max()  # a term that only punishes doing nothing
            else:
                ref = noop_k
            total += np.maximum(ref - acts_k, 0.0)
        cost = np.rint(total * COST_SCALE).astype(np.int64)
        out: dict[str, str] = {}
        start = 0
        for p in acts:
            n = int(np.prod([len(self.model.objects(t)) for t in p.params], dtype=np.int64))
            mine = cost[start : start + n]
            rows = ground[start : start + n]
            start += n
            if len(set(mine.tolist())) == 1:
                out[p.name] = f"(increase (total-cost) {int(mine[0])})"
                continue
            # Groundings of different costs: one action per cost, told apart by
            # a static predicate (strict parsers take a cost function other than
            # total-cost for a numeric fluent, and Fast Downward refuses
            # :numeric-fluents).
            classes: list[tuple[int, str]] = []
            for c in sorted(set(mine.tolist())):
                pname = self.names("predicate", f"ippc-cost-{p.name}-{c}")
                params = " ".join(f"?x{k} - {self.typ(t)}" for k, t in enumerate(p.params))
                self.static_preds.append(f"({pname} {params})")
                classes.append((int(c), pname))
            by_cost = dict(classes)
            for (_, idx), c in zip(rows, mine.tolist(), strict=True):
                args = [
                    self.obj(self.model.objects(t)[i]) for t, i in zip(p.params, idx, strict=True)
                ]
                self.static_facts.append(f"({' '.join([by_cost[c], *args])})")
            self.cost_classes[p.name] = classes
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

    def world_step(self) -> dict[tuple[str, tuple[str, ...]], bool]:
        """The boolean facts the exogenous operator most likely sets in the
        next step, evaluated on the current knowledge (exogenous="most-likely":
        the world as it most likely is once the plan starts)."""
        exo = self.kb.operator(EXOGENOUS)
        out: dict[tuple[str, tuple[str, ...]], bool] = {}

        def apply(effects: Iterable[Effect], env: dict[str, str]) -> None:
            for e in effects:
                if e.kind not in ("add", "delete"):
                    continue
                try:
                    if not self.kb._evaluator(e.condition_expr, env):
                        continue
                except NotEvaluable:
                    continue
                args = tuple(env.get(a, a) for a in e.atom.args)
                out[(e.atom.fluent, args)] = e.kind == "add"

        for e in exo.effects:
            for env in self._envs(e.forall):
                apply([e], env)
        for d in exo.probabilistic:
            for env in self._envs(d.forall):
                try:
                    if not self.kb._evaluator(d.condition_expr, env):
                        continue
                    probs = [float(self.kb._evaluator(o.probability_expr, env)) for o in d.outcomes]  # type: ignore[arg-type]
                except (NotEvaluable, TypeError, ValueError):
                    continue
                best = max(range(len(probs)), key=lambda i: (probs[i], -i))
                apply(d.outcomes[best].effects, env)
        return out

    def _envs(self, forall: Iterable[Any]) -> list[dict[str, str]]:
        params = list(forall)
        return [
            {"?" + q.name: m for q, m in zip(params, combo, strict=True)}
            for combo in itertools.product(*(self.objects_of_type[q.type] for q in params))
        ]

    def exogenous_actions(self) -> list[str]:
        """exogenous="outcomes": each outcome of each exogenous draw as an action
        of cost 0, so that the planner may count on any outcome."""
        exo = self.kb.operator(EXOGENOUS)
        out = []
        for n, d in enumerate(exo.probabilistic):
            types = {"?" + q.name: q.type for q in d.forall}
            params = " ".join(f"{self.var(q.name)} - {self.typ(q.type)}" for q in d.forall)
            cond = "(and)" if d.condition_expr == TRUE else self.formula(d.condition_expr, types)
            if cond is None:
                self.note(EXOGENOUS, f"the condition {d.condition} cannot be written: dropped")
                cond = "(and)"
            fluent = d.outcomes[0].effects[0].atom.fluent if d.outcomes[0].effects else str(n)
            for i, oc in enumerate(d.outcomes):
                effects = self.outcome_effects(EXOGENOUS, oc, types)
                if not effects:
                    continue
                name = self.names("action", f"{EXOGENOUS}__{fluent}__o{i + 1}")
                out.append(
                    "\n".join(
                        [
                            f"  (:action {name}",
                            f"   :parameters ({params})",
                            f"   :precondition {cond}",
                            f"   :effect {normal_effect('(and ' + ' '.join(effects) + ')')})",
                        ]
                    )
                )
        return out

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


def reward_terms(e: A.Expr) -> list[A.Expr]:
    """The additive terms of a reward, each with its sign (`a - b` gives a
    and -b)."""
    if isinstance(e, A.Binary) and e.op in ("+", "-"):
        right = reward_terms(e.right)
        if e.op == "-":
            right = [A.Unary("-", t, t.loc) for t in right]
        return [*reward_terms(e.left), *right]
    return [e]


# ------------------------------------------------------- effect normal form

SExpr = str | list["SExpr"]


def _sexpr(text: str) -> SExpr:
    """A PDDL s-expression as nested lists of tokens."""
    stack: list[list[SExpr]] = [[]]
    for tok in re.findall(r"\(|\)|[^\s()]+", text):
        if tok == "(":
            stack.append([])
        elif tok == ")":
            done = stack.pop()
            stack[-1].append(done)
        else:
            stack[-1].append(tok)
    return stack[0][0]


def _show(e: SExpr) -> str:
    return e if isinstance(e, str) else "(" + " ".join(_show(x) for x in e) + ")"


def _flat(e: SExpr, conds: list[SExpr], params: list[SExpr]) -> list[str]:
    """The PDDL effect `e` as standard c-effects: `and` only at the top,
    one `forall` around one `when` around one literal (the writer builds
    nested forms freely; strict parsers refuse them)."""
    if isinstance(e, list) and e and e[0] == "and":
        return [x for sub in e[1:] for x in _flat(sub, conds, params)]
    if isinstance(e, list) and e and e[0] == "when":
        return _flat(e[2], [*conds, e[1]], params)
    if isinstance(e, list) and e and e[0] == "forall":
        return _flat(e[2], conds, [*params, *e[1]])  # type: ignore[misc]
    out = _show(e)
    if conds:
        cond = _show(conds[0]) if len(conds) == 1 else _show(["and", *conds])
        out = f"(when {cond} {out})"
    if params:
        out = f"(forall ({' '.join(_show(p) for p in params)}) {out})"
    return [out]


def normal_effect(text: str) -> str:
    """`text` (an effect) in the standard form `_flat` describes."""
    return "(and " + " ".join(_flat(_sexpr(text), [], [])) + ")"


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
    kb: KnowledgeBase, mode: str = "most-likely", exogenous: str = "current"
) -> tuple[str, str]:
    """(domain, problem) PDDL texts of `kb` (see the module's docstring)."""
    return _Writer(kb, mode, exogenous).write()


__all__ = ["MODES", "to_pddl"]
