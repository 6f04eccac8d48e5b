"""Action costs for the PDDL domain: for every ground action, what each
additive term of the reward that reads actions costs it at the current state
against noop, in one batched simulator pass per term, in hundredths, with one
action per cost where the groundings of an operator cost differently (see
the package docstring).
"""

from __future__ import annotations

import numpy as np

from ...rddl import ast as A
from ...rddl.model import ACTION, PVariable
from ..exprs import mentions
from ..operators import Operator
from .translate import _Translator

MAX_GROUND_ACTIONS = 200_000  # beyond this, unit costs
COST_SCALE = 100  # costs in hundredths of the reward
_CHUNK = 4096  # ground actions per simulator batch


class _Costs(_Translator):
    """The reward as action costs."""

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


def reward_terms(e: A.Expr) -> list[A.Expr]:
    """The additive terms of a reward, each with its sign (`a - b` gives a
    and -b)."""
    if isinstance(e, A.Binary) and e.op in ("+", "-"):
        right = reward_terms(e.right)
        if e.op == "-":
            right = [A.Unary("-", t, t.loc) for t in right]
        return [*reward_terms(e.left), *right]
    return [e]
