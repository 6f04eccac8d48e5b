"""The determinisation of the operators' draws in PDDL: each draw's most
likely outcome for every grounding, through static predicates where it
differs between groundings (mode "most-likely"), the outcomes that can
happen (mode "all-outcomes"), and the exogenous operator's part (its most
likely next step, or its outcomes as actions of cost 0). See the package
docstring.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable
from typing import Any

from ..evaluate import NotEvaluable
from ..exprs import TRUE, free_vars
from ..operators import EXOGENOUS, Effect, Operator, Outcome, ProbabilisticEffect
from .normal_form import normal_effect
from .translate import _Translator


class _Determiniser(_Translator):
    """The probabilistic effects of the operators and of the exogenous one."""

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
