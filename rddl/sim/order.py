"""The order in which a step evaluates the cpfs.

Owns `_order_cpfs`: interm and derived fluents, then next-state cpfs, then
observations, by level and declaration order as rddlsim does, except where
a cpf reads one computed later (pyRDDLGym's levels-free style): then by
dependency. A cycle is a `SimulationError`. Imports the model, the AST and
`state` only.
"""

from __future__ import annotations

from .. import ast as A
from ..model import DERIVED, INTERM, OBSERV, STATE, Model
from .state import SimulationError


def _order_cpfs(model: Model) -> list[str]:
    """Keys of every cpf ("name" or "name'" for next state) in evaluation order."""
    rank = {INTERM: 0, DERIVED: 0, STATE: 1, OBSERV: 2}
    keys: dict[str, tuple[int, int, int]] = {}
    for i, p in enumerate(model.pvariables.values()):
        if p.kind in rank and p.name in model.cpfs:
            key = p.name + ("'" if p.kind == STATE else "")
            keys[key] = (rank[p.kind], p.level if p.level is not None else 0, i)
    deps: dict[str, set[str]] = {}
    for key in keys:
        cp = model.cpfs[key.rstrip("'")]
        found = set()
        for node in A.walk(cp.expr):
            if isinstance(node, A.PVar):
                ref = node.name + ("'" if node.primed else "")
                if ref in keys and ref != key:
                    found.add(ref)
                elif node.name in keys and not node.primed and ref != key:
                    found.add(node.name)
        deps[key] = found
    order: list[str] = []
    done: set[str] = set()
    pending = sorted(keys, key=lambda k: keys[k])
    while pending:
        for k in pending:
            if deps[k] <= done:
                order.append(k)
                done.add(k)
                pending.remove(k)
                break
        else:
            cycle = ", ".join(pending)
            raise SimulationError(f"the cpfs of {cycle} depend on each other in a cycle")
    return order
